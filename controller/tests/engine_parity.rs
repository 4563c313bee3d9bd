//! The compiled engine computes what tract computes, on every fixture and every shipped
//! model, with each instruction set this CPU runs (under `cross/test` that is the emulated
//! Atoms' sets), and says so when it hands a network to tract. A recurrent policy's state
//! over a whole episode of real thumbnails: `tests/recurrent_parity.rs`.

mod support;

use std::path::{Path, PathBuf};

use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::manifest::{PolicyManifest, Precision};
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, SpeedCommand, TopThumbnail};
use prost::Message;
use support::fixture;
use tract_onnx::pb;

/// Feed-forward models differ by at most 2.6e-6 (the README's figure), a recurrent one's
/// state carries rounding over the 60 steps to 7.3e-6 (`rcnn-24-epochs`); the margins are for
/// other CPUs' rounding. A whole episode: `tests/recurrent_parity.rs`.
const TOLERANCE: f32 = 4e-6;
const RECURRENT_TOLERANCE: f32 = 1e-5;
/// An int8 policy: both engines compute the same integer sums (the kernel tests hold them
/// equal to the definition bit for bit), but tract sums the dequantized floats in its own
/// order, so a value within rounding of half a grid step can take the neighbouring step in one
/// engine and not in the other, and that step is carried on. Such a step is rare, and small:
/// - at most [`INT8_DIFFERING_SHARE`] of the command components may differ by more than the
///   float [`TOLERANCE`] (seen: at most 3.3 %, `cnn-dagger1-observable-int8`; a wrong scale, zero
///   point or rounding rule moves nearly every command);
/// - none by more than [`INT8_CARRIED_STEPS`] steps of one hidden unit through the largest
///   weight of the command layer ([`int8_step`]; seen: at most 0.75 of one, the random int8
///   fixture, whose small weights leave several units a step off; 0.24 for
///   `cnn-8-16-4-8-distilled-dagger2-observable-int8`).
///
/// The figures are the same on CI's CPU and on the session's (AMD EPYC, AVX-512); an earlier
/// machine's tract rounded otherwise (the int8 fixture: 1.5e-8 there, 1.46e-4 here), and
/// both bounds also hold under `cross/test v5` (`qemu-i386 -cpu n270`).
const INT8_DIFFERING_SHARE: f64 = 0.15;
const INT8_CARRIED_STEPS: f32 = 3.0;

/// How far one hidden unit a grid step off moves a command, the largest over the policy's
/// networks ([`one_carried_step`]).
fn int8_step(manifest: &Path) -> f32 {
    let directory = manifest.parent().expect("a policy directory");
    let networks = PolicyManifest::load(manifest).expect("a manifest").networks;
    networks
        .iter()
        .map(|network| one_carried_step(&directory.join(network)))
        .fold(0.0, f32::max)
}

/// One grid step of the value the network's last `Gemm` reads (the scale of the
/// `DequantizeLinear` it comes from, through a ReLU, flatten or reshape), times the largest
/// magnitude of that `Gemm`'s float weights: how far one hidden unit a step off moves a command.
fn one_carried_step(network: &Path) -> f32 {
    let bytes = std::fs::read(network).unwrap_or_else(|e| panic!("{}: {e}", network.display()));
    let graph = pb::ModelProto::decode(bytes.as_slice())
        .unwrap_or_else(|e| panic!("{}: {e}", network.display()))
        .graph
        .expect("a graph");
    // tract (the oracle here) reads the constants, raw or typed, as it does for its own run.
    let resolver = tract_onnx::data_resolver::default();
    let floats = |name: &str| -> Vec<f32> {
        let tensor = graph
            .initializer
            .iter()
            .find(|t| t.name == name)
            .unwrap_or_else(|| panic!("{}: no constant {name}", network.display()));
        tract_onnx::tensor::load_tensor(&*resolver, tensor, None)
            .and_then(|t| Ok(t.try_as_plain_ram()?.as_slice::<f32>()?.to_vec()))
            .unwrap_or_else(|e| panic!("{}: {name}: {e}", network.display()))
    };
    let last = graph
        .node
        .iter()
        .rev()
        .find(|n| n.op_type == "Gemm")
        .unwrap_or_else(|| panic!("{}: no Gemm", network.display()));
    let largest_weight = floats(&last.input[1])
        .iter()
        .fold(0.0f32, |m, w| m.max(w.abs()));
    let mut value = &last.input[0];
    let step = loop {
        let producer = graph
            .node
            .iter()
            .find(|n| n.output.contains(value))
            .unwrap_or_else(|| panic!("{}: {value} comes from no node", network.display()));
        match producer.op_type.as_str() {
            "Relu" | "Flatten" | "Reshape" => value = &producer.input[0],
            // One scale per tensor as onnxruntime writes activations; the largest if more.
            "DequantizeLinear" => {
                break floats(&producer.input[1]).into_iter().fold(0.0, f32::max);
            }
            other => panic!(
                "{}: the command layer reads {other}, not a grid",
                network.display()
            ),
        }
    };
    assert!(step > 0.0 && largest_weight > 0.0, "{}", network.display());
    step * largest_weight
}

