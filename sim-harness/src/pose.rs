//! Poses and points with their frame in the type (DESIGN.md, "Units and frames").

use glam::{Vec2, Vec3};

/// A robot pose on the field: position in metres, heading in radians from the field's +x
/// axis, counter-clockwise.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FieldPose {
    pub x: f32,
    pub y: f32,
    pub theta: f32,
}

/// A point on the ground in the field frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FieldPoint(pub Vec2);

/// A point in the robot frame: origin on the ground between the feet, x forward, y left,
/// z up.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobotPoint(pub Vec3);

impl FieldPose {
    pub const fn new(x: f32, y: f32, theta: f32) -> Self {
        Self { x, y, theta }
    }

    pub fn position(&self) -> FieldPoint {
        FieldPoint(Vec2::new(self.x, self.y))
    }

    /// A robot-frame point in the field frame (3D: z is kept).
    pub fn to_field(&self, point: RobotPoint) -> Vec3 {
        let (sin, cos) = self.theta.sin_cos();
        let p = point.0;
        Vec3::new(
            self.x + cos * p.x - sin * p.y,
            self.y + sin * p.x + cos * p.y,
            p.z,
        )
    }

    /// A field-frame point in this robot's frame (3D: z is kept).
    pub fn to_robot(&self, point: Vec3) -> RobotPoint {
        let (sin, cos) = self.theta.sin_cos();
        let d = Vec2::new(point.x - self.x, point.y - self.y);
        RobotPoint(Vec3::new(
            cos * d.x + sin * d.y,
            -sin * d.x + cos * d.y,
            point.z,
        ))
    }

    /// Moves by a robot-frame displacement (forward, left) and turn.
    pub fn moved_by(&self, forward: f32, left: f32, turn: f32) -> Self {
        let (sin, cos) = self.theta.sin_cos();
        Self {
            x: self.x + cos * forward - sin * left,
            y: self.y + sin * forward + cos * left,
            theta: wrap_angle(self.theta + turn),
        }
    }
}

/// An angle in (-pi, pi].
pub fn wrap_angle(angle: f32) -> f32 {
    let wrapped =
        (angle + core::f32::consts::PI).rem_euclid(core::f32::consts::TAU) - core::f32::consts::PI;
    if wrapped <= -core::f32::consts::PI {
        wrapped + core::f32::consts::TAU
    } else {
        wrapped
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f32::consts::FRAC_PI_2;

    #[test]
    fn robot_and_field_frames_invert_each_other() {
        let pose = FieldPose::new(1.0, -2.0, FRAC_PI_2);
        let ahead = pose.to_field(RobotPoint(Vec3::new(1.0, 0.0, 0.5)));
        assert!((ahead - Vec3::new(1.0, -1.0, 0.5)).length() < 1e-6);
        let back = pose.to_robot(ahead);
        assert!((back.0 - Vec3::new(1.0, 0.0, 0.5)).length() < 1e-6);
    }

    #[test]
    fn angles_wrap_into_half_open_range() {
        assert!((wrap_angle(3.0 * core::f32::consts::PI) - core::f32::consts::PI).abs() < 1e-5);
        assert!((wrap_angle(-FRAC_PI_2 - core::f32::consts::TAU) + FRAC_PI_2).abs() < 1e-5);
    }
}
