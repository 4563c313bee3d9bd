// The scene under a directional light (after scene_vertex.wgsl): the clean scene's flat
// colours and soft light, plus a light from `light.towards` whose share of the light is lost
// in the shadows of the casters (capsules: goal posts and bars, the ball, robots, people),
// and bright spots on the field where that light falls.

const MAX_CASTERS: u32 = 64u;
const MAX_SPOTS: u32 = 8u;

struct Light {
    // Towards the light (unit), and its share of a lit surface's light.
    towards_share: vec4<f32>,
    // Casters and spots in use.
    counts: vec4<u32>,
    // Per caster two entries: a.xyz and radius, then b.xyz.
    casters: array<vec4<f32>, 128>,
    // Per spot two entries: centre.xy and half axes, then cos, sin of its angle and gain.
    spots: array<vec4<f32>, 16>,
};

// The same buffer twice. Read as a uniform buffer its values are loaded once for every
// fragment of a group (a storage buffer's are gathered per fragment: two thirds more time on
// lavapipe), but lavapipe specialises a shader on the uniform values its control flow reads
// and keeps every variant (the ball's caster changes every frame: about 2 MB a frame): so
// what decides control flow, the counts, is read through the storage alias.
@group(2) @binding(0) var<uniform> light: Light;
@group(2) @binding(1) var<storage, read> light_flow: Light;

// Shortest distance between segments p0-p1 and q0-q1.
fn segment_distance(p0: vec3<f32>, p1: vec3<f32>, q0: vec3<f32>, q1: vec3<f32>) -> f32 {
    let d1 = p1 - p0;
    let d2 = q1 - q0;
    let r = p0 - q0;
    let a = dot(d1, d1);
    let e = dot(d2, d2);
    let f = dot(d2, r);
    var s = 0.0;
    var t = 0.0;
    let c = dot(d1, r);
    if (e <= 1e-12) {
        s = clamp(-c / a, 0.0, 1.0);
    } else {
        let b = dot(d1, d2);
        let denominator = a * e - b * b;
        if (denominator > 1e-12) {
            s = clamp((b * f - c * e) / denominator, 0.0, 1.0);
        }
        t = (b * s + f) / e;
        if (t < 0.0) {
            t = 0.0;
            s = clamp(-c / a, 0.0, 1.0);
        } else if (t > 1.0) {
            t = 1.0;
            s = clamp((b - c) / a, 0.0, 1.0);
        }
    }
    return length((p0 + d1 * s) - (q0 + d2 * t));
}

// Distance from `point` to the segment a-b.
fn point_distance(point: vec3<f32>, a: vec3<f32>, b: vec3<f32>) -> f32 {
    let ab = b - a;
    let length2 = dot(ab, ab);
    var t = 0.0;
    if (length2 > 1e-12) {
        t = clamp(dot(point - a, ab) / length2, 0.0, 1.0);
    }
    return length(point - (a + ab * t));
}

// 1 where the light reaches `point`, 0 in a shadow. Every fragment walks all casters: no
// `continue` and no `return` in the loop, whose control flow so stays the same for all lanes
// (with them, a lit pair took about a sixth more CPU on lavapipe for the same frames,
// presumably because the counter, and with it the casters' loads, became per lane; lavapipe
// runs the skipped work under a mask either way).
fn lit(point: vec3<f32>) -> f32 {
    let towards = light.towards_share.xyz;
    // The ray's length bounds each caster's shadow (`render/shadow_casters.rs`, RAY_M).
    let end = point + towards * 25.0;
    var shadowed = false;
    for (var i = 0u; i < min(light_flow.counts.x, MAX_CASTERS); i = i + 1u) {
        let a = light.casters[2u * i];
        let b = light.casters[2u * i + 1u].xyz;
        // A point on a caster's own surface is not shadowed by it.
        if (point_distance(point, a.xyz, b) >= a.w + 0.01) {
            // Cheap rejection: the caster's bounding sphere far from the ray.
            let middle = 0.5 * (a.xyz + b);
            let bound = 0.5 * length(b - a.xyz) + a.w;
            let along = max(dot(middle - point, towards), 0.0);
            if (!(length(point + towards * along - middle) > bound)) {
                if (segment_distance(point, end, a.xyz, b) < a.w) {
                    shadowed = true;
                }
            }
        }
    }
    return select(1.0, 0.0, shadowed);
}

@fragment
fn fragment_main(in: VertexOut) -> @location(0) vec4<f32> {
    let n = normalize(in.normal);
    // The soft light of the clean scene.
    let shade = soft_shade(n);
    let towards = light.towards_share.xyz;
    let share = light.towards_share.w;
    let reach = lit(in.world);
    // A lit ground is as bright as in the clean scene; surfaces facing the light brighter.
    let facing = min(abs(dot(n, towards)) / max(towards.z, 0.3), 1.6);
    var factor = (1.0 - share) + share * reach * facing;
    if (reach > 0.0 && n.z > 0.9 && in.world.z < 0.01) {
        for (var i = 0u; i < min(light_flow.counts.y, MAX_SPOTS); i = i + 1u) {
            let first = light.spots[2u * i];
            let second = light.spots[2u * i + 1u];
            let d = in.world.xy - first.xy;
            let along = (d.x * second.x + d.y * second.y) / first.z;
            let across = (-d.x * second.y + d.y * second.x) / first.w;
            let r2 = along * along + across * across;
            if (r2 < 1.0) {
                // A soft edge over the outer fifth.
                factor = factor * (1.0 + second.z * clamp((1.0 - r2) * 5.0, 0.0, 1.0));
            }
        }
    }
    return vec4<f32>(in.colour * shade * factor, 1.0);
}
