//! The controller (its compiled engine, by default) reproduces PyTorch on the committed fixtures.

mod support;

use dribble_controller::policy::{OnnxPolicy, PolicyKind};
use dribble_controller::{Policy, PolicyInput};
use support::{fixture, reference};

const TOLERANCE: f32 = 1e-5;

/// Runs every reference step in order and returns the largest difference from PyTorch.
fn worst_difference(policy: &mut OnnxPolicy, kind: &str) -> f32 {
    let reference = reference(kind);
    let mut worst = 0.0f32;
    for (step, ((top, bottom), expected)) in reference
        .thumbnails
        .iter()
        .zip(&reference.commands)
        .enumerate()
    {
        let output = policy
            .step(PolicyInput { top, bottom })
            .unwrap_or_else(|error| panic!("step {step}: {error}"));
        let got = [output.forward, output.left, output.turn];
        for (g, e) in got.iter().zip(expected) {
            worst = worst.max((g - e).abs());
        }
        if let (OnnxPolicy::Hcnn(hcnn, _), Some(clusters)) = (&*policy, &reference.clusters) {
            assert_eq!(
                hcnn.last_network(),
                Some(clusters[step]),
                "step {step}: Rust and Python gate to different networks"
            );
        }
    }
    worst
}

fn load(kind: &str) -> OnnxPolicy {
    let (policy, _) = OnnxPolicy::load(&fixture(kind).join("policy.toml"))
        .unwrap_or_else(|error| panic!("loading the {kind} fixture: {error}"));
    policy
}

#[test]
fn cnn_matches_pytorch() {
    let mut policy = load("cnn");
    assert_eq!(policy.kind(), PolicyKind::Cnn);
    let worst = worst_difference(&mut policy, "cnn");
    println!("CNN: max |controller - PyTorch| = {worst:.2e}");
    assert!(worst <= TOLERANCE, "{worst}");
}

#[test]
fn hcnn_matches_pytorch_and_gates_like_python() {
    let mut policy = load("hcnn");
    let worst = worst_difference(&mut policy, "hcnn");
    println!("H-CNN: max |controller - PyTorch| = {worst:.2e}");
    assert!(worst <= TOLERANCE, "{worst}");
    let OnnxPolicy::Hcnn(hcnn, _) = &policy else {
        panic!("an H-CNN fixture loads as {:?}", policy.kind());
    };
    assert!(
        hcnn.selections().iter().all(|&n| n > 0),
        "the reference visits every network: {:?}",
        hcnn.selections()
    );
}

#[test]
fn rcnn_matches_pytorch_over_sixty_steps_and_reset_starts_afresh() {
    let mut policy = load("rcnn");
    let worst = worst_difference(&mut policy, "rcnn");
    println!("R-CNN: max |controller - PyTorch| over 60 steps = {worst:.2e}");
    assert!(worst <= TOLERANCE, "{worst}");
    // Without a reset the state of the first run would change the second one.
    policy.reset();
    let again = worst_difference(&mut policy, "rcnn");
    assert!(again <= TOLERANCE, "after reset: {again}");
}

#[test]
fn rcnn_state_is_carried_between_steps() {
    let reference = reference("rcnn");
    let (top, bottom) = &reference.thumbnails[0];
    let input = PolicyInput { top, bottom };
    let mut policy = load("rcnn");
    let first = policy.step(input).expect("step");
    let second = policy.step(input).expect("step");
    assert_ne!(
        first, second,
        "the same frame twice must differ through the state"
    );
}
