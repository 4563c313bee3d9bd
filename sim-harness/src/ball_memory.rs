//! What the observable teacher knows of the ball: what its cameras show, and where it last
//! saw it (DESIGN.md, "Teachers").
//!
//! A B-Human-like ball model without the filter: while the ball is inside either camera's
//! image its position is known; when it leaves the images, its last seen position stays (in
//! the field frame, which the robot's own pose carries as odometry would); the memory is
//! dropped when the remembered position is itself inside an image and the ball is not there
//! (the ball moved), or after [`BallMemory::FORGET_AFTER_S`]. Without a position the
//! teacher searches by turning toward the side where it last saw the ball, or, before the
//! first sighting, to the left ([`BallMemory::FIRST_SEARCH_TURN`]): a choice the images
//! explain, where the paper's expert turned toward a ball it knew from ground truth.

use glam::{Vec2, Vec3};

use crate::camera_geometry::CameraGeometry;
use crate::camera_model::CameraModel;
use crate::conditions::Occluder;
use crate::conditions::venue::goal_occluders;
use crate::field::FieldGeometry;
use crate::pose::FieldPose;
use crate::visibility::SightingRule;
use crate::walk::HeadSway;

/// What the teacher believes about the ball at one decision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BallBelief {
    /// Seen now, or remembered: a position in the field frame.
    At(Vec2),
    /// Not known: search by turning this way (+1 left, -1 right).
    Search { turn: f32 },
}

/// The ball as the robot's cameras let it know it.
#[derive(Clone, Debug)]
pub struct BallMemory {
    cameras: CameraGeometry,
    field: FieldGeometry,
    /// Where and when (simulated seconds) the ball was last seen.
    last_seen: Option<(Vec2, f64)>,
    /// The side (sign of the bearing, robot frame) the ball was on when last seen.
    last_side: Option<f32>,
    /// When a camera counts as seeing the ball.
    rule: SightingRule,
}

impl BallMemory {
    /// Before the first sighting, the search turns left.
    pub const FIRST_SEARCH_TURN: f32 = 1.0;
    /// A memory older than this is dropped (the ball may have rolled away).
    pub const FORGET_AFTER_S: f64 = 10.0;

    pub fn new(cameras: CameraGeometry, field: FieldGeometry) -> Self {
        Self {
            cameras,
            field,
            last_seen: None,
            last_side: None,
            rule: SightingRule::CentreInImage,
        }
    }

    /// A memory whose sightings are a detector's: enough of the ball unoccluded in an image,
    /// never through the goals' posts and bars (more occluders with [`Self::see_among`]).
    pub fn detecting(cameras: CameraGeometry, field: FieldGeometry) -> Self {
        Self {
            rule: SightingRule::Detector {
                occluders: goal_occluders(&field),
            },
            ..Self::new(cameras, field)
        }
    }

    /// For a detector's memory: what stands about in this episode (robots, people) hides
    /// the ball too, besides the goals.
    pub fn see_among(&mut self, occluders: &[Occluder]) {
        if let SightingRule::Detector { occluders: current } = &mut self.rule {
            *current = goal_occluders(&self.field);
            current.extend_from_slice(occluders);
        }
    }

    /// Starts an episode: nothing seen yet.
    pub fn reset(&mut self) {
        self.last_seen = None;
        self.last_side = None;
    }

    /// Updates the memory with what the cameras show from `robot` at `time_s` of the ball at
    /// `ball` (the truth, used only through the images' geometry), and says what is known.
    pub fn perceive(&mut self, robot: FieldPose, ball: Vec2, time_s: f64) -> BallBelief {
        let seen = self.sees(robot, ball);
        if seen {
            self.remember(robot, ball, time_s);
            return BallBelief::At(ball);
        }
        if let Some((remembered, when)) = self.last_seen {
            let should_see = self.sees(robot, remembered);
            if should_see || time_s - when > Self::FORGET_AFTER_S {
                self.last_seen = None;
            } else {
                return BallBelief::At(remembered);
            }
        }
        BallBelief::Search {
            turn: self.last_side.unwrap_or(Self::FIRST_SEARCH_TURN),
        }
    }

    /// Whether the middle of the target goal's mouth (half the posts' height) is in the top
    /// camera's image from `robot`: what the orbiting teacher needs to see before it turns
    /// toward the goal. The middle, not a post: close to the goal a post at the image's edge
    /// lies far off the goal's direction, and turning toward the goal would lose it again.
    pub fn target_goal_in_view(&self, robot: FieldPose, target_side: f32) -> bool {
        let top = CameraModel::new(&self.cameras.top, robot, HeadSway::default());
        let middle = Vec3::new(
            target_side * self.field.length / 2.0,
            0.0,
            self.field.goal_height / 2.0,
        );
        top.project(middle).is_some_and(|p| top.contains(p))
    }

    fn sees(&self, robot: FieldPose, ball: Vec2) -> bool {
        self.rule.sees_ball(&self.cameras, &self.field, robot, ball)
    }

    fn remember(&mut self, robot: FieldPose, ball: Vec2, time_s: f64) {
        self.last_seen = Some((ball, time_s));
        let local = robot.to_robot(ball.extend(0.0)).0;
        self.last_side = Some(if local.y >= 0.0 { 1.0 } else { -1.0 });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn memory() -> BallMemory {
        BallMemory::new(CameraGeometry::nao(), FieldGeometry::SPL)
    }

    #[test]
    fn an_unseen_ball_is_searched_for_to_the_left_whichever_side_it_is_on() {
        let robot = FieldPose::new(0.0, 0.0, 0.0);
        for ball in [
            Vec2::new(0.0, 2.0),
            Vec2::new(0.0, -2.0),
            Vec2::new(-2.0, 0.1),
        ] {
            assert_eq!(
                memory().perceive(robot, ball, 0.0),
                BallBelief::Search { turn: 1.0 },
                "{ball}"
            );
        }
    }

    #[test]
    fn a_seen_ball_is_known_and_remembered_when_it_leaves_the_images() {
        let mut memory = memory();
        let ball = Vec2::new(2.0, -0.3);
        let ahead = FieldPose::new(0.0, 0.0, 0.0);
        assert_eq!(memory.perceive(ahead, ball, 0.0), BallBelief::At(ball));
        // Turned away: the ball is behind, still remembered where it was.
        let away = FieldPose::new(0.0, 0.0, 3.0);
        assert_eq!(memory.perceive(away, ball, 1.0), BallBelief::At(ball));
        // Forgotten after a while: search toward the side it was last seen on (right).
        assert_eq!(
            memory.perceive(away, ball, 1.0 + BallMemory::FORGET_AFTER_S + 0.1),
            BallBelief::Search { turn: -1.0 }
        );
    }

    #[test]
    fn a_remembered_ball_that_is_not_where_it_should_be_is_forgotten() {
        let mut memory = memory();
        let ahead = FieldPose::new(0.0, 0.0, 0.0);
        assert_eq!(
            memory.perceive(ahead, Vec2::new(2.0, 0.3), 0.0),
            BallBelief::At(Vec2::new(2.0, 0.3))
        );
        // The ball rolled behind the robot while it looked at the old place.
        assert_eq!(
            memory.perceive(ahead, Vec2::new(-1.5, 0.0), 0.5),
            BallBelief::Search { turn: 1.0 }
        );
    }
}
