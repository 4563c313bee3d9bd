//! The physical world in rapier3d: ground, goals with nets, border boards, the ball, and the
//! robot's legs as a kinematic body that pushes the ball when it walks into it.
//!
//! The world steps at a fixed 300 Hz: a multiple of the 100 Hz motion rate and of the 60 Hz
//! at which the two 30 Hz cameras take turns, so every camera frame and motion cycle falls on
//! a step. Nothing in it is random; the episode's seed decides the placements and the walk's
//! noise, and the same inputs give the same trajectory, bit for bit.

use dribble_controller::Timestamp;
use glam::{Quat, Vec2, Vec3};
use rapier3d::prelude::*;

use crate::field::FieldGeometry;
use crate::pose::FieldPose;

/// Physics steps per simulated second.
pub const STEPS_PER_SECOND: u64 = 300;
/// Length of one physics step.
pub const STEP_SECONDS: f32 = 1.0 / STEPS_PER_SECOND as f32;

/// Physical properties of the ball and the surfaces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldConfig {
    pub ball_mass_kg: f32,
    pub ball_restitution: f32,
    pub ball_friction: f32,
    /// Deceleration of a rolling ball by the carpet, m/s². With 0.35, a ball already
    /// rolling at 1 m/s stops after v²/2a = 1.4 m; a ball knocked to 1 m/s without spin
    /// slides first and keeps 5/7 of its speed once it rolls, so it stops after 0.74 m.
    pub rolling_deceleration: f32,
    /// Height of the boards around the carpet, metres.
    pub board_height: f32,
    /// Depth of the goal behind the goal line, metres.
    pub goal_depth: f32,
}

impl Default for WorldConfig {
    fn default() -> Self {
        Self {
            ball_mass_kg: 0.045,
            ball_restitution: 0.4,
            ball_friction: 0.6,
            rolling_deceleration: 0.35,
            board_height: 0.3,
            goal_depth: 0.5,
        }
    }
}

/// The robot's colliders in its own frame: feet and shins (half extents, centre).
const ROBOT_PARTS: [([f32; 3], [f32; 3]); 4] = [
    ([0.08, 0.04, 0.025], [0.02, 0.05, 0.025]),
    ([0.08, 0.04, 0.025], [0.02, -0.05, 0.025]),
    ([0.035, 0.035, 0.13], [0.0, 0.05, 0.18]),
    ([0.035, 0.035, 0.13], [0.0, -0.05, 0.18]),
];

/// Where the ball is and how it moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BallState {
    pub position: Vec3,
    pub velocity: Vec3,
    pub rotation: Quat,
}

/// The simulated field with its ball and robot.
pub struct World {
    config: WorldConfig,
    field: FieldGeometry,
    physics: PhysicsWorld,
    ball: RigidBodyHandle,
    robot: RigidBodyHandle,
    robot_pose: FieldPose,
    steps: u64,
}

impl std::fmt::Debug for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("World")
            .field("steps", &self.steps)
            .field("robot_pose", &self.robot_pose)
            .field("ball", &self.ball())
            .finish_non_exhaustive()
    }
}

impl World {
    /// A world with the robot at `robot_pose` and the ball at rest on `ball`.
    pub fn new(
        config: WorldConfig,
        field: FieldGeometry,
        robot_pose: FieldPose,
        ball: Vec2,
    ) -> Self {
        let mut physics = PhysicsWorld {
            gravity: Vec3::new(0.0, 0.0, -9.81),
            ..Default::default()
        };
        physics.integration_parameters.dt = STEP_SECONDS;
        add_static_world(&mut physics, &config, &field);

        let radius = field.ball_diameter / 2.0;
        let (ball, _) = physics.insert(
            RigidBodyBuilder::dynamic()
                .translation(Vec3::new(ball.x, ball.y, radius))
                .ccd_enabled(true),
            ColliderBuilder::ball(radius)
                .mass(config.ball_mass_kg)
                .restitution(config.ball_restitution)
                .friction(config.ball_friction),
        );
        let robot = physics
            .bodies
            .insert(RigidBodyBuilder::kinematic_position_based().pose(robot_body_pose(robot_pose)));
        for (half, centre) in ROBOT_PARTS {
            let collider = ColliderBuilder::cuboid(half[0], half[1], half[2])
                .translation(Vec3::from(centre))
                .friction(0.8);
            physics
                .colliders
                .insert_with_parent(collider, robot, &mut physics.bodies);
        }
        Self {
            config,
            field,
            physics,
            ball,
            robot,
            robot_pose,
            steps: 0,
        }
    }

