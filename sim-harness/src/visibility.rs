//! What the cameras can see of the ball and the goal from a recorded pose: the measurement
//! behind the head pitch in `config/nao_cameras.toml`.
//!
//! Geometry only (the pinhole model the renderer also uses), without the gait's head sway and
//! without occlusion by the robot's own body: a visibility share computed here is an upper
//! bound of what the rendered image shows, accurate to the sway (a few pixels).

use glam::{Vec2, Vec3};

use crate::camera_geometry::CameraGeometry;
use crate::camera_model::CameraModel;
use crate::conditions::Occluder;
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

/// The least unoccluded part of the ball inside an image that a detector finds, in pixels
/// of the controller's thumbnail (4x4 camera pixels each): 2.5, a disc about 1.8 thumbnail
/// pixels (7 camera pixels) wide, the whole ball 8 m from the top camera. Measured
/// (`sim-harness/tests/conditions.rs`,
/// `the_detector_threshold_is_where_the_ball_still_shows_in_the_thumbnail`): from that size
/// up, wherever the ball falls on the thumbnail's grid, its brightest thumbnail pixel rises
/// at least 17 levels over the carpet without it, more than twice the noise a thumbnail
/// pixel keeps at `noise:3`; at 2.2 pixels (8.6 m) it can rise only 9.
pub const MIN_VISIBLE_THUMBNAIL_PIXELS: f32 = 2.5;
/// Camera pixels per thumbnail pixel.
const THUMBNAIL_BLOCK_PIXELS: f32 = 16.0;

/// What a detector would see of the ball in one camera: the area (in thumbnail pixels) of
/// its disc that is inside the image and not hidden behind an occluder (goal posts and bars,
/// robots, people), sampled on a disc of 61 points facing the camera.
pub fn visible_ball_thumbnail_pixels(
    camera: &CameraModel,
    centre: Vec3,
    radius: f32,
    occluders: &[Occluder],
) -> f32 {
    let to_ball = centre - camera.position;
    let distance = to_ball.length();
    if distance <= radius {
        return 0.0;
    }
    let view = to_ball / distance;
    let across = view.cross(Vec3::Z).normalize_or(Vec3::Y);
    let up = across.cross(view);
    // The disc's radius in camera pixels (the pinhole's scale at the ball's depth).
    let depth = camera.to_camera(centre).x;
    if depth <= radius {
        return 0.0;
    }
    let radius_px = camera.fx * radius / depth;
    let (mut seen, mut samples) = (0u32, 0u32);
    for ring in 0..=4 {
        let r = ring as f32 / 4.0;
        let count = if ring == 0 { 1 } else { 6 * ring };
        for k in 0..count {
            let angle = k as f32 / count as f32 * core::f32::consts::TAU;
            // A point of the ball's visible face (lifted toward the camera onto the sphere).
            let offset = (across * angle.cos() + up * angle.sin()) * (r * 0.95 * radius);
            let lift = -view * (radius * radius - offset.length_squared()).max(0.0).sqrt();
            let point = centre + offset + lift;
            samples += 1;
            let inside = camera.project(point).is_some_and(|p| camera.contains(p));
            if inside && !occluders.iter().any(|o| o.blocks(camera.position, point)) {
                seen += 1;
            }
        }
    }
    let area_px = core::f32::consts::PI * radius_px * radius_px;
    area_px * seen as f32 / samples as f32 / THUMBNAIL_BLOCK_PIXELS
}

/// How a teacher decides that a camera sees the ball.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum SightingRule {
    /// Its centre projects inside the image (no occlusion, no least size): the observable
    /// teacher's rule, kept for its rows.
    #[default]
    CentreInImage,
    /// As a detector: at least [`MIN_VISIBLE_THUMBNAIL_PIXELS`] of it unoccluded inside the
    /// image, never through a goal post, a bar, a robot or a person (`occluders`).
    Detector { occluders: Vec<Occluder> },
}

impl SightingRule {
    /// Whether the cameras of `cameras` at `robot` see a ball at `ball` under this rule.
    pub fn sees_ball(
        &self,
        cameras: &CameraGeometry,
        field: &FieldGeometry,
        robot: FieldPose,
        ball: Vec2,
    ) -> bool {
        match self {
            Self::CentreInImage => {
                Visibility::of(cameras, field, robot, ball, 1.0).ball_in_either()
            }
            Self::Detector { occluders } => {
                let radius = field.ball_diameter / 2.0;
                let centre = ball.extend(radius);
                [&cameras.top, &cameras.bottom].into_iter().any(|mount| {
                    let camera = CameraModel::new(mount, robot, HeadSway::default());
                    visible_ball_thumbnail_pixels(&camera, centre, radius, occluders)
                        >= MIN_VISIBLE_THUMBNAIL_PIXELS
                })
            }
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
    fn a_detector_loses_a_far_or_hidden_ball_that_the_centre_rule_sees() {
        let field = FieldGeometry::SPL;
        let cameras = straight();
        let robot = FieldPose::new(-4.0, 0.0, 0.0);
        let detector = SightingRule::Detector {
            occluders: crate::conditions::venue::goal_occluders(&field),
        };
        let near = Vec2::new(-2.0, 0.0);
        assert!(detector.sees_ball(&cameras, &field, robot, near));
        assert!(SightingRule::CentreInImage.sees_ball(&cameras, &field, robot, near));
        // 12 m away: in the image, but under two thumbnail pixels.
        let far_robot = FieldPose::new(-7.5, 0.0, 0.0);
        let far = Vec2::new(4.4, 0.0);
        assert!(SightingRule::CentreInImage.sees_ball(&cameras, &field, far_robot, far));
        assert!(!detector.sees_ball(&cameras, &field, far_robot, far));
        // Behind a post, seen along the post's line.
        let [(px, py), _] = field.goal_post_centres(1.0);
        let behind_post = Vec2::new(px + 0.3, py);
        let lined_up = FieldPose::new(2.0, py, 0.0);
        assert!(SightingRule::CentreInImage.sees_ball(&cameras, &field, lined_up, behind_post));
        assert!(!detector.sees_ball(&cameras, &field, lined_up, behind_post));
        // A robot standing in between hides it too.
        let robot_between = crate::conditions::Occluder::new(
            Vec3::new(-3.0, 0.0, 0.08),
            Vec3::new(-3.0, 0.0, 0.38),
            0.1,
        );
        let blocked = SightingRule::Detector {
            occluders: vec![robot_between],
        };
        assert!(!blocked.sees_ball(&cameras, &field, robot, near));
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
