//! The teacher: a B-Human-style striker. A small state machine over the robot's pose and
//! the ball's: search (turn until the ball is in the top camera's view), approach (walk to
//! a point behind the ball on the ball-to-goal line, going around the ball if the robot is
//! on its wrong side), align (circle the ball until facing the goal), dribble (walk through
//! the ball toward the goal, correcting sideways).
//!
//! Five teachers play it (DESIGN.md, "Teachers"; [`Teacher`]): the paper's reads the ball's
//! true position always, and so searches by turning toward a ball no image shows; the
//! observable one knows the ball only through its cameras ([`BallMemory`]), remembers where
//! it last saw it, and searches to the side it last saw it on, or to the left before the
//! first sighting. The orbiting one is the observable one that also leaves the goal's
//! direction out of its approach and alignment while no camera shows the target goal: it
//! walks straight to the ball, circles it to the left until the middle of the goal's mouth is
//! in the top image, then turns toward it ([`ORBIT_TURN`]). The detector teacher is the
//! observable one seeing the ball as a detector would; the one-way detector teacher also goes
//! around the ball always clockwise where it must go around it ([`ONE_WAY_STEP`]), a direction
//! the images explain where the side of the ball-to-goal line is not. All take their own
//! pose from ground truth, standing in for self-localisation as in the paper; which goal is
//! the target (the one on the ball's half) stays ground truth for all, as a symmetric field's
//! images cannot tell the two goals apart.

use core::f32::consts::PI;

use dribble_controller::SpeedCommand;
use glam::Vec2;

use crate::ball_memory::{BallBelief, BallMemory};
use crate::camera_geometry::CameraGeometry;
use crate::conditions::EpisodeLook;
use crate::field::FieldGeometry;
use crate::pose::{FieldPose, wrap_angle};

/// Which teacher labels and drives (DESIGN.md, "Teachers").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Teacher {
    /// The paper's expert: the ball's true position at every decision.
    #[default]
    Paper,
    /// Only what the cameras show, and where the ball was last seen.
    Observable,
    /// The observable teacher, and the goal's direction only while the top camera shows the
    /// target goal: straight to the ball, then around it to the left until the goal is seen.
    Orbit,
    /// The observable teacher seeing as a detector does: the ball only while at least
    /// `visibility::MIN_VISIBLE_THUMBNAIL_PIXELS` of it are unoccluded inside an image, never
    /// through a goal post, a bar, a robot or a person.
    Detector,
    /// The detector teacher going around the ball always clockwise, seen from above, where it
    /// must go around it to get behind it, instead of on the side of the ball-to-goal line it
    /// stands on: facing a plain wall with the ball at its feet, the images cannot show which
    /// side that is (`dribble_models.one_way_detour` relabels recorded detector rows so).
    DetectorOneWay,
}

impl Teacher {
    pub const ALL: [Self; 5] = [
        Self::Paper,
        Self::Observable,
        Self::Orbit,
        Self::Detector,
        Self::DetectorOneWay,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Paper => "paper",
            Self::Observable => "observable",
            Self::Orbit => "orbit",
            Self::Detector => "detector",
            Self::DetectorOneWay => "detector-one-way",
        }
    }
}

impl std::fmt::Display for Teacher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Teacher {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|teacher| teacher.name() == text)
            .ok_or_else(|| {
                format!(
                    "unknown teacher {text:?}: paper, observable, orbit, detector or detector-one-way"
                )
            })
    }
}

/// The expert's sub-behaviour, recorded with every command (DESIGN.md, "Dataset").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Phase {
    Search = 0,
    Approach = 1,
    Align = 2,
    Dribble = 3,
}

impl Phase {
    pub const ALL: [Self; 4] = [Self::Search, Self::Approach, Self::Align, Self::Dribble];

    pub fn name(self) -> &'static str {
        match self {
            Self::Search => "search",
            Self::Approach => "approach",
            Self::Align => "align",
            Self::Dribble => "dribble",
        }
    }
}

