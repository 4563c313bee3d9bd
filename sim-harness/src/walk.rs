//! A B-Human-like walk as the simulator moves the robot: speed commands at the motion rate
//! become a body velocity with a short lag, acceleration limits and seeded odometry noise,
//! and a gait sway that moves the head cameras.

use std::collections::VecDeque;

use dribble_controller::{SpeedCommand, WalkLimits};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::pose::FieldPose;

/// How the walk responds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkConfig {
    pub limits: WalkLimits,
    /// Acceleration limits: forward and left in m/s², turn in rad/s².
    pub max_acceleration: [f32; 3],
    /// Motion cycles between a command and the walk acting on it.
    pub lag_cycles: usize,
    /// Standard deviation of the relative error of each velocity component, per cycle.
    pub odometry_noise: f32,
    /// Steps per second (both feet) at full activity.
    pub step_frequency_hz: f32,
    /// Side-to-side head movement at full activity, metres.
    pub sway_lateral_m: f32,
    /// Head roll at full activity, radians.
    pub sway_roll_rad: f32,
    /// Head pitch bob at full activity, radians.
    pub sway_pitch_rad: f32,
}

impl Default for WalkConfig {
    fn default() -> Self {
        Self {
            limits: WalkLimits::default(),
            max_acceleration: [0.5, 0.4, 2.0],
            lag_cycles: 2,
            odometry_noise: 0.05,
            step_frequency_hz: 2.0,
            sway_lateral_m: 0.012,
            sway_roll_rad: 1.2_f32.to_radians(),
            sway_pitch_rad: 0.8_f32.to_radians(),
        }
    }
}

/// The head's deviation from standing still, from the gait.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeadSway {
    pub lateral_m: f32,
    pub roll_rad: f32,
    pub pitch_rad: f32,
}

/// The walk's state: commands in flight, current velocity, gait phase, noise source.
#[derive(Clone, Debug)]
pub struct Walk {
    config: WalkConfig,
    in_flight: VecDeque<SpeedCommand>,
    /// Current body velocity: forward m/s, left m/s, turn rad/s.
    velocity: [f32; 3],
    /// Velocity error factors drawn this cycle.
    noise: [f32; 3],
    phase: f32,
    rng: ChaCha8Rng,
}

