//! A head camera at one instant: pose in the field frame and pinhole intrinsics. It
//! projects field points to pixels (for tests and plots) and gives the renderer its
//! view-projection matrix; both use the same numbers, so what is drawn is where the
//! pinhole model says.

use glam::{Mat3, Mat4, Quat, Vec2, Vec3, Vec4};

use crate::camera_geometry::CameraMount;
use crate::pose::{FieldPose, RobotPoint};
use crate::walk::HeadSway;

/// Near and far clipping planes of the rendered cameras, metres.
const NEAR: f32 = 0.02;
const FAR: f32 = 40.0;

/// A camera placed in the field. Its own frame: x along the optical axis, y left, z up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraModel {
    /// Optical centre in the field frame.
    pub position: Vec3,
    /// Rotation from the camera frame to the field frame.
    pub rotation: Quat,
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
}

/// A pixel position: `u` right, `v` down, pixel `(i, j)` covers `[i, i+1) x [j, j+1)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pixel {
    pub u: f32,
    pub v: f32,
}

impl CameraModel {
    /// The camera of `mount` on a robot at `pose` whose gait moved its head by `sway`.
    pub fn new(mount: &CameraMount, pose: FieldPose, sway: HeadSway) -> Self {
        let position = pose.to_field(RobotPoint(Vec3::new(
            mount.forward_m,
            sway.lateral_m,
            mount.height_m,
        )));
        let rotation = Quat::from_rotation_z(pose.theta)
            * Quat::from_rotation_x(sway.roll_rad)
            * Quat::from_rotation_y(mount.pitch_down_deg.to_radians() + sway.pitch_rad);
        Self {
            position,
            rotation,
            width: mount.width,
            height: mount.height,
            fx: mount.fx(),
            fy: mount.fy(),
        }
    }

    /// A field point in the camera frame.
    pub fn to_camera(&self, point: Vec3) -> Vec3 {
        self.rotation.inverse() * (point - self.position)
    }

    /// Where the pinhole model puts a field point in the image, if it is in front of the
    /// camera (it may still be outside the image).
    pub fn project(&self, point: Vec3) -> Option<Pixel> {
        let c = self.to_camera(point);
        if c.x <= NEAR {
            return None;
        }
        Some(Pixel {
            u: self.width as f32 / 2.0 - self.fx * c.y / c.x,
            v: self.height as f32 / 2.0 - self.fy * c.z / c.x,
        })
    }

    pub fn contains(&self, pixel: Pixel) -> bool {
        (0.0..self.width as f32).contains(&pixel.u) && (0.0..self.height as f32).contains(&pixel.v)
    }

    /// The field-frame-to-clip-space matrix for rendering (wgpu conventions: depth 0..1).
    pub fn view_projection(&self) -> Mat4 {
        // Camera frame (x forward, y left, z up) to view space (x right, y up, z backward).
        let camera_to_view = Mat4::from_mat3(Mat3::from_cols(
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ));
        let field_to_camera =
            Mat4::from_quat(self.rotation.inverse()) * Mat4::from_translation(-self.position);
        // Right-handed perspective with depth 0..1, separate focal lengths for x and y.
        let depth = FAR / (NEAR - FAR);
        let projection = Mat4::from_cols(
            Vec4::new(2.0 * self.fx / self.width as f32, 0.0, 0.0, 0.0),
            Vec4::new(0.0, 2.0 * self.fy / self.height as f32, 0.0, 0.0),
            Vec4::new(0.0, 0.0, depth, -1.0),
            Vec4::new(0.0, 0.0, depth * NEAR, 0.0),
        );
        projection * camera_to_view * field_to_camera
    }

    /// The ground point (z = 0) seen at `pixel`, if the ray through it meets the ground ahead.
    pub fn ground_point(&self, pixel: Pixel) -> Option<Vec2> {
        let direction_camera = Vec3::new(
            1.0,
            (self.width as f32 / 2.0 - pixel.u) / self.fx,
            (self.height as f32 / 2.0 - pixel.v) / self.fy,
        );
        let direction = self.rotation * direction_camera;
        if direction.z >= -1e-6 {
            return None;
        }
        let t = -self.position.z / direction.z;
        let hit = self.position + direction * t;
        Some(Vec2::new(hit.x, hit.y))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera_geometry::CameraGeometry;

    fn top_at_origin() -> CameraModel {
        CameraModel::new(
            &CameraGeometry::nao().top,
            FieldPose::default(),
            HeadSway::default(),
        )
    }

    #[test]
    fn a_point_on_the_optical_axis_projects_to_the_image_centre() {
        let camera = top_at_origin();
        let axis = camera.rotation * Vec3::X;
        let pixel = camera
            .project(camera.position + axis * 3.0)
            .expect("in front");
        assert!(
            (pixel.u - 320.0).abs() < 1e-3 && (pixel.v - 240.0).abs() < 1e-3,
            "{pixel:?}"
        );
    }

    #[test]
    fn points_to_the_left_appear_left_and_points_above_appear_higher() {
        let camera = top_at_origin();
        let left = camera.project(Vec3::new(3.0, 1.0, 0.5)).expect("in front");
        let up = camera.project(Vec3::new(3.0, 0.0, 1.5)).expect("in front");
        assert!(left.u < 320.0);
        assert!(up.v < 240.0);
        assert!(
            camera.project(Vec3::new(-3.0, 0.0, 0.5)).is_none(),
            "behind"
        );
    }

    #[test]
    fn the_render_matrix_agrees_with_the_pinhole_model() {
        let camera = CameraModel::new(
            &CameraGeometry::nao().bottom,
            FieldPose::new(1.0, -0.5, 0.7),
            HeadSway {
                lateral_m: 0.01,
                roll_rad: 0.02,
                pitch_rad: -0.01,
            },
        );
        for point in [Vec3::new(1.4, -0.3, 0.0), Vec3::new(1.2, -0.1, 0.05)] {
            let pixel = camera.project(point).expect("in front");
            let clip = camera.view_projection() * point.extend(1.0);
            let ndc = clip.truncate() / clip.w;
            let u = (ndc.x + 1.0) / 2.0 * camera.width as f32;
            let v = (1.0 - ndc.y) / 2.0 * camera.height as f32;
            assert!(
                (u - pixel.u).abs() < 1e-2 && (v - pixel.v).abs() < 1e-2,
                "{u},{v} vs {pixel:?}"
            );
            assert!((0.0..=1.0).contains(&ndc.z));
        }
    }

    #[test]
    fn ground_point_inverts_projection_on_the_ground() {
        let camera = CameraModel::new(
            &CameraGeometry::nao().bottom,
            FieldPose::new(0.0, 0.0, 0.3),
            HeadSway::default(),
        );
        let spot = Vec3::new(0.4, 0.1, 0.0);
        let pixel = camera.project(spot).expect("in front");
        let back = camera.ground_point(pixel).expect("on the ground");
        assert!((back - spot.truncate()).length() < 1e-4, "{back}");
    }
}