/// The expert's tuning. Distances in metres, angles in radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExpertConfig {
    /// Half the angle around the heading within which the ball counts as seen.
    pub view_half_angle: f32,
    /// How far behind the ball (away from the goal) the approach point lies.
    pub approach_distance: f32,
    /// Within this of the approach point, the expert starts aligning.
    pub approach_tolerance: f32,
    /// Distance kept from the ball when going around it.
    pub detour_radius: f32,
    /// Heading error to the goal below which dribbling starts.
    pub align_tolerance: f32,
    /// Lateral offset of the ball (robot frame) beyond which a dribble is given up.
    pub dribble_lateral_limit: f32,
    /// Forward speed while dribbling, normalised.
    pub dribble_speed: f32,
}

impl Default for ExpertConfig {
    fn default() -> Self {
        Self {
            view_half_angle: 25f32.to_radians(),
            approach_distance: 0.28,
            approach_tolerance: 0.08,
            detour_radius: 0.4,
            align_tolerance: 10f32.to_radians(),
            dribble_lateral_limit: 0.12,
            dribble_speed: 0.9,
        }
    }
}

/// The state of the world at a decision: the truth (the observable teacher reads the ball
/// only through its cameras' geometry).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundTruth {
    pub robot: FieldPose,
    pub ball: Vec2,
    /// +1 to attack the goal at +x, -1 for the one at -x.
    pub target_side: f32,
    /// Simulated time, seconds since the episode's start.
    pub time_s: f64,
}

/// How the orbiting teacher turns while it circles the ball without the goal in view
/// (normalised turn; positive is left): always the same way, so that the images explain it,
/// and slowly enough that the walk's sideways speed keeps up ([`orbit_sidestep`]). At the
/// walk's full turn rate (1 rad/s) the ball would need 0.28 m/s sideways against the walk's
/// 0.15: the robot turned almost in place, the ball left both images in a fifth of the
/// orbiting rows, and a CNN cloned from that scored 4 of 20 test goals.
pub const ORBIT_TURN: f32 = 0.45;

/// The sideways step (normalised, negative is right) that circles a ball at `distance` metres
/// ahead while turning at [`ORBIT_TURN`]: the turn rate times the distance, over the walk's
/// top sideways speed.
pub fn orbit_sidestep(distance: f32) -> f32 {
    let limits = dribble_controller::WalkLimits::default();
    -(ORBIT_TURN * limits.max_turn.0 * distance / limits.max_left.0)
}

/// How far clockwise around the ball, radians, the one-way detour walks toward
/// ([`Teacher::DetectorOneWay`]; `dribble_models.one_way_detour`'s `step`).
pub const ONE_WAY_STEP: f32 = PI / 3.0;

/// The striker.
#[derive(Clone, Debug)]
pub struct Expert {
    config: ExpertConfig,
    field: FieldGeometry,
    phase: Phase,
    /// The observable teachers' knowledge of the ball; `None` for the paper's.
    memory: Option<BallMemory>,
    /// Which teacher this is: the orbiting one leaves the goal's direction out until the top
    /// camera shows the goal, the one-way one goes around the ball always clockwise.
    teacher: Teacher,
}

impl Expert {
    /// The paper's expert (ground truth).
    pub fn new(config: ExpertConfig, field: FieldGeometry) -> Self {
        Self {
            config,
            field,
            phase: Phase::Search,
            memory: None,
            teacher: Teacher::Paper,
        }
    }

    /// The teacher `teacher`; the observable one sees through `cameras`.
    pub fn teaching(
        teacher: Teacher,
        config: ExpertConfig,
        field: FieldGeometry,
        cameras: CameraGeometry,
    ) -> Self {
        let mut expert = Self::new(config, field);
        expert.memory = match teacher {
            Teacher::Paper => None,
            Teacher::Detector | Teacher::DetectorOneWay => {
                Some(BallMemory::detecting(cameras, field))
            }
            Teacher::Observable | Teacher::Orbit => Some(BallMemory::new(cameras, field)),
        };
        expert.teacher = teacher;
        expert
    }

    pub fn teacher(&self) -> Teacher {
        self.teacher
    }

