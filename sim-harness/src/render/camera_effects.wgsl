// A camera's own effects on its full-resolution image, then YUYV packing (`yuyv_pair.wgsl`,
// put before this file): motion blur and rolling-shutter skew from the camera's rotation
// during the exposure (a pure rotation moves every pixel by a homography, whatever its
// depth), a softer lens, vignetting, exposure gain, shot and read noise in the raw (linear)
// signal, the sensor's saturation, white balance gains, the display curve and contrast.

struct Effects {
    // Exposure gain (linear), contrast, read noise variance, shot noise factor.
    gain_contrast_noise: vec4<f32>,
    white_balance: vec4<f32>,
    // Angular velocity in the camera frame (x optical axis, y left, z up), exposure time.
    omega_exposure: vec4<f32>,
    // Readout time, vignetting, lens softness (px), samples per pixel.
    readout_vignetting_softness_samples: vec4<f32>,
    // fx, fy, width, height.
    intrinsics: vec4<f32>,
    seed: vec4<u32>,
};

// `image` (binding 0, `yuyv_pair.wgsl`) is the rendered image in linear light here
// (`linear_light.wgsl` raised it to GAMMA once a texel).
// The same buffer twice. As a uniform buffer its values are loaded once for every
// invocation of a group (a storage buffer's are gathered per invocation), but lavapipe
// specialises a shader on the uniform values its control flow reads (the samples' count,
// the noise that follows the gain frame by frame) and keeps every variant: what decides
// control flow is read through the storage alias.
@group(0) @binding(2) var<uniform> effects: Effects;
@group(0) @binding(3) var<storage, read> effects_flow: Effects;

// The optional stages this pipeline has. lavapipe runs both sides of every branch under a
// lane mask, so a stage costs its full price wherever it is in the shader, even in a frame
// where no pixel takes it; the renderer builds a pipeline per combination (on first use)
// and, frame by frame, leaves out the stages whose runtime condition below is false for the
// whole frame (`EffectsStages`): the arithmetic of every stage it keeps is unchanged.
// Noise: the read or the shot noise is positive.
override NOISE: bool = true;
// The camera turns during the exposure or the readout: its angular velocity is not zero.
override TURN: bool = true;
// A softer lens: its softness is positive.
override SOFT_LENS: bool = true;

const GAMMA: f32 = 2.2;
const TAU: f32 = 6.2831853;

