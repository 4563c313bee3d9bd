//! The expert scores, in closed loop, at the controller's cadence. Physics only (the expert
//! needs no images), so these run in well under a second each in release.

use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::runner::{Driver, EpisodeConfig, run_episode};

fn play(seed: u64, time_limit_s: f32) -> dribble_sim::runner::EpisodeResult {
    let config = EpisodeConfig {
        time_limit_s,
        ..EpisodeConfig::default()
    };
    let expert = Expert::new(ExpertConfig::default(), FieldGeometry::SPL);
    run_episode(
        &EpisodeSetup::from_seed(seed),
        &config,
        Driver::Expert(expert),
        None,
        None,
    )
    .expect("no rendering, no failure")
}

#[test]
fn the_expert_scores_on_fixed_test_seeds() {
    for seed in [10_002, 10_003, 10_004] {
        let result = play(seed, 45.0);
        println!(
            "seed {seed}: {} after {:.1} s, {:.1} m walked",
            result.outcome.name(),
            result.duration_s,
            result.distance_walked_m
        );
        assert_eq!(result.outcome, Outcome::Goal, "seed {seed}");
    }
}

#[test]
fn commands_are_computed_once_per_camera_pair() {
    let result = play(10_003, 10.0);
    assert_eq!(result.outcome, Outcome::TimeLimit);
    // 30 pairs a second for 10 s; the first pair completes half a period in.
    assert!(
        (295..=300).contains(&result.computed_commands),
        "{}",
        result.computed_commands
    );
}

#[test]
fn an_episode_ends_at_its_time_limit() {
    let result = play(10_017, 3.0);
    assert_eq!(result.outcome, Outcome::TimeLimit);
    assert!((result.duration_s - 3.0).abs() < 0.01);
}
