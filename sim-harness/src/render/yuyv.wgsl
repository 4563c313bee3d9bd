// Packs the resolved RGBA image into YUYV (`yuyv_pair.wgsl`, put before this file).

@compute @workgroup_size(8, 8, 1)
fn pack_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if (beyond_the_image(id)) {
        return;
    }
    let left = textureLoad(image, vec2<u32>(2u * id.x, id.y), 0).rgb;
    let right = textureLoad(image, vec2<u32>(2u * id.x + 1u, id.y), 0).rgb;
    store_pair(id, left, right);
}
