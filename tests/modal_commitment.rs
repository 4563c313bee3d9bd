//! The controller's commitment to one hypothesis of the committed two-hypothesis CNN
//! (`controller/src/policy/commitment.rs`, `models/policy/cnn-modal-committed-observable`):
//! at margin 0 it answers exactly the graph's own commands, on both engines; with a margin
//! it keeps its hypothesis where the graph's choice flips; a reset forgets it.

mod support;

use std::fs;
use std::path::{Path, PathBuf};

use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, PolicyOutput, TopThumbnail};

const MODEL: &str = "models/policy/cnn-modal-committed-observable";
const SOURCE: &str = "models/policy/cnn-modal-observable";
const STEPS: usize = 48;

/// A copy of the committed model with `switch_margin = margin`.
fn with_margin(margin: f32, name: &str) -> PathBuf {
    let model = support::package_dir().join(MODEL);
    let directory =
        std::env::temp_dir().join(format!("dribble-commitment-{name}-{}", std::process::id()));
    fs::create_dir_all(&directory).expect("scratch directory");
    fs::copy(model.join("policy.onnx"), directory.join("policy.onnx")).expect("copy the network");
    let manifest = fs::read_to_string(model.join("policy.toml")).expect("the manifest");
    let line = manifest
        .lines()
        .find(|line| line.starts_with("switch_margin = "))
        .expect("a [hypotheses] table with a switch margin");
    let manifest = manifest.replace(line, &format!("switch_margin = {margin:?}"));
    fs::write(directory.join("policy.toml"), manifest).expect("write the manifest");
    directory.join("policy.toml")
}

fn load(manifest: &Path, engine: Engine) -> OnnxPolicy {
    OnnxPolicy::load_with(manifest, EngineOptions { engine, isa: None })
        .unwrap_or_else(|error| panic!("{}: {error}", manifest.display()))
        .0
}

/// Thumbnails that swing between scenes: pseudo-random blobs on a field-like gradient, so
/// that the two hypotheses' logits cross now and then.
fn inputs() -> Vec<(Box<TopThumbnail>, Box<BottomThumbnail>)> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut scene = |pixels: &mut [u8], width: usize| {
        let (horizon, cx, cy, radius, gain) = (
            (next() % 60) as usize,
            (next() % width as u64) as f32,
            (next() % 100) as f32,
            (next() % 30 + 3) as f32,
            0.5 + (next() % 100) as f32 / 100.0,
        );
        for (i, pixel) in pixels.iter_mut().enumerate() {
            let (x, y) = ((i % width) as f32, (i / width) as f32);
            let base = if (i / width) < horizon { 190.0 } else { 100.0 };
            let ball = (x - cx).powi(2) + (y - cy).powi(2) < radius * radius;
            *pixel = ((if ball { 245.0 } else { base }) * gain).min(255.0) as u8;
        }
    };
    (0..STEPS)
        .map(|_| {
            let mut top = vec![0u8; TopThumbnail::PIXELS];
            let mut bottom = vec![0u8; BottomThumbnail::PIXELS];
            scene(&mut top, 160);
            scene(&mut bottom, 80);
            (
                Box::new(TopThumbnail::from_bytes(&top).expect("top size")),
                Box::new(BottomThumbnail::from_bytes(&bottom).expect("bottom size")),
            )
        })
        .collect()
}

fn run(
    policy: &mut OnnxPolicy,
    inputs: &[(Box<TopThumbnail>, Box<BottomThumbnail>)],
) -> Vec<PolicyOutput> {
    inputs
        .iter()
        .map(|(top, bottom)| {
            policy
                .step(PolicyInput::at_rest(top, bottom))
                .expect("a command")
        })
        .collect()
}

fn switches(policy: &OnnxPolicy) -> u64 {
    match policy {
        OnnxPolicy::Cnn(cnn, _) => cnn.commitment().expect("a committed CNN").switches(),
        other => panic!("the committed model loads as {:?}", other.kind()),
    }
}

#[test]
fn margin_zero_is_the_graphs_choice_and_a_margin_holds_a_hypothesis() {
    let inputs = inputs();
    let graph_manifest = support::package_dir().join(MODEL).join("policy.toml");
    // The graph's own choice: the modal CNN it was made from (the same weights, without
    // the hypotheses outputs; a network with outputs its manifest does not name is refused).
    let plain = support::package_dir().join(SOURCE).join("policy.toml");
    let graph = run(&mut load(&plain, Engine::Compiled), &inputs);

    let zero = with_margin(0.0, "zero");
    let mut committed = load(&zero, Engine::Compiled);
    assert_eq!(
        run(&mut committed, &inputs),
        graph,
        "margin 0 answers the graph's commands"
    );
    let flips = switches(&committed);
    assert!(
        flips >= 2,
        "the inputs make the graph's choice flip (it flipped {flips} times)"
    );

    let tract = run(&mut load(&zero, Engine::Tract), &inputs);
    for (step, (a, b)) in tract.iter().zip(&graph).enumerate() {
        let worst = [a.forward - b.forward, a.left - b.left, a.turn - b.turn]
            .iter()
            .fold(0.0f32, |w, d| w.max(d.abs()));
        assert!(
            worst <= 1e-4,
            "step {step}: tract and the compiled engine differ by {worst}"
        );
    }

    let mut holding = load(&with_margin(1.0e6, "hold"), Engine::Compiled);
    let held = run(&mut holding, &inputs);
    assert_eq!(switches(&holding), 0, "no logit beats another by a million");
    assert_eq!(held[0], graph[0], "the first frame takes the largest logit");
    assert_ne!(
        held, graph,
        "holding one hypothesis changes the commands where the choice flips"
    );
    holding.reset();
    let again = run(&mut holding, &inputs);
    assert_eq!(again, held, "after a reset the first frame chooses afresh");

    // The shipped manifest's margin lies between: fewer switches than the graph's.
    let mut shipped = load(&graph_manifest, Engine::Compiled);
    run(&mut shipped, &inputs);
    assert!(switches(&shipped) <= flips);
}
