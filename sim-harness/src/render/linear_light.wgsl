// The resolved image in linear light, once a texel, for `camera_effects.wgsl`: its samples
// (up to 32 a pixel for blur and a softer lens, four texels each) read these values instead
// of raising every texel they touch to GAMMA again. Same `pow`, same input: the same values.

const GAMMA: f32 = 2.2;

@group(0) @binding(0) var image: texture_2d<f32>;
@group(0) @binding(1) var linear: texture_storage_2d<rgba32float, write>;

@compute @workgroup_size(8, 8, 1)
fn linear_main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(image);
    if (id.x >= size.x || id.y >= size.y) {
        return;
    }
    let texel = textureLoad(image, id.xy, 0);
    textureStore(linear, id.xy, vec4<f32>(pow(texel.rgb, vec3<f32>(GAMMA)), 1.0));
}
