// YUYV packing (BT.601, full range), put before the plain pack (`yuyv.wgsl`) and the camera
// effects pass (`camera_effects.wgsl`): one u32 per pixel pair, bytes Y0 U Y1 V, U and V the
// mean of the pair. Each invocation packs the pair `id` of `image` into `packed`.

@group(0) @binding(0) var image: texture_2d<f32>;
@group(0) @binding(1) var<storage, read_write> packed: array<u32>;

// Whether invocation `id` is past the image's pixel pairs (the last groups overhang it).
fn beyond_the_image(id: vec3<u32>) -> bool {
    let size = textureDimensions(image);
    return id.x >= size.x / 2u || id.y >= size.y;
}

fn store_pair(id: vec3<u32>, left: vec3<f32>, right: vec3<f32>) {
    packed[id.y * (textureDimensions(image).x / 2u) + id.x] = yuyv_pair(left, right);
}

fn to_byte(value: f32) -> u32 {
    return u32(clamp(round(value * 255.0), 0.0, 255.0));
}

fn yuyv_pair(left: vec3<f32>, right: vec3<f32>) -> u32 {
    let luma = vec3<f32>(0.299, 0.587, 0.114);
    let y0 = dot(left, luma);
    let y1 = dot(right, luma);
    let mean = (left + right) * 0.5;
    let u = dot(mean, vec3<f32>(-0.168736, -0.331264, 0.5)) + 0.5;
    let v = dot(mean, vec3<f32>(0.5, -0.418688, -0.081312)) + 0.5;
    return to_byte(y0) | (to_byte(u) << 8u) | (to_byte(y1) << 16u) | (to_byte(v) << 24u);
}