impl Walk {
    pub fn new(config: WalkConfig, seed: u64) -> Self {
        Self {
            config,
            in_flight: VecDeque::from(vec![SpeedCommand::STOP; config.lag_cycles]),
            velocity: [0.0; 3],
            noise: [1.0; 3],
            phase: 0.0,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    pub fn config(&self) -> &WalkConfig {
        &self.config
    }

    /// One motion cycle of `dt` seconds with the newest command.
    pub fn motion_cycle(&mut self, command: SpeedCommand, dt: f32) {
        self.in_flight.push_back(command);
        let acting = self.in_flight.pop_front().unwrap_or(SpeedCommand::STOP);
        let limits = self.config.limits;
        let target = [
            acting.forward() * limits.max_forward.0,
            acting.left() * limits.max_left.0,
            acting.turn() * limits.max_turn.0,
        ];
        for ((v, t), a) in self
            .velocity
            .iter_mut()
            .zip(target)
            .zip(self.config.max_acceleration)
        {
            *v += (t - *v).clamp(-a * dt, a * dt);
        }
        let sigma = self.config.odometry_noise;
        for factor in &mut self.noise {
            // Sum of uniforms: a cheap, seeded, roughly normal draw with deviation sigma.
            let draw: f32 = (0..3).map(|_| self.rng.random_range(-1.0f32..1.0)).sum();
            *factor = 1.0 + sigma * draw;
        }
    }

    /// Moves `pose` by `dt` seconds at the current velocity and advances the gait.
    pub fn advance(&mut self, pose: FieldPose, dt: f32) -> FieldPose {
        let [forward, left, turn] = self.actual_velocity();
        self.phase = (self.phase
            + core::f32::consts::TAU * self.config.step_frequency_hz * dt * self.activity())
            % core::f32::consts::TAU;
        pose.moved_by(forward * dt, left * dt, turn * dt)
    }

    /// The velocity the body actually moves with (commanded, delayed, limited, noisy).
    pub fn actual_velocity(&self) -> [f32; 3] {
        [
            self.velocity[0] * self.noise[0],
            self.velocity[1] * self.noise[1],
            self.velocity[2] * self.noise[2],
        ]
    }

    /// 0 standing, 1 walking at full speed in some direction.
    fn activity(&self) -> f32 {
        let limits = self.config.limits;
        let normalised = [
            self.velocity[0] / limits.max_forward.0,
            self.velocity[1] / limits.max_left.0,
            self.velocity[2] / limits.max_turn.0,
        ];
        normalised
            .iter()
            .map(|v| v.abs())
            .fold(0.0, f32::max)
            .min(1.0)
    }

    /// Where the gait has moved the head.
    pub fn sway(&self) -> HeadSway {
        let activity = self.activity();
        let (sin, cos) = self.phase.sin_cos();
        HeadSway {
            lateral_m: self.config.sway_lateral_m * activity * sin,
            roll_rad: self.config.sway_roll_rad * activity * sin,
            // Two bobs per stride: one per step.
            pitch_rad: self.config.sway_pitch_rad * activity * (2.0 * cos * cos - 1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk_for(walk: &mut Walk, command: SpeedCommand, seconds: f32) -> FieldPose {
        let mut pose = FieldPose::default();
        for _ in 0..(seconds * 100.0) as usize {
            walk.motion_cycle(command, 0.01);
            for _ in 0..3 {
                pose = walk.advance(pose, 0.01 / 3.0);
            }
        }
        pose
    }

    #[test]
    fn full_forward_reaches_the_maximum_speed_after_accelerating() {
        let mut walk = Walk::new(WalkConfig::default(), 1);
        let forward = SpeedCommand::new(1.0, 0.0, 0.0).expect("finite");
        let pose = walk_for(&mut walk, forward, 4.0);
        let speed = walk.actual_velocity()[0];
        assert!((speed - 0.25).abs() < 0.05, "{speed}");
        // Half a second to accelerate and a lag: a bit less than 4 s at full speed.
        assert!(pose.x > 0.8 && pose.x < 1.0, "{pose:?}");
        assert!(pose.y.abs() < 0.05 && pose.theta.abs() < 0.05, "{pose:?}");
    }

    #[test]
    fn a_command_acts_only_after_the_lag() {
        let mut walk = Walk::new(WalkConfig::default(), 1);
        let forward = SpeedCommand::new(1.0, 0.0, 0.0).expect("finite");
        walk.motion_cycle(forward, 0.01);
        walk.motion_cycle(forward, 0.01);
        assert_eq!(walk.actual_velocity()[0], 0.0);
        walk.motion_cycle(forward, 0.01);
        assert!(walk.actual_velocity()[0] > 0.0);
    }

    #[test]
    fn the_same_seed_walks_the_same_path_and_another_seed_does_not() {
        let command = SpeedCommand::new(0.7, 0.3, -0.4).expect("finite");
        let a = walk_for(&mut Walk::new(WalkConfig::default(), 5), command, 3.0);
        let b = walk_for(&mut Walk::new(WalkConfig::default(), 5), command, 3.0);
        let c = walk_for(&mut Walk::new(WalkConfig::default(), 6), command, 3.0);
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn standing_still_does_not_sway() {
        let mut walk = Walk::new(WalkConfig::default(), 1);
        walk_for(&mut walk, SpeedCommand::STOP, 1.0);
        assert_eq!(walk.sway(), HeadSway::default());
        walk_for(
            &mut walk,
            SpeedCommand::new(1.0, 0.0, 0.0).expect("finite"),
            1.3,
        );
        let sway = walk.sway();
        assert!(
            sway.lateral_m.abs() > 0.0 || sway.pitch_rad.abs() > 0.0,
            "{sway:?}"
        );
    }
}
