// The scene's vertex stage and soft light, shared by the clean scene (scene.wgsl) and the
// lit one (scene_lit.wgsl): flat-coloured triangles, one model matrix per draw. Prepended to
// each (render/pipelines.rs).

struct Camera {
    view_projection: mat4x4<f32>,
};

struct Model {
    transform: mat4x4<f32>,
};

@group(0) @binding(0) var<uniform> camera: Camera;
@group(1) @binding(0) var<uniform> model: Model;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) colour: vec3<f32>,
    @location(2) world: vec3<f32>,
};

@vertex
fn vertex_main(
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) colour: vec3<f32>,
) -> VertexOut {
    var out: VertexOut;
    let world = model.transform * vec4<f32>(position, 1.0);
    out.clip = camera.view_projection * world;
    out.normal = (model.transform * vec4<f32>(normal, 0.0)).xyz;
    out.colour = colour;
    out.world = world.xyz;
    return out;
}

// The clean scene's light from high above one corner, for a unit normal `n`: faces seen from
// behind are lit like their fronts.
fn soft_shade(n: vec3<f32>) -> f32 {
    let soft = normalize(vec3<f32>(0.3, 0.2, 1.0));
    return 0.55 + 0.45 * abs(dot(n, soft));
}
