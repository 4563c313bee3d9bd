//! The engine's tests: the plan's layout and kernels on small graphs, the CNN fixture's
//! lowering (pools folded, multiply-adds counted), quantization refused with a reason, and
//! the int8 networks against tract and onnxruntime. The property tests of the lowering are
//! in `proptest.rs`, the int8 kernels' in `kernels/int8/tests.rs`.

use super::*;
use tract_onnx::prelude::Framework;

/// The CNN fixture's file and parsed model.
fn cnn_fixture() -> (PathBuf, pb::ModelProto) {
    let path = crate::package_dir().join("../models/fixtures/cnn/policy.onnx");
    let bytes = std::fs::read(&path).expect("fixture");
    let proto = tract_onnx::onnx()
        .proto_model_for_read(&mut &bytes[..])
        .expect("parses");
    (path, proto)
}

/// The CNN fixture's inputs: names and shapes.
const CNN_INPUTS: [(&str, &[usize]); 2] = [("top", &[1, 1, 120, 160]), ("bottom", &[1, 1, 60, 80])];

#[test]
fn aligned_weights_start_on_a_64_byte_boundary_and_keep_their_values() {
    for len in [0, 1, 7, 8, 25 * 16, 1000] {
        let values: Vec<f32> = (0..len).map(|i| i as f32 * 0.5 - 3.0).collect();
        // Moved after construction, as a plan's steps are.
        let weights = vec![layout::AlignedWeights::new(&values)].remove(0);
        let slice = weights.as_slice();
        assert_eq!(slice, &values[..], "length {len}");
        assert!(
            slice
                .as_ptr()
                .addr()
                .is_multiple_of(layout::AlignedWeights::ALIGN),
            "length {len}: starts at {:p}",
            slice.as_ptr()
        );
    }
}

/// A plan of one dense layer, `inputs` -> `outputs`, panels as `isa` lays them out.
fn dense_plan(isa: Isa, weights: &[f32], bias: &[f32], x: &[f32]) -> CompiledNetwork {
    let (outputs, inputs) = (bias.len(), x.len());
    CompiledNetwork {
        path: PathBuf::from("dense"),
        isa,
        steps: vec![Step::Dense {
            from: 0,
            weights: layout::DenseWeights::from_rows(
                weights,
                outputs,
                inputs,
                isa.dense_panel_width(),
            ),
            bias: bias.to_vec(),
            rows: 1,
            relu: false,
            to: 1,
        }],
        buffers: vec![x.to_vec(), vec![f32::NAN; outputs]],
        nonzero: vec![u32::MAX; inputs],
        inputs: vec![],
        outputs: vec![("y".into(), 1, outputs)],
    }
}

#[test]
fn dense_panels_skip_zero_inputs_and_match_the_plain_sum_on_every_path() {
    for (inputs, outputs) in [(2560, 128), (192, 256), (128, 3), (13, 130), (1, 8)] {
        let weights: Vec<f32> = (0..inputs * outputs)
            .map(|i| ((i * 7919 % 1000) as f32 - 500.0) / 4000.0)
            .collect();
        let bias: Vec<f32> = (0..outputs).map(|o| o as f32 / 100.0 - 0.5).collect();
        // Every third input zero (as after ReLU), one a negative zero.
        let mut x: Vec<f32> = (0..inputs)
            .map(|i| {
                if i % 3 == 1 {
                    0.0
                } else {
                    (i % 11) as f32 / 7.0 - 0.6
                }
            })
            .collect();
        if inputs > 5 {
            x[5] = -0.0;
        }
        // The sum in f64, and a bound on f32's rounding: 1e-6 of the terms' magnitude.
        let expected: Vec<(f64, f64)> = (0..outputs)
            .map(|o| {
                let row = &weights[o * inputs..(o + 1) * inputs];
                let terms = row.iter().zip(&x).map(|(&w, &v)| w as f64 * v as f64);
                let magnitude: f64 = terms.clone().map(f64::abs).sum();
                (
                    terms.sum::<f64>() + bias[o] as f64,
                    1e-6 * (1.0 + magnitude),
                )
            })
            .collect();
        for isa in Isa::available() {
            let mut plan = dense_plan(isa, &weights, &bias, &x);
            plan.run();
            let y = plan.output("y").expect("output");
            for (o, (&got, &(want, bound))) in y.iter().zip(&expected).enumerate() {
                assert!(
                    (got as f64 - want).abs() <= bound,
                    "{isa}, {inputs}x{outputs}, output {o}: {got} against {want}"
                );
            }
            // A NaN input is not skipped: it reaches every output.
            let mut with_nan = x.clone();
            with_nan[0] = f32::NAN;
            let mut plan = dense_plan(isa, &weights, &bias, &with_nan);
            plan.run();
            assert!(
                plan.output("y").expect("output").iter().all(|v| v.is_nan()),
                "{isa}"
            );
        }
    }
}

