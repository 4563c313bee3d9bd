// The clean scene: flat colours under the soft light (after scene_vertex.wgsl).

@fragment
fn fragment_main(in: VertexOut) -> @location(0) vec4<f32> {
    return vec4<f32>(in.colour * soft_shade(normalize(in.normal)), 1.0);
}
