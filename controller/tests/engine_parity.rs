//! The compiled engine computes what tract computes, on every fixture and every shipped
//! model, with each instruction set this CPU runs (under `cross/test` that is the emulated
//! Atoms' sets), and says so when it hands a network to tract. A recurrent policy's state
//! over a whole episode of real thumbnails: `tests/recurrent_parity.rs`.

mod support;

use std::path::{Path, PathBuf};

use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::manifest::{PolicyManifest, Precision};
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, TopThumbnail};
use support::fixture;

/// Feed-forward models differ by at most 2.6e-6 (the README's figure), a recurrent one's
/// state carries rounding over the 60 steps to 7.3e-6 (`rcnn-long`); the margins are for
/// other CPUs' rounding. A whole episode: `tests/recurrent_parity.rs`.
const TOLERANCE: f32 = 4e-6;
const RECURRENT_TOLERANCE: f32 = 1e-5;
/// An int8 policy: both compute the same integer sums, but a value within rounding of half a
/// grid step can take the neighbouring step in one and not in the other, and that step is
/// carried on (`cnn-observable-int8`: 5.7e-4 over these 60 steps; `dagger-observable-more-int8`:
/// 2.03e-3, a step of its coarser command grid; the int8 fixture: 1.5e-8). The integer sums
/// themselves are held equal to the definition bit for bit by the kernel tests.
const INT8_TOLERANCE: f32 = 3e-3;

/// Every policy the tests compare: the fixtures and every model `models/policy` ships. The
/// paper's three rows and the one `SHIPPED` names must be there: a missing one fails.
fn policies() -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> = ["cnn", "cnn-int8", "hcnn", "rcnn"]
        .iter()
        .map(|kind| fixture(kind).join("policy.toml"))
        .collect();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/policy");
    let chosen = std::fs::read_to_string(shipped.join("SHIPPED"))
        .unwrap_or_else(|error| panic!("{}/SHIPPED: {error}", shipped.display()));
    for name in ["cnn", "hcnn", "rcnn", chosen.trim()] {
        let manifest = shipped.join(name).join("policy.toml");
        assert!(manifest.is_file(), "{} is missing", manifest.display());
    }
    let mut rows: Vec<PathBuf> = std::fs::read_dir(&shipped)
        .unwrap_or_else(|error| panic!("{}: {error}", shipped.display()))
        .filter_map(Result::ok)
        .filter(|entry| entry.path().is_dir())
        .map(|entry| entry.path().join("policy.toml"))
        .collect();
    rows.sort();
    for row in &rows {
        assert!(row.is_file(), "{} is missing", row.display());
    }
    found.extend(rows);
    found
}

/// Thumbnails from a seeded generator: every step different, the same every run.
fn thumbnails(seed: u64, steps: usize) -> Vec<(Box<TopThumbnail>, Box<BottomThumbnail>)> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 24) as u8
    };
    (0..steps)
        .map(|_| {
            let (mut top, mut bottom) = (
                Box::new(TopThumbnail::black()),
                Box::new(BottomThumbnail::black()),
            );
            top.as_bytes_mut().iter_mut().for_each(|p| *p = next());
            bottom.as_bytes_mut().iter_mut().for_each(|p| *p = next());
            (top, bottom)
        })
        .collect()
}

fn load(path: &Path, engine: Engine, isa: Option<Isa>) -> OnnxPolicy {
    OnnxPolicy::load_with(path, EngineOptions { engine, isa })
        .unwrap_or_else(|error| panic!("{}: {error}", path.display()))
        .0
}

/// Largest difference between two policies over the same steps (an episode, then a reset
/// and a second one, so a recurrent state is carried and cleared).
fn worst_difference(
    a: &mut OnnxPolicy,
    b: &mut OnnxPolicy,
    steps: &[(Box<TopThumbnail>, Box<BottomThumbnail>)],
) -> f32 {
    let mut worst = 0.0f32;
    for episode in 0..2 {
        a.reset();
        b.reset();
        for (step, (top, bottom)) in steps.iter().enumerate() {
            let input = PolicyInput { top, bottom };
            let x = a
                .step(input)
                .unwrap_or_else(|e| panic!("episode {episode} step {step}: {e}"));
            let y = b
                .step(input)
                .unwrap_or_else(|e| panic!("episode {episode} step {step}: {e}"));
            for (u, v) in [(x.forward, y.forward), (x.left, y.left), (x.turn, y.turn)] {
                assert!(u.is_finite() && v.is_finite());
                worst = worst.max((u - v).abs());
            }
        }
    }
    worst
}

#[test]
fn the_engine_matches_tract_on_every_model_and_instruction_set() {
    let steps = thumbnails(7, 60);
    let mut checked = 0;
    for path in policies() {
        let mut tract = load(&path, Engine::Tract, None);
        assert_eq!(tract.engine().compiled, None);
        for isa in Isa::available() {
            let mut compiled = load(&path, Engine::Compiled, Some(isa));
            assert_eq!(
                compiled.engine().compiled,
                Some(isa),
                "{}: {}",
                path.display(),
                compiled.engine()
            );
            let worst = worst_difference(&mut compiled, &mut tract, &steps);
            println!(
                "{} ({isa}): max |engine - tract| = {worst:.2e}",
                path.display()
            );
            let manifest = PolicyManifest::load(&path).expect("a manifest");
            let recurrent = manifest.recurrent.is_some();
            // An int8 manifest runs on the integer kernels, not on its float reading.
            let int8 = manifest.precision == Precision::Int8;
            assert_eq!(compiled.engine().int8, int8, "{}", path.display());
            let tolerance = if int8 {
                INT8_TOLERANCE
            } else if recurrent {
                RECURRENT_TOLERANCE
            } else {
                TOLERANCE
            };
            assert!(worst <= tolerance, "{}, {isa}: {worst}", path.display());
            checked += 1;
        }
    }
    assert!(checked >= 3);
}

#[test]
fn a_graph_outside_the_engine_runs_under_tract_and_says_why() {
    // The NaN fixture averages with ReduceMean, which the engine does not lower.
    let path = fixture("nan").join("policy.toml");
    let policy = load(&path, Engine::Compiled, None);
    let report = policy.engine();
    assert_eq!(report.compiled, None);
    let why = report.fallback.as_deref().unwrap_or_default();
    assert!(why.contains("ReduceMean"), "{why}");
    assert!(
        report
            .to_string()
            .starts_with("tract (the compiled engine cannot run it")
    );
}

#[test]
fn the_default_is_the_widest_instruction_set_of_this_cpu() {
    let policy = load(&fixture("cnn").join("policy.toml"), Engine::Compiled, None);
    assert_eq!(policy.engine().compiled, Some(Isa::detect()));
    assert!(Isa::detect().is_available());
    assert!(Isa::Portable.is_available());
    for isa in Isa::ALL {
        assert_eq!(isa.name().parse::<Isa>(), Ok(isa));
    }
    assert!("mmx".parse::<Isa>().is_err());
}