#[test]
fn dense_panels_are_as_wide_as_the_outputs_need_and_the_kernels_hold() {
    let panel =
        |outputs, max| layout::DenseWeights::from_rows(&vec![1.0; outputs * 4], outputs, 4, max);
    assert_eq!(panel(3, 64).width(), 8);
    assert_eq!(panel(9, 64).width(), 16);
    assert_eq!(panel(128, 64).width(), 64);
    assert_eq!(panel(128, 16).width(), 16);
    let weights = panel(20, 16);
    // Two panels of 16: outputs 16..20 in the second, its other columns zero.
    assert_eq!(weights.panels().len(), 2 * 4 * 16);
    assert_eq!(
        &weights.panels()[4 * 16..4 * 16 + 5],
        &[1.0, 1.0, 1.0, 1.0, 0.0]
    );
    assert!(
        weights
            .panels()
            .as_ptr()
            .addr()
            .is_multiple_of(layout::AlignedWeights::ALIGN)
    );
}

#[test]
fn each_pool_of_the_cnn_fixture_is_folded_into_its_convolution() {
    let (path, proto) = cnn_fixture();
    let graph = proto.graph.as_ref().expect("graph");
    let network =
        CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, Isa::Portable).expect("lowers");
    let pools = graph.node.iter().filter(|n| n.op_type == "MaxPool").count();
    let folded: Vec<_> = network
        .steps
        .iter()
        .filter_map(|step| match step {
            Step::Conv {
                pool: Some(pool),
                relu,
                ..
            } => Some((pool.kernel, *relu)),
            _ => None,
        })
        .collect();
    assert_eq!(
        pools, 4,
        "the fixture has a pool after each of its four convolutions"
    );
    assert_eq!(folded, vec![([2, 2], true); 4]);
    assert!(
        !network
            .steps
            .iter()
            .any(|s| matches!(s, Step::MaxPool { .. }))
    );
}

/// The robot package's float student (four channels out of each camera's first layer)
/// runs those layers vectorised over pooled pixels on x86-64's vector sets, and gives
/// tract's command there.
#[cfg(target_arch = "x86_64")]
#[test]
fn a_narrow_first_layer_runs_vectorised_over_pooled_pixels() {
    let (path, proto) = committed_network("policy", "cnn-4-16-4-8-distilled-dagger2-observable");
    let network = CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, Isa::Sse42).expect("lowers");
    let planes: Vec<_> = network
        .steps
        .iter()
        .filter_map(|step| match step {
            Step::Conv {
                pool: Some(pool),
                shape,
                ..
            } => Some((shape.in_channels, pool.planes.is_some())),
            _ => None,
        })
        .collect();
    assert_eq!(planes, [(1, true), (4, false), (1, true), (4, false)]);
    for isa in Isa::available() {
        match oracle::compare(&proto, &CNN_INPUTS, isa, 31, 3) {
            oracle::Comparison::Agree { largest_difference } => {
                println!("{isa}: largest difference from tract {largest_difference}");
            }
            other => panic!("{isa}: {other:?}"),
        }
    }
}

#[test]
fn the_cnn_fixture_counts_the_multiply_adds_of_the_papers_layers() {
    let (path, proto) = cnn_fixture();
    let network =
        CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, Isa::Portable).expect("lowers");
    // Output pixels times a 5x5 window times input and output channels, per layer. The
    // top camera's second convolution has 15 rows, of which its 2x2 pool reads 14: the
    // fifteenth is never computed, and not counted.
    let top = 60 * 80 * 25 * 16 + 14 * 20 * 25 * 16 * 32;
    let bottom = 30 * 40 * 25 * 8 + 8 * 10 * 25 * 8 * 16;
    let head = 2560 * 128 + 128 * 3;
    assert_eq!(network.multiply_adds(), top + bottom + head);
    assert_eq!(network.multiply_adds(), 6_328_064);
}

