//! Which shadow casters a lit frame's shader is given, camera by camera and frame by frame:
//! those whose shadow can fall inside the camera's view.
//!
//! The lit shader (`scene_lit.wgsl`) tests every fragment against every caster it is given,
//! and lavapipe pays for each test even where it rejects the caster early (both sides of a
//! branch run under a lane mask). A fragment is shadowed by a caster only if it lies within
//! the caster's radius of the caster's segment swept 25 m away from the light (the shader's
//! ray from the fragment towards the light is 25 m long); every fragment of a frame lies in
//! the camera's view frustum. So a caster whose swept volume lies wholly outside the frustum
//! shadows nothing in the frame, and leaving it out draws the same frame bit for bit: the
//! other casters' tests are the same arithmetic on the same values, and a fragment is
//! shadowed when any caster shadows it, in whatever order they come. The bounds below are
//! generous (a margin beyond the radius, a slack on the frustum's planes) so that rounding
//! never decides.

use glam::{Mat4, Vec3, Vec4};

use crate::conditions::Occluder;

/// How far the shader's ray from a fragment reaches towards the light, metres
/// (`scene_lit.wgsl`, `lit`).
const RAY_M: f32 = 25.0;
/// Added to a caster's radius for the bounds, metres.
const MARGIN_M: f32 = 0.1;
/// The lowest point of the scene (the floor), metres: no fragment lies below it.
const LOWEST_Z_M: f32 = 0.0;
/// Relative slack on the frustum's planes.
const SLACK: f32 = 0.02;

/// Whether `caster`'s shadow, from a light towards `towards` (unit, field frame), can fall on
/// a fragment that the camera of `view_projection` (field to clip space, depth 0..1) draws.
pub(super) fn may_shadow_view(caster: &Occluder, towards: Vec3, view_projection: &Mat4) -> bool {
    if caster.radius <= 0.0 {
        // The shader's test `distance < radius` never holds.
        return false;
    }
    let reach = caster.radius + MARGIN_M;
    // How far along the sweep a point of the caster stays above the floor: below it there is
    // nothing to shadow.
    let sweep = |point: Vec3| -> f32 {
        if towards.z > 1e-3 {
            ((point.z + reach - LOWEST_Z_M) / towards.z).clamp(0.0, RAY_M)
        } else {
            RAY_M
        }
    };
    let ends = [
        caster.a,
        caster.b,
        caster.a - towards * sweep(caster.a),
        caster.b - towards * sweep(caster.b),
    ];
    let (mut min, mut max) = (ends[0], ends[0]);
    for end in &ends[1..] {
        min = min.min(*end);
        max = max.max(*end);
    }
    let (min, max) = (min - Vec3::splat(reach), max + Vec3::splat(reach));
    let corners: [Vec4; 8] = std::array::from_fn(|i| {
        let corner = Vec3::new(
            if i & 1 == 0 { min.x } else { max.x },
            if i & 2 == 0 { min.y } else { max.y },
            if i & 4 == 0 { min.z } else { max.z },
        );
        *view_projection * corner.extend(1.0)
    });
    // Outside when every corner is beyond the same plane of the frustum.
    let beyond =
        |outside: fn(Vec4, f32) -> bool| corners.iter().all(|c| outside(*c, c.w.abs() * SLACK));
    !(beyond(|c, slack| c.x < -c.w - slack)
        || beyond(|c, slack| c.x > c.w + slack)
        || beyond(|c, slack| c.y < -c.w - slack)
        || beyond(|c, slack| c.y > c.w + slack)
        || beyond(|c, slack| c.z < -slack)
        || beyond(|c, slack| c.z > c.w + slack))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera_geometry::CameraGeometry;
    use crate::camera_model::CameraModel;
    use crate::pose::FieldPose;
    use crate::walk::HeadSway;
    use dribble_controller::CameraPosition;

    fn top_camera_at_centre_looking_along_x() -> Mat4 {
        let pose = FieldPose {
            x: 0.0,
            y: 0.0,
            theta: 0.0,
        };
        let geometry = CameraGeometry::nao();
        let mount = geometry.mount(CameraPosition::Top);
        CameraModel::new(mount, pose, HeadSway::default()).view_projection()
    }

    #[test]
    fn a_caster_in_view_is_kept_and_one_behind_the_camera_is_left_out() {
        let view = top_camera_at_centre_looking_along_x();
        let sun = Vec3::new(0.3, 0.2, 0.9).normalize();
        let post = |x: f32, y: f32| Occluder::new(Vec3::new(x, y, 0.0), Vec3::new(x, y, 0.8), 0.05);
        assert!(may_shadow_view(&post(3.0, 0.0), sun, &view));
        assert!(!may_shadow_view(&post(-4.0, 0.0), sun, &view));
        // Out of view to the left, but a low sun on that side throws its shadow into view:
        // kept; with the sun on the other side the shadow falls away from the view.
        let low_sun_left = Vec3::new(0.0, 1.0, 0.25).normalize();
        assert!(may_shadow_view(&post(3.0, 4.0), low_sun_left, &view));
        let low_sun_right = Vec3::new(0.0, -1.0, 0.25).normalize();
        assert!(!may_shadow_view(&post(3.0, 4.0), low_sun_right, &view));
        // No radius: it never shadows.
        let ball_left_out =
            Occluder::new(Vec3::new(2.0, 0.0, 0.05), Vec3::new(2.0, 0.0, 0.05), 0.0);
        assert!(!may_shadow_view(&ball_left_out, sun, &view));
    }
}