    /// Advances one step, moving the robot to `next_robot_pose` over it.
    pub fn step(&mut self, next_robot_pose: FieldPose) {
        let limit_x = self.field.length / 2.0 + self.field.border;
        let limit_y = self.field.width / 2.0 + self.field.border;
        let pose = FieldPose::new(
            next_robot_pose.x.clamp(-limit_x, limit_x),
            next_robot_pose.y.clamp(-limit_y, limit_y),
            next_robot_pose.theta,
        );
        if let Some(robot) = self.physics.bodies.get_mut(self.robot) {
            robot.set_next_kinematic_position(robot_body_pose(pose));
        }
        self.robot_pose = pose;
        self.physics.step();
        self.apply_rolling_resistance();
        self.steps += 1;
    }

    /// The carpet slows a rolling ball at a constant rate until it rests.
    fn apply_rolling_resistance(&mut self) {
        let radius = self.field.ball_diameter / 2.0;
        let Some(ball) = self.physics.bodies.get_mut(self.ball) else {
            return;
        };
        let on_ground = ball.translation().z < radius * 1.2;
        if !on_ground {
            return;
        }
        let velocity = ball.linvel();
        let horizontal = Vec2::new(velocity.x, velocity.y);
        let speed = horizontal.length();
        let slowdown = self.config.rolling_deceleration * STEP_SECONDS;
        if speed <= slowdown {
            if speed > 0.0 {
                ball.set_linvel(Vec3::new(0.0, 0.0, velocity.z), false);
                ball.set_angvel(Vec3::ZERO, false);
            }
            return;
        }
        let scale = (speed - slowdown) / speed;
        ball.set_linvel(
            Vec3::new(velocity.x * scale, velocity.y * scale, velocity.z),
            false,
        );
        ball.set_angvel(ball.angvel() * scale, false);
    }

    pub fn ball(&self) -> BallState {
        match self.physics.bodies.get(self.ball) {
            Some(ball) => BallState {
                position: ball.translation(),
                velocity: ball.linvel(),
                rotation: *ball.rotation(),
            },
            None => BallState {
                position: Vec3::ZERO,
                velocity: Vec3::ZERO,
                rotation: Quat::IDENTITY,
            },
        }
    }

    /// Sets the ball's velocity (a kick, in tests).
    pub fn set_ball_velocity(&mut self, velocity: Vec3) {
        if let Some(ball) = self.physics.bodies.get_mut(self.ball) {
            ball.set_linvel(velocity, true);
        }
    }

    pub fn robot_pose(&self) -> FieldPose {
        self.robot_pose
    }

    pub fn field(&self) -> &FieldGeometry {
        &self.field
    }

