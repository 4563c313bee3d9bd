//! The compiled engine carries a recurrent policy's state as tract does over a whole episode
//! of real thumbnails: the expert plays training seed 0 to its goal through the rendered
//! cameras (`dribble record`), and every R-CNN the project has (the fixture and each shipped
//! R-CNN row) runs all of its steps, state carried from the first to the last, under tract
//! and under the engine with every instruction set this CPU runs.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, TopThumbnail};
use dribble_sim::dataset::{episode_file, read_npz};

/// The largest difference allowed over a whole episode (747 steps): measured 7.8e-7 at most
/// on every shipped R-CNN and instruction set; the margin is for other CPUs' rounding.
const TOLERANCE: f32 = 2e-6;

/// The fixture R-CNN and every shipped policy of kind `rcnn`; at least one shipped.
fn recurrent_policies() -> Vec<PathBuf> {
    let mut found = vec![support::fixture_manifest("rcnn")];
    let shipped = support::package_dir().join("models/policy");
    let mut rows: Vec<PathBuf> = std::fs::read_dir(&shipped)
        .unwrap_or_else(|error| panic!("{}: {error}", shipped.display()))
        .filter_map(Result::ok)
        .map(|entry| entry.path().join("policy.toml"))
        .filter(|path| path.is_file())
        .filter(|path| {
            PolicyManifest::load(path)
                .unwrap_or_else(|error| panic!("{}: {error}", path.display()))
                .recurrent
                .is_some()
        })
        .collect();
    rows.sort();
    assert!(
        !rows.is_empty(),
        "no shipped R-CNN in {}",
        shipped.display()
    );
    found.extend(rows);
    found
}

/// The thumbnails of one whole expert episode (training seed 0), as recorded.
fn episode_thumbnails() -> Vec<(Box<TopThumbnail>, Box<BottomThumbnail>)> {
    let out = std::env::temp_dir().join(format!("dribble-recurrent-parity-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let output = Command::new(env!("CARGO_BIN_EXE_dribble"))
        .args(["record", "--episodes", "0..1", "--out"])
        .arg(&out)
        .output()
        .expect("run dribble record");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let arrays = read_npz(&out.join(episode_file(0))).expect("the recorded episode");
    let (top, bottom) = (&arrays["top"], &arrays["bottom"]);
    let steps = top.shape[0];
    assert_eq!(bottom.shape[0], steps);
    let pairs = top
        .data
        .chunks_exact(120 * 160)
        .zip(bottom.data.chunks_exact(60 * 80))
        .map(|(t, b)| {
            let (mut top, mut bottom) = (
                Box::new(TopThumbnail::black()),
                Box::new(BottomThumbnail::black()),
            );
            top.as_bytes_mut().copy_from_slice(t);
            bottom.as_bytes_mut().copy_from_slice(b);
            (top, bottom)
        })
        .collect();
    std::fs::remove_dir_all(out).expect("clean up");
    pairs
}

fn load(path: &Path, engine: Engine, isa: Option<Isa>) -> OnnxPolicy {
    OnnxPolicy::load_with(path, EngineOptions { engine, isa })
        .unwrap_or_else(|error| panic!("{}: {error}", path.display()))
        .0
}

#[test]
fn the_engine_carries_the_recurrent_state_as_tract_does_over_a_whole_episode() {
    let steps = episode_thumbnails();
    // A whole episode: the expert needs about 25 s of the 90 at 30 Hz.
    assert!(steps.len() > 300, "{} steps", steps.len());
    for path in recurrent_policies() {
        let mut tract = load(&path, Engine::Tract, None);
        let expected: Vec<[f32; 3]> = steps
            .iter()
            .map(|(top, bottom)| {
                let out = tract
                    .step(PolicyInput::at_rest(top, bottom))
                    .expect("tract steps");
                [out.forward, out.left, out.turn]
            })
            .collect();
        for isa in Isa::available() {
            let mut compiled = load(&path, Engine::Compiled, Some(isa));
            assert_eq!(compiled.engine().compiled, Some(isa), "{}", path.display());
            let (mut worst, mut worst_step) = (0.0f32, 0);
            for (step, ((top, bottom), want)) in steps.iter().zip(&expected).enumerate() {
                let out = compiled
                    .step(PolicyInput::at_rest(top, bottom))
                    .unwrap_or_else(|error| panic!("step {step}: {error}"));
                for (got, want) in [out.forward, out.left, out.turn].iter().zip(want) {
                    assert!(got.is_finite(), "step {step}");
                    if (got - want).abs() > worst {
                        (worst, worst_step) = ((got - want).abs(), step);
                    }
                }
            }
            println!(
                "{} ({isa}): {} steps, max |engine - tract| = {worst:.2e} (step {worst_step})",
                path.display(),
                steps.len()
            );
            assert!(
                worst <= TOLERANCE,
                "{} ({isa}): {worst} at step {worst_step}",
                path.display()
            );
        }
    }
}
