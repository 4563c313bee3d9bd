//! Allocations per policy step, per kind and engine, measured with a counting allocator.
//!
//! The compiled engine allocates nothing. tract allocates its intermediate tensors on every
//! run by design, so its numbers are not zero; what the test holds to there is that they are
//! the same on every step (nothing grows or leaks from step to step) and that the tick
//! around the policy adds nothing of its own.

mod support;

use std::time::Duration;

use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraInput, Clock, ControlLoop, LoopConfig, ManualClock, Policy,
    PolicyInput, TopFrame, TopThumbnail,
};
use support::counting_allocator::{CountingAllocator, count_allocations};
use support::fixture_manifest;

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

const STEPS: usize = 40;

/// The committed two-hypothesis CNN whose manifest has the controller commit to one
/// hypothesis (`controller/src/policy/commitment.rs`): its state is carried in the policy.
const COMMITTED: &str = "cnn-modal-committed-observable";

/// The model the robot package carries (`models/policy/ROBOT_MODEL`, int8) and its float
/// twin: their cameras' first layers run the pooled-pixel kernels on x86-64.
fn robot_models() -> [String; 2] {
    let named = std::fs::read_to_string(committed_models().join("ROBOT_MODEL"))
        .expect("models/policy/ROBOT_MODEL");
    let int8 = named.trim().to_string();
    let float = int8.trim_end_matches("-int8").to_string();
    [int8, float]
}

fn committed_models() -> std::path::PathBuf {
    support::package_dir().join("models/policy")
}

/// A committed model's manifest for the committed ones named here, else the fixture's.
fn manifest(kind: &str) -> std::path::PathBuf {
    if kind == COMMITTED || robot_models().iter().any(|name| name == kind) {
        committed_models().join(kind).join("policy.toml")
    } else {
        fixture_manifest(kind)
    }
}

fn load(kind: &str, engine: Engine) -> OnnxPolicy {
    let options = EngineOptions { engine, isa: None };
    OnnxPolicy::load_with(&manifest(kind), options)
        .expect("fixture loads")
        .0
}

fn per_step_allocations(kind: &str, engine: Engine) -> Vec<(u64, u64)> {
    let mut policy = load(kind, engine);
    let pattern = TestPattern::default();
    let (mut top_frame, mut bottom_frame) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    let (mut top, mut bottom) = (
        Box::new(TopThumbnail::black()),
        Box::new(BottomThumbnail::black()),
    );
    let mut counts = Vec::with_capacity(STEPS + 5);
    for step in 0..STEPS + 5 {
        let time = dribble_controller::Timestamp::from_nanos(step as u64 * 33_000_000);
        pattern.paint(&mut top_frame, step as u64, time);
        pattern.paint(&mut bottom_frame, step as u64, time);
        downscale(&top_frame, &mut top);
        downscale(&bottom_frame, &mut bottom);
        let input = PolicyInput::at_rest(&top, &bottom);
        let mut result = None;
        let counted = count_allocations(|| result = Some(policy.step(input)));
        result.expect("stepped").expect("step succeeds");
        counts.push(counted);
    }
    counts.split_off(5) // the first steps warm tract's caches
}

fn report(kind: &str, engine: Engine) -> u64 {
    let counts = per_step_allocations(kind, engine);
    let (allocations, bytes): (Vec<u64>, Vec<u64>) = counts.iter().copied().unzip();
    let mean_bytes = bytes.iter().sum::<u64>() as f64 / bytes.len() as f64;
    println!(
        "{kind} ({}): {} to {} allocations per step, {:.0} bytes per step on average ({} to {})",
        engine.name(),
        allocations.iter().min().expect("steps"),
        allocations.iter().max().expect("steps"),
        mean_bytes,
        bytes.iter().min().expect("steps"),
        bytes.iter().max().expect("steps"),
    );
    let spread =
        allocations.iter().max().expect("steps") - allocations.iter().min().expect("steps");
    assert!(
        spread == 0,
        "{kind}: allocations per step vary by {spread}, so something accumulates: {allocations:?}"
    );
    allocations.iter().copied().max().unwrap_or(0)
}

// One test function, so no other test runs beside it: tract shares caches between threads,
// and a model run on another thread changes what this one allocates.
#[test]
fn allocations_per_step_are_steady_and_the_tick_adds_none() {
    support::install_log_subscriber();
    for kind in ["cnn", "cnn-previous", "hcnn", "rcnn", COMMITTED] {
        assert_eq!(
            report(kind, Engine::Compiled),
            0,
            "{kind} on the compiled engine"
        );
        report(kind, Engine::Tract);
    }
    for kind in robot_models() {
        assert_eq!(
            report(&kind, Engine::Compiled),
            0,
            "{kind} on the compiled engine"
        );
    }
    tick_adds_no_allocation_to_the_policys();
}

fn tick_adds_no_allocation_to_the_policys() {
    // A tick that computes allocates exactly what the policy step does; a repeating tick
    // allocates nothing.
    let policy = load("cnn", Engine::Tract);
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(LoopConfig::default(), policy, clock.clone());
    let pattern = TestPattern::default();
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    let mut compute_counts = Vec::new();
    for sequence in 0..20 {
        clock.advance(Duration::from_millis(33));
        pattern.paint(&mut top, sequence, clock.now());
        pattern.paint(&mut bottom, sequence, clock.now());
        let input = CameraInput {
            top: Some(&top),
            bottom: Some(&bottom),
        };
        compute_counts.push(count_allocations(|| {
            control.tick(input);
        }));
        clock.advance(Duration::from_millis(10));
        let (repeat_allocations, _) = count_allocations(|| {
            control.tick(CameraInput::default());
        });
        assert_eq!(repeat_allocations, 0);
    }
    assert_eq!(control.counters().new_commands, 20);
    let policy_steps = per_step_allocations("cnn", Engine::Tract);
    let tick = compute_counts[5..]
        .iter()
        .map(|c| c.0)
        .max()
        .expect("ticks");
    let step = policy_steps.iter().map(|c| c.0).max().expect("steps");
    println!("cnn (tract): a computing tick allocates {tick} times, a policy step {step} times");
    assert_eq!(tick, step);
}