#[test]
fn a_grid_rounds_half_to_even_saturates_and_snaps_to_its_codes() {
    let grid = layout::Grid::new(0.5, 3).expect("grid");
    let dequantize = |code: u8| (f32::from(code) - 3.0) * 0.5;
    // x / 0.5 = 0.5, 1.5, 2.5, -0.5, -1.5 round to 0, 2, 2, -0, -2 (half to even), plus 3.
    for (x, code) in [(0.25, 3), (0.75, 5), (1.25, 5), (-0.25, 3), (-0.75, 1)] {
        assert_eq!(grid.code(x), code, "{x}");
        assert_eq!(grid.snap(x), dequantize(code), "{x}");
    }
    // Saturation at both ends, and far outside.
    for (x, code) in [
        (-1.5, 0),
        (-100.0, 0),
        (126.0, 255),
        (1e30, 255),
        (-1e30, 0),
    ] {
        assert_eq!(grid.code(x), code, "{x}");
        assert_eq!(grid.snap(x), dequantize(code), "{x}");
    }
    // Every code's own value snaps onto itself, exactly, for a scale like the policies'.
    let grid = layout::Grid::new(0.011_601_844, 17).expect("grid");
    for code in 0..=255u8 {
        let value = f32::from(i16::from(code) - 17) * 0.011_601_844;
        assert_eq!(grid.code(value), code);
        assert_eq!(grid.snap(value).to_bits(), value.to_bits());
    }
    assert!(layout::Grid::new(0.0, 0).is_none() && layout::Grid::new(f32::NAN, 0).is_none());
}

#[test]
fn malformed_quantization_is_refused_with_a_reason_not_a_panic() {
    use onnx_builder::{Attribute, floats, model, node};
    let codes = |name: &str, data_type: i32, shape: &[i64], raw: &[u8]| pb::TensorProto {
        name: name.to_owned(),
        dims: shape.to_vec(),
        data_type,
        raw_data: raw.to_vec(),
        ..Default::default()
    };
    let (uint8, int8) = (2, 3);
    let lower = |nodes, initializers| {
        let graph = model(17, &[("x", &[1, 4])], nodes, initializers, &["y"]);
        CompiledNetwork::lower(Path::new("q"), &graph, &[("x", &[1, 4])], Isa::Portable)
    };
    // Several scales for a scalar; a scale of zero; a DequantizeLinear on another grid
    // than its QuantizeLinear; a zero point of the wrong type; raw data of the wrong
    // length: each refused, none a panic.
    let cases: Vec<(Vec<pb::NodeProto>, Vec<pb::TensorProto>)> = vec![
        (
            vec![
                node(
                    "DequantizeLinear",
                    &["w", "s2"],
                    &["wf"],
                    &[("axis", Attribute::Int(0))],
                ),
                node("Add", &["x", "wf"], &["y"], &[]),
            ],
            vec![
                codes("w", int8, &[], &[3]),
                floats("s2", &[2], &[0.5, 0.25]),
            ],
        ),
        (
            vec![
                node("QuantizeLinear", &["x", "zero_scale", "z"], &["q"], &[]),
                node("DequantizeLinear", &["q", "zero_scale", "z"], &["y"], &[]),
            ],
            vec![
                floats("zero_scale", &[], &[0.0]),
                codes("z", uint8, &[], &[0]),
            ],
        ),
        (
            vec![
                node("QuantizeLinear", &["x", "s", "z"], &["q"], &[]),
                node("DequantizeLinear", &["q", "t", "z"], &["y"], &[]),
            ],
            vec![
                floats("s", &[], &[0.5]),
                floats("t", &[], &[0.25]),
                codes("z", uint8, &[], &[0]),
            ],
        ),
        (
            vec![
                node("QuantizeLinear", &["x", "s", "z"], &["q"], &[]),
                node("DequantizeLinear", &["q", "s", "z"], &["y"], &[]),
            ],
            vec![floats("s", &[], &[0.5]), codes("z", int8, &[], &[0])],
        ),
        (
            vec![
                node("DequantizeLinear", &["w", "s"], &["wf"], &[]),
                node("Add", &["x", "wf"], &["y"], &[]),
            ],
            vec![
                codes("w", int8, &[1, 4], &[1, 2, 3]),
                floats("s", &[], &[0.5]),
            ],
        ),
    ];
    for (i, (nodes, initializers)) in cases.into_iter().enumerate() {
        match lower(nodes, initializers) {
            Err(Unsupported(why)) => println!("case {i}: {why}"),
            Ok(_) => panic!("case {i} was lowered"),
        }
    }
}

