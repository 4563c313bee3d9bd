//! The world's physics: pushing, rolling, goals, and bit-for-bit repeatability.
//! Run in release: rapier is about a hundred times slower in debug.

use dribble_controller::SpeedCommand;
use dribble_sim::camera_geometry::CameraGeometry;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use dribble_sim::simulation::Simulation;
use dribble_sim::walk::WalkConfig;
use dribble_sim::world::{STEPS_PER_SECOND, World, WorldConfig};
use glam::{Vec2, Vec3};

fn simulation(setup: &EpisodeSetup) -> Simulation {
    Simulation::new(
        setup,
        WorldConfig::default(),
        WalkConfig::default(),
        CameraGeometry::nao(),
    )
}

#[test]
fn a_robot_walking_forward_into_the_ball_moves_it_forward() {
    let setup = EpisodeSetup::placed(FieldPose::new(0.0, 0.0, 0.0), Vec2::new(0.4, 0.02));
    let mut sim = simulation(&setup);
    sim.set_command(SpeedCommand::new(1.0, 0.0, 0.0).expect("finite"));
    for _ in 0..5 * STEPS_PER_SECOND {
        sim.step();
    }
    let ball = sim.world().ball().position;
    let robot = sim.world().robot_pose();
    println!("after 5 s: robot at {robot:?}, ball at {ball}");
    assert!(ball.x > 0.9, "the ball was not pushed forward: {ball}");
    assert!(
        ball.x > robot.x + 0.1,
        "the ball is not ahead of the robot: {ball} vs {robot:?}"
    );
    assert!(ball.y.abs() < 0.5, "the ball went sideways: {ball}");
}

#[test]
fn a_rolling_ball_stops_within_a_realistic_distance() {
    let mut world = World::new(
        WorldConfig::default(),
        FieldGeometry::SPL,
        FieldPose::new(-3.0, 2.0, 0.0),
        Vec2::new(0.0, 0.0),
    );
    world.set_ball_velocity(Vec3::new(1.0, 0.0, 0.0));
    let parked = world.robot_pose();
    for _ in 0..5 * STEPS_PER_SECOND {
        world.step(parked);
    }
    let ball = world.ball();
    println!(
        "a ball rolled at 1 m/s stopped after {:.2} m",
        ball.position.x
    );
    assert_eq!(
        ball.velocity.truncate(),
        Vec2::ZERO,
        "still rolling: {ball:?}"
    );
    // A ball knocked to 1 m/s without spin slides until friction makes it roll, keeping 5/7
    // of its speed (a solid sphere); the carpet then stops it at the rolling deceleration:
    // (5/7 m/s)^2 / (2 * 0.35 m/s^2) = 0.73 m, plus the short slide. README: 0.74 m.
    let rolling = 5.0 / 7.0;
    let expected = rolling * rolling / (2.0 * WorldConfig::default().rolling_deceleration);
    assert!(
        (expected..expected + 0.03).contains(&ball.position.x),
        "stopped at {:.3} m, the model says {expected:.3} m plus the slide: {ball:?}",
        ball.position.x
    );
}

#[test]
fn a_ball_shot_into_the_goal_stays_in_it() {
    let field = FieldGeometry::SPL;
    let mut world = World::new(
        WorldConfig::default(),
        field,
        FieldPose::new(0.0, 2.0, 0.0),
        Vec2::new(4.1, 0.1),
    );
    world.set_ball_velocity(Vec3::new(3.0, 0.0, 0.0));
    let parked = world.robot_pose();
    for _ in 0..3 * STEPS_PER_SECOND {
        world.step(parked);
    }
    let ball = world.ball().position;
    println!("the shot ball rests at {ball}");
    assert!(field.is_goal(1.0, ball.x, ball.y), "{ball}");
    assert!(
        ball.x < field.length / 2.0 + WorldConfig::default().goal_depth,
        "through the net: {ball}"
    );
}

fn trajectory(seed: u64) -> Vec<[u32; 5]> {
    let mut sim = simulation(&EpisodeSetup::from_seed(seed));
    let mut trace = Vec::new();
    for step in 0..4 * STEPS_PER_SECOND {
        // A command that changes now and then, as a policy's would.
        let phase = (step / 90) as f32;
        let command = SpeedCommand::new(0.9, (phase * 0.7).sin() * 0.5, (phase * 1.3).cos() * 0.6)
            .expect("finite");
        sim.set_command(command);
        sim.step();
        let robot = sim.world().robot_pose();
        let ball = sim.world().ball().position;
        trace.push([robot.x, robot.y, robot.theta, ball.x, ball.y].map(f32::to_bits));
    }
    trace
}

#[test]
fn the_same_seed_gives_the_same_trajectory_bit_for_bit() {
    let first = trajectory(10_007);
    assert_eq!(first, trajectory(10_007));
    assert_ne!(first, trajectory(10_008));
}
