//! Model files built as an attacker would build them (small ONNX graphs that tract accepts,
//! with sizes that wrap unchecked arithmetic) load through the controller's own loader on
//! every instruction set and under the `dribble-controller forward` binary: the engine
//! refuses them with a reason and tract runs them, or the load fails with a typed error.
//! Nothing reads out of bounds, panics or answers differently from tract.

mod support;

use std::fs;
use std::path::{Path, PathBuf};

use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::engine::onnx_builder::{Attribute, floats, model, node};
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, TopThumbnail};
use prost::Message;
use tract_onnx::pb;

const TOP: [usize; 4] = [1, 1, 120, 160];
const BOTTOM: [usize; 4] = [1, 1, 60, 80];

/// A CNN policy directory holding `network` under the fixture's manifest.
fn policy_directory(test: &str, network: &pb::ModelProto) -> PathBuf {
    let directory = support::scratch_copy("cnn", test);
    fs::write(directory.join("policy.onnx"), network.encode_to_vec()).expect("write network");
    directory
}

/// top -> Conv(3 filters of 1x1, `pads` and `strides`) -> Flatten -> command [1, 3]; the
/// bottom camera feeds a product with zero that is added to it, so both inputs are read.
fn crafted_convolution(pads: [i64; 4], strides: [i64; 2]) -> pb::ModelProto {
    model(
        17,
        &[("top", &TOP), ("bottom", &BOTTOM)],
        vec![
            node(
                "Conv",
                &["top", "w", "b"],
                &["c"],
                &[
                    ("pads", Attribute::Ints(pads.to_vec())),
                    ("strides", Attribute::Ints(strides.to_vec())),
                ],
            ),
            node("Flatten", &["c"], &["f"], &[("axis", Attribute::Int(1))]),
            node(
                "ReduceMax",
                &["bottom"],
                &["m"],
                &[("keepdims", Attribute::Int(1))],
            ),
            node("Flatten", &["m"], &["mf"], &[("axis", Attribute::Int(1))]),
            node("Mul", &["mf", "zero"], &["z"], &[]),
            node("Add", &["f", "z"], &["command"], &[]),
        ],
        vec![
            floats("w", &[3, 1, 1, 1], &[0.5, -0.25, 2.0]),
            floats("b", &[3], &[0.125, 0.5, -0.75]),
            floats("zero", &[], &[0.0]),
        ],
        &["command"],
    )
}

fn step(policy: &mut OnnxPolicy, brightness: u8) -> [f32; 3] {
    let mut top = TopThumbnail::black();
    let mut bottom = BottomThumbnail::black();
    top.as_bytes_mut().fill(brightness);
    bottom.as_bytes_mut().fill(brightness / 2);
    let out = policy
        .step(PolicyInput::at_rest(&top, &bottom))
        .expect("a step runs");
    [out.forward, out.left, out.turn]
}

/// Loads `directory` under tract and under the engine with every instruction set; returns
/// the compiled loads' fallback reasons (one per instruction set) after checking that every
/// engine that loaded answers as tract does. `None` when tract itself refuses the file.
fn load_everywhere(directory: &Path) -> Option<Vec<Option<String>>> {
    let manifest = directory.join("policy.toml");
    let tract = OnnxPolicy::load_with(
        &manifest,
        EngineOptions {
            engine: Engine::Tract,
            isa: None,
        },
    );
    let mut tract = match tract {
        Ok((policy, _)) => policy,
        Err(error) => {
            // Whatever tract refuses, the compiled load refuses too, with a reason.
            for isa in Isa::available() {
                let options = EngineOptions {
                    engine: Engine::Compiled,
                    isa: Some(isa),
                };
                let error =
                    OnnxPolicy::load_with(&manifest, options).expect_err("tract refused the file");
                assert!(error.to_string().contains("policy"), "{error}");
            }
            println!("tract refuses: {error}");
            return None;
        }
    };
    let expected: Vec<[f32; 3]> = [0, 77, 255].map(|b| step(&mut tract, b)).to_vec();
    let mut reasons = Vec::new();
    for isa in Isa::available() {
        let options = EngineOptions {
            engine: Engine::Compiled,
            isa: Some(isa),
        };
        let (mut policy, _) = OnnxPolicy::load_with(&manifest, options).expect("loads");
        let report = policy.engine().clone();
        for (&brightness, want) in [0u8, 77, 255].iter().zip(&expected) {
            let got = step(&mut policy, brightness);
            for (a, b) in got.iter().zip(want) {
                assert!(
                    (a - b).abs() <= 1e-5 * (1.0 + b.abs()),
                    "{isa} ({report}): {got:?} against tract's {want:?}"
                );
            }
        }
        reasons.push(report.fallback);
    }
    Some(reasons)
}

