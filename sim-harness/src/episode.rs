//! The paper's episode placements (DESIGN.md, "Episodes"), drawn from a seed.

use glam::Vec2;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::conditions::Conditions;
use crate::pose::FieldPose;

/// Seeds of the training episodes.
pub const TRAINING_SEEDS: core::ops::Range<u64> = 0..100;
/// Seeds of the test episodes (reporting only).
pub const TEST_SEEDS: core::ops::Range<u64> = 10_000..10_020;
/// Seeds of the selection episodes, where choices are made (never training data).
pub const SELECTION_SEEDS: core::ops::Range<u64> = 20_000..20_050;
/// Seeds of the 100 fresh test episodes (reporting only).
pub const FRESH_SEEDS: core::ops::Range<u64> = 30_000..30_100;

/// The name of the range kept for choosing or reporting that `seed` lies in, if any: such
/// an episode is never training data (DESIGN.md, "Metrics").
pub fn reserved_range(seed: u64) -> Option<&'static str> {
    [
        ("test", TEST_SEEDS),
        ("selection", SELECTION_SEEDS),
        ("fresh", FRESH_SEEDS),
    ]
    .into_iter()
    .find_map(|(name, range)| range.contains(&seed).then_some(name))
}

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
    /// What the cameras see it under (clean: the paper's render); its random draws come
    /// from `seed` too.
    pub conditions: Conditions,
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
            conditions: Conditions::CLEAN,
        }
    }

    /// The same episode under `conditions`.
    pub fn under(self, conditions: Conditions) -> Self {
        Self { conditions, ..self }
    }

    /// A setup placed by hand (tests, demonstrations).
    pub fn placed(robot: FieldPose, ball: Vec2) -> Self {
        Self {
            seed: 0,
            robot,
            ball,
            target_side: if ball.x >= 0.0 { 1.0 } else { -1.0 },
            conditions: Conditions::CLEAN,
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
    fn reserved_ranges_are_named_and_training_seeds_are_not() {
        assert_eq!(reserved_range(10_019), Some("test"));
        assert_eq!(reserved_range(20_000), Some("selection"));
        assert_eq!(reserved_range(30_099), Some("fresh"));
        for seed in TRAINING_SEEDS
            .chain(1000..1010)
            .chain([20_050, 10_020, 30_100])
        {
            assert_eq!(reserved_range(seed), None, "{seed}");
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