fn hash(value: u32) -> u32 {
    let state = value * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

fn unit(value: u32) -> f32 {
    return (f32(value >> 8u) + 0.5) / 16777216.0;
}

// A standard normal draw for one pixel's channel.
fn gaussian(x: u32, y: u32, channel: u32) -> f32 {
    let base = hash(effects.seed.x ^ hash(x + hash(y ^ hash(channel + effects.seed.y))));
    let u1 = unit(base);
    let u2 = unit(hash(base ^ 0x9e3779b9u));
    return sqrt(-2.0 * log(u1)) * cos(TAU * u2);
}

// The rendered image in linear light at a position in pixels, bilinear, edges clamped.
fn linear_at(position: vec2<f32>) -> vec3<f32> {
    let size = vec2<f32>(textureDimensions(image));
    let q = clamp(position - vec2<f32>(0.5), vec2<f32>(0.0), size - vec2<f32>(1.0));
    let i0 = vec2<u32>(floor(q));
    let f = q - floor(q);
    let last = vec2<u32>(size) - vec2<u32>(1u);
    let i1 = min(i0 + vec2<u32>(1u), last);
    let a = textureLoad(image, i0, 0).rgb;
    let b = textureLoad(image, vec2<u32>(i1.x, i0.y), 0).rgb;
    let c = textureLoad(image, vec2<u32>(i0.x, i1.y), 0).rgb;
    let d = textureLoad(image, i1, 0).rgb;
    return mix(mix(a, b, f.x), mix(c, d, f.x), f.y);
}

// Where the rendered (mid-exposure) image shows what pixel `pixel` sees after the camera
// turned by the rotation vector `angle` (camera frame).
fn rotated(pixel: vec2<f32>, angle: vec3<f32>) -> vec2<f32> {
    let fx = effects.intrinsics.x;
    let fy = effects.intrinsics.y;
    let centre = effects.intrinsics.zw * 0.5;
    let ray = vec3<f32>(1.0, (centre.x - pixel.x) / fx, (centre.y - pixel.y) / fy);
    let theta = length(angle);
    var turned = ray;
    if (TURN) {
        if (theta > 1e-7) {
            let k = angle / theta;
            turned = ray * cos(theta) + cross(k, ray) * sin(theta) + k * dot(k, ray) * (1.0 - cos(theta));
        }
    }
    return vec2<f32>(centre.x - fx * turned.y / turned.x, centre.y - fy * turned.z / turned.x);
}

// Light reaching the sensor at one pixel (linear): blur, skew and lens, vignetting, gain.
fn exposed(x: u32, y: u32) -> vec3<f32> {
    let pixel = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
    let size = effects.intrinsics.zw;
    let omega = effects.omega_exposure.xyz;
    let exposure = effects.omega_exposure.w;
    let readout = effects.readout_vignetting_softness_samples.x;
    let softness = effects.readout_vignetting_softness_samples.z;
    let samples = u32(effects_flow.readout_vignetting_softness_samples.w);
    // Rows are read top to bottom during the readout; the render is the frame's middle.
    let row_time = (pixel.y / size.y - 0.5) * readout;
    var sum = vec3<f32>(0.0);
    for (var i = 0u; i < samples; i = i + 1u) {
        let share = (f32(i) + 0.5) / f32(samples);
        let t = row_time + (share - 0.5) * exposure;
        var at = rotated(pixel, omega * t);
        if (SOFT_LENS) {
            if (effects_flow.readout_vignetting_softness_samples.z > 0.0) {
                // A Vogel spiral of radius 2 sigma: variance sigma^2 along each axis.
                let k = f32(i % 8u);
                let radius = 2.0 * softness * sqrt((k + 0.5) / 8.0);
                let turn = k * 2.39996323;
                at = at + radius * vec2<f32>(cos(turn), sin(turn));
            }
        }
        sum = sum + linear_at(at);
    }
    var light = sum / f32(samples);
    let offset = pixel - size * 0.5;
    let r2 = dot(offset, offset) / dot(size * 0.5, size * 0.5);
    light = light * (1.0 - effects.readout_vignetting_softness_samples.y * r2);
    return light * effects.gain_contrast_noise.x;
}

// The processed display value of one pixel: noise, saturation, white balance, curve, contrast.
fn processed(x: u32, y: u32) -> vec3<f32> {
    var raw = exposed(x, y);
    let read = effects.gain_contrast_noise.z;
    let shot = effects.gain_contrast_noise.w;
    if (NOISE) {
        if (effects_flow.gain_contrast_noise.z > 0.0 || effects_flow.gain_contrast_noise.w > 0.0) {
            for (var c = 0u; c < 3u; c = c + 1u) {
                let sigma = sqrt(read + shot * max(raw[c], 0.0));
                raw[c] = raw[c] + sigma * gaussian(x, y, c);
            }
        }
    }
    let balanced = clamp(clamp(raw, vec3<f32>(0.0), vec3<f32>(1.0)) * effects.white_balance.rgb,
                         vec3<f32>(0.0), vec3<f32>(1.0));
    let display = pow(balanced, vec3<f32>(1.0 / GAMMA));
    return clamp(vec3<f32>(0.5) + (display - vec3<f32>(0.5)) * effects.gain_contrast_noise.y,
                 vec3<f32>(0.0), vec3<f32>(1.0));
}

@compute @workgroup_size(8, 8, 1)
fn effects_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if (beyond_the_image(id)) {
        return;
    }
    let left = processed(2u * id.x, id.y);
    let right = processed(2u * id.x + 1u, id.y);
    store_pair(id, left, right);
}