    /// The orbiting teacher: the goal's direction only while the top camera shows the goal.
    fn orbits(&self) -> bool {
        self.teacher == Teacher::Orbit
    }

    /// Starts an episode seen through `look`: a detector's sightings are hidden by what
    /// stands about in it too.
    pub fn see_among(&mut self, look: &EpisodeLook) {
        if let Some(memory) = &mut self.memory {
            memory.see_among(&look.layout.occluders());
        }
    }

    pub fn config(&self) -> &ExpertConfig {
        &self.config
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Starts an episode afresh.
    pub fn reset(&mut self) {
        self.phase = Phase::Search;
        if let Some(memory) = &mut self.memory {
            memory.reset();
        }
    }

    /// The next command, and the phase that produced it.
    pub fn decide(&mut self, truth: &GroundTruth) -> (SpeedCommand, Phase) {
        let Some(memory) = &mut self.memory else {
            return self.decide_knowing(truth);
        };
        match memory.perceive(truth.robot, truth.ball, truth.time_s) {
            BallBelief::At(ball) => self.decide_knowing(&GroundTruth { ball, ..*truth }),
            BallBelief::Search { turn } => {
                self.phase = Phase::Search;
                (command(0.0, 0.0, turn), Phase::Search)
            }
        }
    }

    /// The state machine on a ball position taken as known.
    fn decide_knowing(&mut self, truth: &GroundTruth) -> (SpeedCommand, Phase) {
        let robot = truth.robot;
        let ball = robot.to_robot(truth.ball.extend(0.0)).0.truncate();
        let ball_bearing = ball.y.atan2(ball.x);
        let goal = Vec2::new(truth.target_side * self.field.length / 2.0, 0.0);
        let to_goal = (goal - truth.ball).normalize_or(Vec2::X);
        let goal_heading = to_goal.y.atan2(to_goal.x);
        let heading_error = wrap_angle(goal_heading - robot.theta);
        // Where it walks to: behind the ball on the ball-to-goal line, or (orbiting) the
        // point at the approach distance on its own side of the ball.
        let stand_off = if self.orbits() {
            (truth.ball - Vec2::new(robot.x, robot.y)).normalize_or(Vec2::X)
        } else {
            to_goal
        };
        let behind_ball = truth.ball - stand_off * self.config.approach_distance;
        let behind = robot.to_robot(behind_ball.extend(0.0)).0.truncate();

        self.phase = self.next_phase(ball, ball_bearing, behind, heading_error);
        let command = match self.phase {
            Phase::Search => search(ball_bearing),
            Phase::Approach if self.orbits() => walk_towards(behind, ball_bearing, 1.0),
            Phase::Approach => self.approach(truth, ball, behind_ball, to_goal),
            // The orbiting teacher knows the goal's direction only while the goal is in view.
            Phase::Align if !self.orbits() || self.goal_in_view(truth) => {
                let turn = (heading_error * 1.6).clamp(-1.0, 1.0);
                self.align(ball, behind, turn, -turn * 0.35)
            }
            Phase::Align => self.align(
                ball,
                behind,
                ORBIT_TURN,
                orbit_sidestep(self.config.approach_distance),
            ),
            Phase::Dribble => self.dribble(truth, ball, goal),
        };
        (command, self.phase)
    }

    /// Whether the top camera shows the target goal (the orbiting teacher's test).
    fn goal_in_view(&self, truth: &GroundTruth) -> bool {
        self.memory
            .as_ref()
            .is_some_and(|memory| memory.target_goal_in_view(truth.robot, truth.target_side))
    }

    fn next_phase(&self, ball: Vec2, ball_bearing: f32, behind: Vec2, heading_error: f32) -> Phase {
        let c = &self.config;
        let seen = ball_bearing.abs() < c.view_half_angle;
        let lost = ball_bearing.abs() > c.view_half_angle * 2.4 && ball.length() > 0.5;
        match self.phase {
            Phase::Search if seen => Phase::Approach,
            Phase::Search => Phase::Search,
            _ if lost => Phase::Search,
            Phase::Approach if behind.length() < c.approach_tolerance => Phase::Align,
            Phase::Approach => Phase::Approach,
            Phase::Align if behind.length() > c.approach_tolerance * 3.0 => Phase::Approach,
            Phase::Align
                if heading_error.abs() < c.align_tolerance
                    && ball.y.abs() < c.dribble_lateral_limit * 0.5 =>
            {
                Phase::Dribble
            }
            Phase::Align => Phase::Align,
            Phase::Dribble
                if ball.y.abs() > c.dribble_lateral_limit
                    || ball.x < 0.05
                    || ball.x > 0.7
                    || heading_error.abs() > 3.0 * c.align_tolerance =>
            {
                Phase::Approach
            }
            Phase::Dribble => Phase::Dribble,
        }
    }

    /// Walk to the point behind the ball, going around the ball when the robot is on its
    /// goal side, facing the ball.
    fn approach(
        &self,
        truth: &GroundTruth,
        ball: Vec2,
        behind_ball: Vec2,
        to_goal: Vec2,
    ) -> SpeedCommand {
        let robot = truth.robot;
        let position = Vec2::new(robot.x, robot.y);
        let from_ball = position - truth.ball;
        // Ahead of the ball (on the goal side) or level with it: go around, not through.
        let along = from_ball.dot(to_goal);
        let target = if along > -self.config.approach_distance * 0.5
            && from_ball.length() < self.config.detour_radius * 2.5
        {
            if self.teacher == Teacher::DetectorOneWay {
                // A sixth of a turn clockwise along the detour circle.
                let around =
                    Vec2::from_angle(-ONE_WAY_STEP).rotate(from_ball.normalize_or(-to_goal));
                truth.ball + around * self.config.detour_radius
            } else {
                // Around the side of the ball-to-goal line the robot is on.
                let side = if to_goal.perp_dot(from_ball) >= 0.0 {
                    to_goal.perp()
                } else {
                    -to_goal.perp()
                };
                truth.ball + (side - to_goal * 0.6).normalize_or_zero() * self.config.detour_radius
            }
        } else {
            behind_ball
        };
        let local = robot.to_robot(target.extend(0.0)).0.truncate();
        let face = ball.y.atan2(ball.x);
        walk_towards(local, face, 1.0)
    }

    /// Circle the ball: turn by `turn` (toward the goal), step sideways by `sidestep`
    /// (opposite to the turn, so that the robot orbits the ball) plus what keeps the ball
    /// centred ahead, and keep the approach distance.
    fn align(&self, ball: Vec2, behind: Vec2, turn: f32, sidestep: f32) -> SpeedCommand {
        let distance_error = ball.x - self.config.approach_distance;
        let forward = (distance_error * 3.0).clamp(-0.5, 0.5);
        let left = (sidestep + ball.y * 4.0 + behind.y * 2.0).clamp(-1.0, 1.0);
        command(forward, left, turn)
    }

    /// Walk through the ball toward the goal, keeping it in front of the feet.
    fn dribble(&self, truth: &GroundTruth, ball: Vec2, goal: Vec2) -> SpeedCommand {
        let robot = truth.robot;
        let goal_local = robot.to_robot(goal.extend(0.0)).0.truncate();
        let goal_bearing = goal_local.y.atan2(goal_local.x);
        let turn = (goal_bearing * 1.5).clamp(-0.6, 0.6);
        let left = (ball.y * 5.0).clamp(-0.6, 0.6);
        command(self.config.dribble_speed, left, turn)
    }
}

/// Turn on the spot toward the ball (ground truth tells which way is shorter).
fn search(ball_bearing: f32) -> SpeedCommand {
    command(0.0, 0.0, if ball_bearing >= 0.0 { 1.0 } else { -1.0 })
}

/// Omnidirectional walk to `target` (robot frame) while turning to `face` (radians).
fn walk_towards(target: Vec2, face: f32, speed: f32) -> SpeedCommand {
    let distance = target.length();
    let direction = target.normalize_or_zero();
    let gain = (distance * 2.5).min(1.0) * speed;
    // Walking forward is faster than sideways: prefer it when the target is ahead.
    let turn = (face * 1.5).clamp(-1.0, 1.0);
    let slow_for_turn = 1.0 - 0.6 * (face.abs() / PI).min(1.0);
    command(
        direction.x * gain * slow_for_turn,
        direction.y * gain * 1.2,
        turn,
    )
}

fn command(forward: f32, left: f32, turn: f32) -> SpeedCommand {
    SpeedCommand::new(forward, left, turn).unwrap_or(SpeedCommand::STOP)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(robot: FieldPose, ball: Vec2) -> GroundTruth {
        GroundTruth {
            robot,
            ball,
            target_side: 1.0,
            time_s: 0.0,
        }
    }

    #[test]
    fn the_observable_teacher_searches_left_for_a_ball_no_camera_shows() {
        let mut expert = Expert::teaching(
            Teacher::Observable,
            ExpertConfig::default(),
            FieldGeometry::SPL,
            CameraGeometry::nao(),
        );
        assert_eq!(expert.teacher(), Teacher::Observable);
        // The ball to the right and behind: the paper's expert turns right, this one left.
        let (command, phase) =
            expert.decide(&truth(FieldPose::new(0.0, 0.0, 0.0), Vec2::new(-1.0, -2.0)));
        assert_eq!(phase, Phase::Search);
        assert_eq!(command.as_array(), [0.0, 0.0, 1.0]);
        let mut paper = Expert::new(ExpertConfig::default(), FieldGeometry::SPL);
        let (command, _) =
            paper.decide(&truth(FieldPose::new(0.0, 0.0, 0.0), Vec2::new(-1.0, -2.0)));
        assert_eq!(command.as_array(), [0.0, 0.0, -1.0]);
        // A ball in view is approached as the paper's expert approaches it.
        let seen = truth(FieldPose::new(0.0, 0.0, 0.0), Vec2::new(2.0, 0.1));
        assert_eq!(expert.decide(&seen), paper.decide(&seen));
    }

    #[test]
    fn the_orbiting_teacher_circles_left_until_the_goal_is_in_view_then_turns_to_it() {
        let orbiting = || {
            Expert::teaching(
                Teacher::Orbit,
                ExpertConfig::default(),
                FieldGeometry::SPL,
                CameraGeometry::nao(),
            )
        };
        let settled = |expert: &mut Expert, state: &GroundTruth| {
            (0..3)
                .map(|_| expert.decide(state))
                .last()
                .expect("decided")
        };
        assert_eq!(orbiting().teacher(), Teacher::Orbit);
        // At the approach distance from the ball, facing it, the goal (at +x) behind.
        let goal_behind = truth(FieldPose::new(0.28, 0.0, PI), Vec2::ZERO);
        let (command, phase) = settled(&mut orbiting(), &goal_behind);
        assert_eq!(phase, Phase::Align);
        assert_eq!(command.turn(), ORBIT_TURN);
        // Stepping right as fast as the turn needs to keep the ball 0.28 m ahead (0.126 m/s
        // of the walk's 0.15).
        assert!(
            (command.left() - orbit_sidestep(0.28)).abs() < 1e-3,
            "{command:?}"
        );
        assert!((orbit_sidestep(0.28) + 0.84).abs() < 1e-3);
        // Mirrored, the goal still behind: the same way round, where the observable teacher
        // (the goal's direction from ground truth) takes the other.
        let mirrored = truth(FieldPose::new(0.28, 0.0, -PI + 0.4), Vec2::ZERO);
        let (command, phase) = settled(&mut orbiting(), &mirrored);
        assert_eq!((phase, command.turn()), (Phase::Align, ORBIT_TURN));
        // Behind the ball with the goal in view a little to the right: toward it.
        let goal_ahead = truth(FieldPose::new(-0.28, 0.0, 0.3), Vec2::ZERO);
        let (command, phase) = settled(&mut orbiting(), &goal_ahead);
        assert_eq!(phase, Phase::Align);
        assert!(command.turn() < 0.0, "{command:?}");
        // Farther away it walks straight at the ball, wherever the goal is.
        let far = truth(FieldPose::new(-2.0, 1.0, -0.46), Vec2::ZERO);
        let (command, phase) = settled(&mut orbiting(), &far);
        assert_eq!(phase, Phase::Approach);
        assert!(
            command.forward() > 0.5 && command.turn().abs() < 0.05,
            "{command:?}"
        );
    }

    #[test]
    fn teachers_are_named_on_the_command_line_as_in_the_manifests() {
        for teacher in Teacher::ALL {
            assert_eq!(teacher.name().parse::<Teacher>(), Ok(teacher));
            let expert = Expert::teaching(
                teacher,
                ExpertConfig::default(),
                FieldGeometry::SPL,
                CameraGeometry::nao(),
            );
            assert_eq!(expert.teacher(), teacher);
        }
        assert!("oracle".parse::<Teacher>().is_err());
        assert_eq!(Teacher::default(), Teacher::Paper);
    }

    #[test]
    fn searches_by_turning_toward_an_unseen_ball() {
        let mut expert = Expert::new(ExpertConfig::default(), FieldGeometry::SPL);
        let (command, phase) =
            expert.decide(&truth(FieldPose::new(0.0, 0.0, 0.0), Vec2::new(0.0, 2.0)));
        assert_eq!(phase, Phase::Search);
        assert_eq!(command.as_array(), [0.0, 0.0, 1.0]);
    }

    #[test]
    fn approaches_a_seen_ball_and_dribbles_when_lined_up() {
        let mut expert = Expert::new(ExpertConfig::default(), FieldGeometry::SPL);
        let (command, phase) =
            expert.decide(&truth(FieldPose::new(0.0, 0.0, 0.0), Vec2::new(2.0, 0.1)));
        assert_eq!(phase, Phase::Approach);
        assert!(command.forward() > 0.5);
        // Right behind the ball, facing the goal.
        let lined_up = truth(FieldPose::new(1.72, 0.0, 0.0), Vec2::new(2.0, 0.0));
        let (_, phase) = expert.decide(&lined_up);
        assert_eq!(phase, Phase::Align);
        let (command, phase) = expert.decide(&lined_up);
        assert_eq!(phase, Phase::Dribble);
        assert!(command.forward() > 0.8);
    }

    /// `models/fixtures/teacher-approach.json` holds states of the teacher's first approach
    /// decision and the commands it sends there, which `dribble_models.one_way_detour`
    /// recomputes to find the detour's rows in recorded data: both sides check the file.
    #[test]
    fn the_committed_approach_fixture_is_the_teachers() {
        #[derive(serde::Deserialize)]
        struct Row {
            robot: [f32; 3],
            ball: [f32; 2],
            target_side: f32,
            command: [f32; 3],
            one_way_command: [f32; 3],
        }
        #[derive(serde::Deserialize)]
        struct Fixture {
            rows: Vec<Row>,
        }
        let path = crate::package_dir().join("../models/fixtures/teacher-approach.json");
        let text = std::fs::read_to_string(path).expect("the committed fixture");
        let fixture: Fixture = serde_json::from_str(&text).expect("fixture JSON");
        assert!(fixture.rows.len() > 100);
        for row in &fixture.rows {
            let state = GroundTruth {
                robot: FieldPose::new(row.robot[0], row.robot[1], row.robot[2]),
                ball: Vec2::from(row.ball),
                target_side: row.target_side,
                time_s: 0.0,
            };
            for (one_way, want) in [(false, row.command), (true, row.one_way_command)] {
                // The paper's ground-truth ball, with the one-way detour or the two-way one.
                let mut expert = Expert::new(ExpertConfig::default(), FieldGeometry::SPL);
                if one_way {
                    expert.teacher = Teacher::DetectorOneWay;
                }
                let (command, phase) = expert.decide(&state);
                assert_eq!(phase, Phase::Approach);
                for (got, want) in command.as_array().iter().zip(want) {
                    assert!(
                        (got - want).abs() < 1e-4,
                        "{:?} (one way: {one_way}) at robot {:?} ball {:?}: the fixture says {:?}",
                        command.as_array(),
                        row.robot,
                        row.ball,
                        want
                    );
                }
            }
        }
    }
}
