//! What the cameras can see of the ball and the goal from a recorded pose: the measurement
//! behind the head pitch in `config/nao_cameras.toml`.
//!
//! Geometry only (the pinhole model the renderer also uses), without the gait's head sway and
//! without occlusion by the robot's own body: a visibility share computed here is an upper
//! bound of what the rendered image shows, accurate to the sway (a few pixels).

use glam::{Vec2, Vec3};

use crate::camera_geometry::CameraGeometry;
use crate::camera_model::CameraModel;
use crate::field::FieldGeometry;
use crate::pose::FieldPose;
use crate::walk::HeadSway;

/// Heights along a goal post at which it counts as seen, metres above the ground.
const POST_SAMPLES: usize = 9;

/// What each camera shows at one pose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Visibility {
    /// The ball's centre is inside the top image.
    pub ball_in_top: bool,
    /// The ball's centre is inside the bottom image.
    pub ball_in_bottom: bool,
    /// Some part of a post of the target goal is inside the top image.
    pub target_post_in_top: bool,
}

impl Visibility {
    pub fn ball_in_either(&self) -> bool {
        self.ball_in_top || self.ball_in_bottom
    }

    /// What the cameras of `cameras` show from `robot` of a ball at `ball`, with the goal at
    /// `target_side` as the target.
    pub fn of(
        cameras: &CameraGeometry,
        field: &FieldGeometry,
        robot: FieldPose,
        ball: Vec2,
        target_side: f32,
    ) -> Self {
        let top = CameraModel::new(&cameras.top, robot, HeadSway::default());
        let bottom = CameraModel::new(&cameras.bottom, robot, HeadSway::default());
        let centre = ball.extend(field.ball_diameter / 2.0);
        let sees = |camera: &CameraModel, point: Vec3| {
            camera.project(point).is_some_and(|p| camera.contains(p))
        };
        let target_post_in_top = field.goal_post_centres(target_side).iter().any(|&(x, y)| {
            (0..POST_SAMPLES).any(|i| {
                let z = field.goal_height * i as f32 / (POST_SAMPLES - 1) as f32;
                sees(&top, Vec3::new(x, y, z))
            })
        });
        Self {
            ball_in_top: sees(&top, centre),
            ball_in_bottom: sees(&bottom, centre),
            target_post_in_top,
        }
    }
}

/// Counts of [`Visibility`] over many rows.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VisibilityShares {
    pub rows: u64,
    pub ball_in_top: u64,
    pub ball_in_bottom: u64,
    pub ball_in_either: u64,
    pub target_post_in_top: u64,
}

impl VisibilityShares {
    pub fn add(&mut self, visibility: Visibility) {
        self.rows += 1;
        self.ball_in_top += u64::from(visibility.ball_in_top);
        self.ball_in_bottom += u64::from(visibility.ball_in_bottom);
        self.ball_in_either += u64::from(visibility.ball_in_either());
        self.target_post_in_top += u64::from(visibility.target_post_in_top);
    }

    pub fn merge(&mut self, other: &Self) {
        self.rows += other.rows;
        self.ball_in_top += other.ball_in_top;
        self.ball_in_bottom += other.ball_in_bottom;
        self.ball_in_either += other.ball_in_either;
        self.target_post_in_top += other.target_post_in_top;
    }

    /// `count` as a percentage of the rows.
    pub fn percent(&self, count: u64) -> f64 {
        100.0 * count as f64 / self.rows.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight() -> CameraGeometry {
        CameraGeometry::nao()
            .with_head_pitch(0.0)
            .expect("in range")
    }

    #[test]
    fn a_ball_far_ahead_is_in_the_top_image_and_one_at_the_feet_needs_a_lowered_head() {
        let field = FieldGeometry::SPL;
        let robot = FieldPose::new(0.0, 0.0, 0.0);
        let far = Visibility::of(&straight(), &field, robot, Vec2::new(2.0, 0.0), 1.0);
        assert!(far.ball_in_top && !far.ball_in_bottom, "{far:?}");
        // A dribbled ball, 0.17 m ahead of the feet: below the straight head's bottom image.
        let at_feet = Vec2::new(0.17, 0.0);
        let straight_view = Visibility::of(&straight(), &field, robot, at_feet, 1.0);
        assert!(!straight_view.ball_in_either(), "{straight_view:?}");
        let lowered = straight().with_head_pitch(20.0).expect("in range");
        assert!(Visibility::of(&lowered, &field, robot, at_feet, 1.0).ball_in_bottom);
    }

    #[test]
    fn the_target_goal_is_seen_when_faced_and_not_from_behind() {
        let field = FieldGeometry::SPL;
        let facing = FieldPose::new(2.0, 0.0, 0.0);
        let seen = Visibility::of(&straight(), &field, facing, Vec2::new(2.3, 0.0), 1.0);
        assert!(seen.target_post_in_top);
        let away = FieldPose::new(2.0, 0.0, core::f32::consts::PI);
        let unseen = Visibility::of(&straight(), &field, away, Vec2::new(2.3, 0.0), 1.0);
        assert!(!unseen.target_post_in_top);
    }

    #[test]
    fn shares_count_rows() {
        let mut shares = VisibilityShares::default();
        shares.add(Visibility {
            ball_in_top: true,
            ..Visibility::default()
        });
        shares.add(Visibility::default());
        assert_eq!(shares.rows, 2);
        assert_eq!(shares.ball_in_either, 1);
        assert!((shares.percent(shares.ball_in_top) - 50.0).abs() < 1e-9);
    }
}
