// Packs the resolved RGBA image into YUYV (BT.601, full range): one u32 per pixel pair,
// bytes Y0 U Y1 V, U and V the mean of the pair.

@group(0) @binding(0) var image: texture_2d<f32>;
@group(0) @binding(1) var<storage, read_write> packed: array<u32>;

fn to_byte(value: f32) -> u32 {
    return u32(clamp(round(value * 255.0), 0.0, 255.0));
}

@compute @workgroup_size(8, 8, 1)
fn pack_main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(image);
    let pairs = size.x / 2u;
    if (id.x >= pairs || id.y >= size.y) {
        return;
    }
    let left = textureLoad(image, vec2<u32>(2u * id.x, id.y), 0).rgb;
    let right = textureLoad(image, vec2<u32>(2u * id.x + 1u, id.y), 0).rgb;
    let luma = vec3<f32>(0.299, 0.587, 0.114);
    let y0 = dot(left, luma);
    let y1 = dot(right, luma);
    let mean = (left + right) * 0.5;
    let u = dot(mean, vec3<f32>(-0.168736, -0.331264, 0.5)) + 0.5;
    let v = dot(mean, vec3<f32>(0.5, -0.418688, -0.081312)) + 0.5;
    packed[id.y * pairs + id.x] =
        to_byte(y0) | (to_byte(u) << 8u) | (to_byte(y1) << 16u) | (to_byte(v) << 24u);
}