    pub fn config(&self) -> &WorldConfig {
        &self.config
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Simulation time: steps since the start.
    pub fn time(&self) -> Timestamp {
        step_time(self.steps)
    }
}

/// The simulation time of step `step`.
pub fn step_time(step: u64) -> Timestamp {
    Timestamp::from_nanos((u128::from(step) * 1_000_000_000 / u128::from(STEPS_PER_SECOND)) as u64)
}

fn robot_body_pose(pose: FieldPose) -> Pose {
    Pose::from_parts(
        Vec3::new(pose.x, pose.y, 0.0),
        Quat::from_rotation_z(pose.theta),
    )
}

/// A fixed box with half extents `half` centred at `centre`.
fn fixed(physics: &mut PhysicsWorld, half: Vec3, centre: Vec3, friction: f32, restitution: f32) {
    physics.insert(
        RigidBodyBuilder::fixed().translation(centre),
        ColliderBuilder::cuboid(half.x, half.y, half.z)
            .friction(friction)
            .restitution(restitution),
    );
}

/// Ground, boards around the carpet, and both goals (posts, crossbar, net walls).
fn add_static_world(physics: &mut PhysicsWorld, config: &WorldConfig, field: &FieldGeometry) {
    let half_length = field.length / 2.0 + field.border;
    let half_width = field.width / 2.0 + field.border;
    fixed(
        physics,
        Vec3::new(half_length + 1.0, half_width + 1.0, 0.1),
        Vec3::new(0.0, 0.0, -0.1),
        0.8,
        0.0,
    );
    let board = 0.05;
    let h = config.board_height / 2.0;
    for side in [-1.0, 1.0] {
        fixed(
            physics,
            Vec3::new(half_length + board * 2.0, board, h),
            Vec3::new(0.0, side * (half_width + board), h),
            0.3,
            0.5,
        );
        fixed(
            physics,
            Vec3::new(board, half_width, h),
            Vec3::new(side * (half_length + board), 0.0, h),
            0.3,
            0.5,
        );
    }
    for side in [-1.0f32, 1.0] {
        for (x, y) in field.goal_post_centres(side) {
            physics.insert(
                RigidBodyBuilder::fixed().pose(Pose::from_parts(
                    Vec3::new(x, y, field.goal_height / 2.0),
                    Quat::from_rotation_x(core::f32::consts::FRAC_PI_2),
                )),
                ColliderBuilder::cylinder(field.goal_height / 2.0, field.goal_post_diameter / 2.0)
                    .restitution(0.5),
            );
        }
        let line_x = field.goal_line_x(side);
        let post_y = field.goal_inner_width / 2.0 + field.goal_post_diameter;
        let net = 0.01;
        // Back net, side nets and crossbar: soft, so a goal stays a goal.
        fixed(
            physics,
            Vec3::new(net, post_y, field.goal_height / 2.0),
            Vec3::new(
                line_x + side * config.goal_depth,
                0.0,
                field.goal_height / 2.0,
            ),
            0.5,
            0.1,
        );
        for y_side in [-1.0, 1.0] {
            fixed(
                physics,
                Vec3::new(config.goal_depth / 2.0, net, field.goal_height / 2.0),
                Vec3::new(
                    line_x + side * config.goal_depth / 2.0,
                    y_side * post_y,
                    field.goal_height / 2.0,
                ),
                0.5,
                0.1,
            );
        }
        fixed(
            physics,
            Vec3::new(config.goal_depth / 2.0, post_y, net),
            Vec3::new(
                line_x + side * config.goal_depth / 2.0,
                0.0,
                field.goal_height,
            ),
            0.5,
            0.1,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world(robot: FieldPose, ball: Vec2) -> World {
        World::new(WorldConfig::default(), FieldGeometry::SPL, robot, ball)
    }

    #[test]
    fn a_ball_at_rest_stays_at_rest_on_the_ground() {
        let mut world = world(FieldPose::new(-2.0, 0.0, 0.0), Vec2::new(1.0, 1.0));
        for _ in 0..300 {
            world.step(FieldPose::new(-2.0, 0.0, 0.0));
        }
        let ball = world.ball();
        assert!(
            (ball.position - Vec3::new(1.0, 1.0, 0.05)).length() < 2e-3,
            "{ball:?}"
        );
        assert_eq!(world.time(), Timestamp::from_nanos(1_000_000_000));
    }

    #[test]
    fn step_times_are_exact_at_camera_and_motion_instants() {
        assert_eq!(step_time(10), Timestamp::from_nanos(33_333_333));
        assert_eq!(step_time(3), Timestamp::from_nanos(10_000_000));
        assert_eq!(step_time(300), Timestamp::from_nanos(1_000_000_000));
    }
}