/// The review's file: pads of 2^61 and a stride past them, so the output is one pixel.
fn reviews_wrapping_convolution() -> pb::ModelProto {
    let huge = 1i64 << 61;
    crafted_convolution([huge, 0, huge, 0], [(1 << 62) + 200, 1000])
}

/// A convolution within the loader's limits whose padded map the engine cannot hold.
fn padded_past_the_engine() -> pb::ModelProto {
    let stride = dribble_controller::policy::model_limits::MAX_SPATIAL;
    crafted_convolution([32_000; 4], [stride, stride])
}

#[test]
fn the_reviews_wrapping_convolution_is_refused_at_load_naming_the_node() {
    // Before: pads this large made the padded size wrap (the buffer came out small) and the
    // kernels' bound wrap the same way, so the first forward pass read far past the heap
    // (SIGSEGV on SSE4.2, AVX2 and AVX-512, a panic on the portable path). A padding of
    // i64::MAX hangs tract's own planner. Now the loader refuses both before tract sees them.
    let directory = policy_directory("wrapping-conv", &reviews_wrapping_convolution());
    assert_eq!(load_everywhere(&directory), None);
    let error = OnnxPolicy::load(&directory.join("policy.toml")).expect_err("refused");
    let text = error.to_string();
    assert!(
        text.contains("Conv") && text.contains("pads = 2305843009213693952"),
        "{text}"
    );
}

#[test]
fn a_convolution_the_loader_accepts_but_the_engine_cannot_hold_runs_under_tract() {
    // Pads of 32,000 on every side (within the loader's 2^16) make a padded map of
    // 64,120 x 64,160: more numbers than the engine's limit for one tensor, so it refuses
    // with the reason and tract runs it, with tract's answers.
    let directory = policy_directory("engine-limit-conv", &padded_past_the_engine());
    let reasons = load_everywhere(&directory).expect("tract loads it");
    for reason in reasons {
        let reason = reason.expect("the engine refuses it");
        assert!(reason.contains("more than 16777216 numbers"), "{reason}");
    }
}

#[test]
fn an_ordinary_padded_convolution_runs_on_the_engine_and_agrees() {
    let directory = policy_directory(
        "ordinary-conv",
        &crafted_convolution([1, 1, 1, 1], [200, 200]),
    );
    let reasons = load_everywhere(&directory).expect("tract loads it");
    assert!(reasons.iter().all(Option::is_none), "{reasons:?}");
}

#[test]
fn the_controller_binary_refuses_or_runs_crafted_files_on_every_instruction_set() {
    let refused = policy_directory("wrapping-conv-binary", &reviews_wrapping_convolution());
    let to_tract = policy_directory("engine-limit-conv-binary", &padded_past_the_engine());
    for isa in Isa::available() {
        let run = |directory: &Path| {
            let output = support::controller_command()
                .args(["--isa", isa.name(), "forward", "--no-peak", "--steps", "3"])
                .arg("--policy")
                .arg(directory.join("policy.toml"))
                .output()
                .expect("runs");
            let text = format!(
                "{}{}",
                String::from_utf8_lossy(&output.stdout),
                String::from_utf8_lossy(&output.stderr)
            );
            (output.status.code(), text)
        };
        // A clear error and exit status 1: no signal, no panic (101).
        let (code, text) = run(&refused);
        assert_eq!(code, Some(1), "{isa}: {text}");
        assert!(text.contains("pads = 2305843009213693952"), "{isa}: {text}");
        let (code, text) = run(&to_tract);
        assert_eq!(code, Some(0), "{isa}: {text}");
        assert!(
            text.contains("engine tract (the compiled engine cannot run it"),
            "{isa}: {text}"
        );
    }
}