/// Every policy the tests compare: the fixtures and every model `models/policy` ships. The
/// paper's three rows and the one `HOST_MODEL` names must be there: a missing one fails.
/// The fixtures and every committed model; with `DRIBBLE_PARITY_ROWS=robot` (the emulated
/// Atoms, `cross/test`), the fixtures and the model the robot package ships (`ROBOT_MODEL`):
/// the fixtures hold one network of each kind the engine lowers (float, int8, hierarchical,
/// recurrent), so every kernel runs on the robot's instruction sets; the wider rows run the
/// same kernels longer, at emulated speed (four fifths of the V5 stage's test time), and are
/// checked on the host.
fn policies() -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> = ["cnn", "cnn-int8", "hcnn", "rcnn"]
        .iter()
        .map(|kind| fixture(kind).join("policy.toml"))
        .collect();
    let shipped = support::package_dir().join("../models/policy");
    let chosen = std::fs::read_to_string(shipped.join("HOST_MODEL"))
        .unwrap_or_else(|error| panic!("{}/HOST_MODEL: {error}", shipped.display()));
    for name in ["cnn", "hcnn", "rcnn", chosen.trim()] {
        let manifest = shipped.join(name).join("policy.toml");
        assert!(manifest.is_file(), "{} is missing", manifest.display());
    }
    let only_robot = match std::env::var("DRIBBLE_PARITY_ROWS") {
        Ok(rows) if rows == "robot" => true,
        Ok(rows) => panic!("DRIBBLE_PARITY_ROWS={rows}: `robot` or unset (every row)"),
        Err(_) => false,
    };
    if !only_robot {
        // A CNN that reads the last command: the same kernels as the CNN fixture's, one more
        // input into its dense layer; the robot package does not read it yet.
        found.push(fixture("cnn-previous").join("policy.toml"));
    }
    let robot = std::fs::read_to_string(shipped.join("ROBOT_MODEL"))
        .unwrap_or_else(|error| panic!("{}/ROBOT_MODEL: {error}", shipped.display()));
    let mut rows: Vec<PathBuf> = std::fs::read_dir(&shipped)
        .unwrap_or_else(|error| panic!("{}: {error}", shipped.display()))
        .filter_map(Result::ok)
        .filter(|entry| entry.path().is_dir())
        .filter(|entry| !only_robot || entry.file_name() == robot.trim())
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

/// How two policies' commands differ over the same steps.
struct Difference {
    /// The largest difference of one command component.
    worst: f32,
    /// Components that differ by more than the float engines' [`TOLERANCE`].
    differing: usize,
    compared: usize,
}

impl Difference {
    fn differing_share(&self) -> f64 {
        self.differing as f64 / self.compared as f64
    }
}

/// A policy's commands (forward, left, turn) over the same steps: an episode, then a reset and
/// a second one, so a recurrent state is carried and cleared.
fn commands(
    policy: &mut OnnxPolicy,
    steps: &[(Box<TopThumbnail>, Box<BottomThumbnail>)],
) -> Vec<[f32; 3]> {
    let mut found = Vec::with_capacity(2 * steps.len());
    for episode in 0..2 {
        policy.reset();
        // Each step is given the command the one before sent, as the control loop gives it.
        let mut previous = SpeedCommand::STOP;
        for (step, (top, bottom)) in steps.iter().enumerate() {
            let output = policy
                .step(PolicyInput {
                    top,
                    bottom,
                    previous,
                })
                .unwrap_or_else(|e| panic!("episode {episode} step {step}: {e}"));
            found.push([output.forward, output.left, output.turn]);
            previous = SpeedCommand::new(output.forward, output.left, output.turn)
                .unwrap_or(SpeedCommand::STOP);
        }
    }
    found
}

/// How two runs' commands differ, component by component.
fn difference(a: &[[f32; 3]], b: &[[f32; 3]]) -> Difference {
    assert_eq!(a.len(), b.len());
    let mut found = Difference {
        worst: 0.0,
        differing: 0,
        compared: 0,
    };
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        assert!(x.is_finite() && y.is_finite());
        found.worst = found.worst.max((x - y).abs());
        found.differing += usize::from((x - y).abs() > TOLERANCE);
        found.compared += 1;
    }
    found
}

#[test]
fn the_engine_matches_tract_on_every_model_and_instruction_set() {
    let steps = thumbnails(7, 60);
    let mut checked = 0;
    for path in policies() {
        // tract's commands once per model (under emulation tract is most of the time).
        let mut tract = load(&path, Engine::Tract, None);
        assert_eq!(tract.engine().compiled, None);
        let reference = commands(&mut tract, &steps);
        for isa in Isa::available() {
            let mut compiled = load(&path, Engine::Compiled, Some(isa));
            assert_eq!(
                compiled.engine().compiled,
                Some(isa),
                "{}: {}",
                path.display(),
                compiled.engine()
            );
            let found = difference(&commands(&mut compiled, &steps), &reference);
            let manifest = PolicyManifest::load(&path).expect("a manifest");
            let recurrent = manifest.recurrent.is_some();
            // An int8 manifest runs on the integer kernels, not on its float reading.
            let int8 = manifest.precision == Precision::Int8;
            assert_eq!(compiled.engine().int8, int8, "{}", path.display());
            let (tolerance, most_differing) = if int8 {
                (INT8_CARRIED_STEPS * int8_step(&path), INT8_DIFFERING_SHARE)
            } else if recurrent {
                (RECURRENT_TOLERANCE, 1.0)
            } else {
                (TOLERANCE, 1.0)
            };
            println!(
                "{} ({isa}): max |engine - tract| = {:.2e} (at most {tolerance:.2e}); {:.1} % of \
                 command components differ by more than {TOLERANCE:.0e}",
                path.display(),
                found.worst,
                100.0 * found.differing_share(),
            );
            assert!(
                found.worst <= tolerance,
                "{}, {isa}: {}",
                path.display(),
                found.worst
            );
            assert!(
                found.differing_share() <= most_differing,
                "{}, {isa}: {} of {} components differ",
                path.display(),
                found.differing,
                found.compared
            );
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