/// A fixture's file and parsed model, by directory name.
fn fixture(name: &str) -> (PathBuf, pb::ModelProto) {
    committed_network("fixtures", name)
}

/// `models/<folder>/<name>/policy.onnx` and its parsed model.
fn committed_network(folder: &str, name: &str) -> (PathBuf, pb::ModelProto) {
    let path = crate::package_dir()
        .join("../models")
        .join(folder)
        .join(name)
        .join("policy.onnx");
    let bytes = std::fs::read(&path).expect("committed network");
    let proto = tract_onnx::onnx()
        .proto_model_for_read(&mut &bytes[..])
        .expect("parses");
    (path, proto)
}

#[test]
fn an_int8_cnn_runs_its_hidden_layers_on_integer_steps_and_agrees_with_tract() {
    // The CNN fixture quantized by onnxruntime (QDQ): its four convolutions and its
    // hidden dense layer in integers, the output layer in floats, on every instruction
    // set; tract, which runs the same QDQ file, is the oracle.
    let (path, proto) = fixture("cnn-int8");
    for isa in Isa::available() {
        let network = CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, isa)
            .unwrap_or_else(|why| panic!("{isa}: {}", why.0));
        let count = |kind: fn(&Step) -> bool| network.steps.iter().filter(|s| kind(s)).count();
        assert_eq!(count(|s| matches!(s, Step::QuantizedConv(_))), 4, "{isa}");
        assert_eq!(count(|s| matches!(s, Step::QuantizedDense(_))), 1, "{isa}");
        assert_eq!(count(|s| matches!(s, Step::Dense { .. })), 1, "{isa}");
        assert_eq!(count(|s| matches!(s, Step::Conv { .. })), 0, "{isa}");
        // Every max-pool folded into the convolution before it.
        assert_eq!(count(|s| matches!(s, Step::MaxPool { .. })), 0, "{isa}");
        // The conv outputs' grids go into the convolutions; the pairs of the inputs,
        // the pooled maps and the features into the codings of the int8 steps that read
        // them (`fold_snaps`).
        assert_eq!(count(|s| matches!(s, Step::SnapToGrid { .. })), 0, "{isa}");
        assert_eq!(network.int8_steps(), 5);
        assert_eq!(network.tolerance(), oracle::INT8_TOLERANCE);
        match oracle::compare(&proto, &CNN_INPUTS, isa, 29, 3) {
            oracle::Comparison::Agree { largest_difference } => {
                println!("{isa}: largest difference from tract {largest_difference}");
            }
            other => panic!("{isa}: {other:?}"),
        }
    }
}

#[test]
fn a_max_pool_folded_into_an_int8_convolution_gives_the_separate_pools_numbers_bit_for_bit() {
    // The same QDQ file twice: as it is (each pool folded into its convolution) and with
    // the pools' inputs made graph outputs too (a second reader: no fold, a MaxPool step
    // of its own over the epilogue's floats). Every command must be the same bits.
    // The pools' outputs are graph outputs in both, so that they are compared too.
    let (path, mut folded) = fixture("cnn-int8");
    let pools = |proto: &pb::ModelProto| -> Vec<(String, String)> {
        let graph = proto.graph.as_ref().expect("graph");
        let pools = graph.node.iter().filter(|n| n.op_type == "MaxPool");
        pools
            .map(|n| (n.input[0].clone(), n.output[0].clone()))
            .collect()
    };
    let names = pools(&folded);
    assert_eq!(names.len(), 4);
    let mut outputs = vec!["command".to_owned()];
    let graph = folded.graph.as_mut().expect("graph");
    for (_, pooled) in &names {
        graph.output.push(onnx_builder::value_info(pooled, None));
        outputs.push(pooled.clone());
    }
    let mut separate = folded.clone();
    let graph = separate.graph.as_mut().expect("graph");
    for (input, _) in &names {
        graph.output.push(onnx_builder::value_info(input, None));
    }
    let mut rng = 0x2545_f491_u32;
    for isa in Isa::available() {
        let mut networks = lowered_pair(&path, [&folded, &separate], isa);
        let pools = count_steps(&networks, |s| matches!(s, Step::MaxPool { .. }));
        assert_eq!(pools, [0, 4], "{isa}");
        for _ in 0..3 {
            let thumbnails = random_thumbnails(&mut rng);
            let commands = networks
                .each_mut()
                .map(|n| output_bits(n, &thumbnails, &outputs));
            assert_eq!(
                commands[0].len(),
                3 + 7 * 10 * 32 + 4 * 5 * 16 + 30 * 40 * 16 + 15 * 20 * 8
            );
            assert_eq!(commands[0], commands[1], "{isa}");
        }
    }
}

