// Flat-coloured, softly lit triangles; one model matrix per draw.

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
    return out;
}

@fragment
fn fragment_main(in: VertexOut) -> @location(0) vec4<f32> {
    // Light from high above one corner; faces seen from behind are lit like their fronts.
    let light = normalize(vec3<f32>(0.3, 0.2, 1.0));
    let lambert = abs(dot(normalize(in.normal), light));
    let shade = 0.55 + 0.45 * lambert;
    return vec4<f32>(in.colour * shade, 1.0);
}
