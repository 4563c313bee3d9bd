//! The paper's episode placements (DESIGN.md, "Episodes"), drawn from a seed.

use glam::Vec2;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::pose::FieldPose;

/// Seeds of the training episodes.
pub const TRAINING_SEEDS: core::ops::Range<u64> = 0..100;
/// Seeds of the test episodes.
pub const TEST_SEEDS: core::ops::Range<u64> = 10_000..10_020;

/// Where an episode starts: the same seed always gives the same placement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeSetup {
    pub seed: u64,
    /// Uniform in a 4 m x 4 m square around the centre spot, uniform heading.
    pub robot: FieldPose,
    /// Uniform in a 2 m (x) by 4 m (y) area on one side, at least 1 m from the centre line.
    pub ball: Vec2,
    /// +1 for the goal at +x, -1 for the goal at -x: the goal on the ball's side.
    pub target_side: f32,
}

impl EpisodeSetup {
    pub fn from_seed(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let robot = FieldPose::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            rng.random_range(-core::f32::consts::PI..core::f32::consts::PI),
        );
        let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let ball = Vec2::new(
            side * rng.random_range(1.0..3.0),
            rng.random_range(-2.0..2.0),
        );
        Self {
            seed,
            robot,
            ball,
            target_side: side,
        }
    }

    /// A setup placed by hand (tests, demonstrations).
    pub fn placed(robot: FieldPose, ball: Vec2) -> Self {
        Self {
            seed: 0,
            robot,
            ball,
            target_side: if ball.x >= 0.0 { 1.0 } else { -1.0 },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placements_follow_the_protocol() {
        for seed in TRAINING_SEEDS.chain(TEST_SEEDS) {
            let setup = EpisodeSetup::from_seed(seed);
            assert!(setup.robot.x.abs() <= 2.0 && setup.robot.y.abs() <= 2.0);
            assert!((1.0..=3.0).contains(&setup.ball.x.abs()), "{setup:?}");
            assert!(setup.ball.y.abs() <= 2.0);
            assert_eq!(setup.target_side, setup.ball.x.signum());
        }
    }

    #[test]
    fn the_same_seed_gives_the_same_episode() {
        assert_eq!(
            EpisodeSetup::from_seed(10_003),
            EpisodeSetup::from_seed(10_003)
        );
        assert_ne!(EpisodeSetup::from_seed(1), EpisodeSetup::from_seed(2));
    }
}
