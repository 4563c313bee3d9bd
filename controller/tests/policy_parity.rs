//! The controller (its compiled engine, by default) reproduces PyTorch on the committed fixtures.

mod support;

use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy, PolicyKind};
use dribble_controller::{Policy, PolicyInput, SpeedCommand};
use support::{fixture, reference};

const TOLERANCE: f32 = 1e-5;

/// Runs every reference step in order and returns the largest difference from PyTorch.
fn worst_difference(policy: &mut OnnxPolicy, kind: &str) -> f32 {
    let reference = reference(kind);
    let mut worst = 0.0f32;
    for (step, (((top, bottom), expected), &previous)) in reference
        .thumbnails
        .iter()
        .zip(&reference.commands)
        .zip(&reference.previous)
        .enumerate()
    {
        let output = policy
            .step(PolicyInput {
                top,
                bottom,
                previous,
            })
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

/// A CNN that reads the last command sent: both engines reproduce PyTorch over steps whose
/// last commands span the range, and the command it answers follows the last command.
#[test]
fn a_cnn_reading_the_last_command_matches_pytorch_on_both_engines() {
    for engine in [Engine::Compiled, Engine::Tract] {
        let options = EngineOptions { engine, isa: None };
        let (mut policy, _) =
            OnnxPolicy::load_with(&fixture("cnn-previous").join("policy.toml"), options)
                .unwrap_or_else(|error| panic!("loading the cnn-previous fixture: {error}"));
        assert_eq!(
            policy.engine().compiled.is_some(),
            engine == Engine::Compiled,
            "{}",
            policy.engine()
        );
        let worst = worst_difference(&mut policy, "cnn-previous");
        println!(
            "CNN with the last command, {}: max |controller - PyTorch| = {worst:.2e}",
            engine.name()
        );
        assert!(worst <= TOLERANCE, "{}: {worst}", engine.name());
        let reference = reference("cnn-previous");
        let (top, bottom) = &reference.thumbnails[0];
        let mut answer = |previous| {
            policy
                .step(PolicyInput {
                    top,
                    bottom,
                    previous,
                })
                .expect("step")
        };
        let at_rest = answer(SpeedCommand::STOP);
        let turning = answer(SpeedCommand::new(0.0, 0.0, 1.0).expect("finite"));
        assert_ne!(
            at_rest,
            turning,
            "{}: the last command is read",
            engine.name()
        );
        assert_eq!(answer(SpeedCommand::STOP), at_rest, "{}", engine.name());
    }
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
    let input = PolicyInput::at_rest(top, bottom);
    let mut policy = load("rcnn");
    let first = policy.step(input).expect("step");
    let second = policy.step(input).expect("step");
    assert_ne!(
        first, second,
        "the same frame twice must differ through the state"
    );
}

/// The CNN fixture with `standardise = true` in its manifest: what the controller computes
/// before the network (`policy::network_input`). Both engines see a thumbnail pair and the
/// same pair under a gain and offset (`2p + 10`, exact in u8 for these pixels) as one input,
/// while the plain fixture tells them apart.
#[test]
fn a_standardised_policy_ignores_a_cameras_gain_and_offset() {
    let directory = support::scratch_copy("cnn", "standardised");
    let manifest = directory.join("policy.toml");
    let text = std::fs::read_to_string(&manifest).expect("fixture manifest");
    let standardised = text.replacen(
        "[normalisation]\n",
        "[normalisation]\nstandardise = true\n",
        1,
    );
    assert_ne!(
        text, standardised,
        "the fixture has a [normalisation] table"
    );
    std::fs::write(&manifest, standardised).expect("write manifest");
    let reference = reference("cnn");
    let (top, bottom) = &reference.thumbnails[0];
    let (mut brighter_top, mut brighter_bottom) = (top.clone(), bottom.clone());
    for pixel in brighter_top
        .as_bytes_mut()
        .iter_mut()
        .chain(brighter_bottom.as_bytes_mut())
    {
        *pixel = (*pixel / 3) * 2 + 10;
    }
    let (mut dim_top, mut dim_bottom) = (top.clone(), bottom.clone());
    for pixel in dim_top
        .as_bytes_mut()
        .iter_mut()
        .chain(dim_bottom.as_bytes_mut())
    {
        *pixel /= 3;
    }
    let command = |policy: &mut OnnxPolicy, top, bottom| {
        let output = policy
            .step(PolicyInput::at_rest(top, bottom))
            .expect("a step of the fixture");
        [output.forward, output.left, output.turn]
    };
    for engine in [Engine::Compiled, Engine::Tract] {
        let options = EngineOptions {
            engine,
            ..EngineOptions::default()
        };
        let (mut policy, loaded) = OnnxPolicy::load_with(&manifest, options)
            .unwrap_or_else(|error| panic!("loading the standardised fixture: {error}"));
        assert!(loaded.normalisation.standardise);
        let dim = command(&mut policy, &dim_top, &dim_bottom);
        let bright = command(&mut policy, &brighter_top, &brighter_bottom);
        for (d, b) in dim.iter().zip(&bright) {
            assert!(
                (d - b).abs() <= 1e-4,
                "{engine:?}: {dim:?} against {bright:?}"
            );
        }
        let (mut plain, _) =
            OnnxPolicy::load_with(&support::fixture("cnn").join("policy.toml"), options)
                .expect("the plain fixture");
        let (plain_dim, plain_bright) = (
            command(&mut plain, &dim_top, &dim_bottom),
            command(&mut plain, &brighter_top, &brighter_bottom),
        );
        assert!(
            plain_dim
                .iter()
                .zip(&plain_bright)
                .any(|(d, b)| (d - b).abs() > 1e-3),
            "{engine:?}: the plain fixture sees the gain: {plain_dim:?} against {plain_bright:?}"
        );
    }
    let _ = std::fs::remove_dir_all(directory);
}