#[test]
fn an_int8_step_coding_a_pairs_input_itself_gives_the_snapped_maps_numbers_bit_for_bit() {
    // The same QDQ file twice: as it is (each activation pair that only an int8 step
    // reads is folded into that step's coding) and with the pairs' outputs made graph
    // outputs (a second reader: each stays a SnapToGrid step of its own). The commands
    // must be the same bits.
    let (path, folded) = fixture("cnn-int8");
    let mut separate = folded.clone();
    let graph = separate.graph.as_mut().expect("graph");
    let quantized: Vec<String> = graph
        .node
        .iter()
        .filter(|n| n.op_type == "QuantizeLinear")
        .map(|n| n.output[0].clone())
        .collect();
    let pairs: Vec<String> = graph
        .node
        .iter()
        .filter(|n| n.op_type == "DequantizeLinear" && quantized.contains(&n.input[0]))
        .map(|n| n.output[0].clone())
        .collect();
    for name in &pairs {
        graph.output.push(onnx_builder::value_info(name, None));
    }
    let mut rng = 0x9e37_79b9_u32;
    for isa in Isa::available() {
        let mut networks = lowered_pair(&path, [&folded, &separate], isa);
        let snaps = count_steps(&networks, |s| matches!(s, Step::SnapToGrid { .. }));
        assert_eq!(snaps, [0, 5], "{isa}");
        for _ in 0..3 {
            let thumbnails = random_thumbnails(&mut rng);
            let commands = networks
                .each_mut()
                .map(|n| output_bits(n, &thumbnails, &["command"]));
            assert_eq!(commands[0], commands[1], "{isa}");
        }
    }
}

/// Two variants of one file, lowered for `isa`.
fn lowered_pair(path: &Path, protos: [&pb::ModelProto; 2], isa: Isa) -> [CompiledNetwork; 2] {
    protos.map(|proto| {
        CompiledNetwork::lower(path, proto, &CNN_INPUTS, isa)
            .unwrap_or_else(|why| panic!("{isa}: {}", why.0))
    })
}

fn count_steps(networks: &[CompiledNetwork; 2], kind: fn(&Step) -> bool) -> [usize; 2] {
    networks
        .each_ref()
        .map(|n| n.steps.iter().filter(|s| kind(s)).count())
}

/// A top and a bottom thumbnail of random bytes (xorshift from `rng`), as the network
/// sees them (`u8 / 255`), one after the other.
fn random_thumbnails(rng: &mut u32) -> Vec<f32> {
    (0..120 * 160 + 60 * 80)
        .map(|_| {
            *rng ^= *rng << 13;
            *rng ^= *rng >> 17;
            *rng ^= *rng << 5;
            f32::from((*rng >> 24) as u8) / 255.0
        })
        .collect()
}

/// Runs `network` on `thumbnails` and returns the bits of the named outputs, in order.
fn output_bits(
    network: &mut CompiledNetwork,
    thumbnails: &[f32],
    names: &[impl AsRef<str>],
) -> Vec<u32> {
    let (top, bottom) = thumbnails.split_at(120 * 160);
    network.input_mut("top").expect("top").copy_from_slice(top);
    network
        .input_mut("bottom")
        .expect("bottom")
        .copy_from_slice(bottom);
    network.run();
    names
        .iter()
        .flat_map(|name| {
            network
                .output(name.as_ref())
                .expect("output")
                .iter()
                .map(|v| v.to_bits())
        })
        .collect()
}

/// The robot package's int8 network (four channels out of each camera's first layer):
/// those layers run over pooled pixels on x86-64 and give the window kernels' numbers bit
/// for bit.
#[cfg(target_arch = "x86_64")]
#[test]
fn the_cameras_int8_layers_over_pooled_pixels_give_the_window_kernels_numbers_bit_for_bit() {
    let (path, proto) =
        committed_network("policy", "cnn-4-16-4-8-distilled-dagger2-observable-int8");
    let mut rng = 0x9e37_79b9;
    let inputs: Vec<Vec<f32>> = (0..3).map(|_| random_thumbnails(&mut rng)).collect();
    for isa in Isa::available().filter(|isa| *isa >= Isa::Ssse3) {
        let mut pooled = CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, isa).expect("lowers");
        let mut windows = CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, isa).expect("lowers");
        let mut taken = 0;
        for step in &mut windows.steps {
            if let Step::QuantizedConv(conv) = step
                && conv.pooled_pixels.take().is_some()
            {
                taken += 1;
            }
        }
        assert_eq!(taken, 2, "{isa}: both cameras' first layers");
        for thumbnails in &inputs {
            assert_eq!(
                output_bits(&mut pooled, thumbnails, &["command"]),
                output_bits(&mut windows, thumbnails, &["command"]),
                "{isa}"
            );
        }
    }
}

#[test]
fn an_int8_cnn_gives_onnxruntimes_commands_on_its_reference_thumbnails() {
    let (path, proto) = fixture("cnn-int8");
    let reference = path.with_file_name("reference");
    let thumbnails = std::fs::read(reference.join("thumbnails.u8")).expect("thumbnails");
    let commands: Vec<f32> = std::fs::read(reference.join("commands.f32"))
        .expect("commands")
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let (top, bottom) = (120 * 160, 60 * 80);
    let steps = thumbnails.len() / (top + bottom);
    assert!(steps >= 4 && commands.len() == 3 * steps);
    for isa in Isa::available() {
        let mut network = CompiledNetwork::lower(&path, &proto, &CNN_INPUTS, isa).expect("lowers");
        let mut worst = 0.0f32;
        for (step, pair) in thumbnails.chunks_exact(top + bottom).enumerate() {
            let scale = 1.0 / 255.0;
            for (name, pixels) in [("top", &pair[..top]), ("bottom", &pair[top..])] {
                let input = network.input_mut(name).expect("input");
                for (x, &p) in input.iter_mut().zip(pixels) {
                    *x = f32::from(p) * scale;
                }
            }
            network.run();
            let output = network.output("command").expect("command");
            for (a, b) in output.iter().zip(&commands[3 * step..3 * step + 3]) {
                worst = worst.max((a - b).abs());
            }
        }
        println!("{isa}: largest difference from onnxruntime {worst}");
        assert!(worst <= 1e-2, "{isa}: {worst}");
    }
}

#[test]
#[ignore = "profiling aid: cargo test --release -p dribble-controller profile -- --ignored --nocapture"]
fn profile_the_cnn_fixture() {
    for (path, proto) in [cnn_fixture(), fixture("cnn-int8")] {
        println!("{}", path.display());
        profile(&path, &proto);
    }
}

fn profile(path: &Path, proto: &pb::ModelProto) {
    for isa in Isa::available() {
        let mut network = CompiledNetwork::lower(path, proto, &CNN_INPUTS, isa).expect("lowers");
        let report = network.profile(2000);
        let total: std::time::Duration = report.iter().map(|(_, t, _)| *t).sum();
        // An int8 plan's share is of the int8 peak (its float steps are a few
        // thousandths of the arithmetic).
        let peak = if network.int8_steps() > 0 {
            peak::int8_multiply_adds_per_second(isa)
        } else {
            peak::multiply_adds_per_second(isa)
        };
        let share = |macs: u64, time: std::time::Duration| {
            peak.map_or(String::new(), |peak| {
                format!("{:5.1} %", 100.0 * macs as f64 / peak / time.as_secs_f64())
            })
        };
        println!(
            "{isa}: {total:?}, {} of the measured peak",
            share(network.multiply_adds(), total)
        );
        for (step, time, macs) in report {
            println!("  {time:>10?} {:>8} {step}", share(macs, time));
        }
    }
}
