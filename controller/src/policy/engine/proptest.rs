//! The lowering against tract: hostile graphs from the review (huge sizes, axes at the wrong
//! opset, values that only look constant) are refused or computed exactly, and random small
//! graphs of every operator the engine lowers give tract's answers on every instruction set
//! this CPU runs. [`super::oracle::compare`] is the judge throughout.

use proptest::prelude::*;
use tract_onnx::pb;

use super::Isa;
use super::onnx_builder::{Attribute, floats, ints, model, node};
use super::oracle::{Comparison, compare};

/// Compares on every instruction set; panics on a disagreement, returns the comparisons.
fn on_every_isa(model: &pb::ModelProto, inputs: &[(&str, &[usize])]) -> Vec<Comparison> {
    Isa::available()
        .map(|isa| {
            let comparison = compare(model, inputs, isa, 7, 3);
            assert!(
                !matches!(comparison, Comparison::Disagree(_)),
                "{isa}: {comparison:?}"
            );
            comparison
        })
        .collect()
}

fn assert_agrees(model: &pb::ModelProto, inputs: &[(&str, &[usize])]) {
    for comparison in on_every_isa(model, inputs) {
        assert!(
            matches!(comparison, Comparison::Agree { .. }),
            "{comparison:?}"
        );
    }
}

fn assert_refused(model: &pb::ModelProto, inputs: &[(&str, &[usize])], why: &str) {
    for comparison in on_every_isa(model, inputs) {
        match comparison {
            Comparison::EngineRefuses(reason) => {
                assert!(reason.contains(why), "refused for {reason:?}, not {why:?}")
            }
            other => panic!("{other:?}: the engine should refuse ({why})"),
        }
    }
}

fn weights(count: usize, seed: u32) -> Vec<f32> {
    (0..count)
        .map(|i| {
            ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 20) as f32 / 4096.0 - 0.5
        })
        .collect()
}

const IMAGE: [(&str, &[usize]); 1] = [("x", &[1, 1, 12, 16])];

#[test]
fn a_convolution_whose_pads_and_strides_would_wrap_is_refused() {
    for (pad, stride) in [
        (i64::MAX / 2, i64::MAX),
        (1 << 40, 1 << 41),
        ((1 << 31) - 1, 1 << 31),
        (1 << 25, 1 << 26),
    ] {
        let graph = model(
            13,
            &IMAGE,
            vec![node(
                "Conv",
                &["x", "w"],
                &["y"],
                &[
                    ("pads", Attribute::Ints(vec![pad, pad, pad, pad])),
                    ("strides", Attribute::Ints(vec![stride, stride])),
                ],
            )],
            vec![floats("w", &[3, 1, 1, 1], &[1.0, 2.0, 3.0])],
            &["y"],
        );
        for isa in Isa::available() {
            let comparison = compare(&graph, &IMAGE, isa, 1, 1);
            assert!(
                matches!(
                    comparison,
                    Comparison::EngineRefuses(_) | Comparison::TractRefuses(_)
                ),
                "pads {pad}, strides {stride}, {isa}: {comparison:?}"
            );
        }
    }
}

#[test]
fn the_lowering_itself_refuses_sizes_that_would_wrap() {
    // The loader refuses these before tract or the engine sees them (`model_limits`); the
    // lowering checks its own arithmetic all the same, for any caller.
    for (pad, stride) in [
        (i64::MAX / 2, i64::MAX),
        (1 << 61, (1 << 62) + 200),
        (1 << 25, 1 << 26),
    ] {
        let graph = model(
            13,
            &IMAGE,
            vec![node(
                "Conv",
                &["x", "w"],
                &["y"],
                &[
                    ("pads", Attribute::Ints(vec![pad, 0, pad, 0])),
                    ("strides", Attribute::Ints(vec![stride, 1000])),
                ],
            )],
            vec![floats("w", &[3, 1, 1, 1], &[1.0, 2.0, 3.0])],
            &["y"],
        );
        for isa in Isa::available() {
            let why = super::CompiledNetwork::lower(std::path::Path::new("x"), &graph, &IMAGE, isa)
                .expect_err("refused");
            assert!(why.0.contains("size"), "{isa}: {why:?}");
        }
    }
}

#[test]
fn a_tensor_past_the_size_limit_is_refused() {
    // A Reshape to a huge declared shape: the product wraps in 64 bits.
    let graph = model(
        13,
        &IMAGE,
        vec![node("Reshape", &["x", "shape"], &["y"], &[])],
        vec![ints("shape", &[3], &[1 << 32, 1 << 32, 192])],
        &["y"],
    );
    assert_refused(&graph, &IMAGE, "size 4294967296");
}

#[test]
fn flatten_counts_a_negative_axis_from_the_end() {
    for axis in [-1, -2, -3, -4, 0, 2, 4] {
        let graph = model(
            13,
            &IMAGE,
            vec![
                node("Flatten", &["x"], &["f"], &[("axis", Attribute::Int(axis))]),
                // Reads the flattened shape: a wrong outer/inner split changes the sums.
                node(
                    "ReduceSum",
                    &["f", "axes"],
                    &["y"],
                    &[("keepdims", Attribute::Int(0))],
                ),
            ],
            vec![ints("axes", &[1], &[0])],
            &["y"],
        );
        assert_agrees(&graph, &IMAGE);
    }
}

#[test]
fn a_graph_input_reshaped_is_not_taken_for_constant_weights() {
    let inputs: [(&str, &[usize]); 2] = [("a", &[1, 4]), ("b", &[1, 12])];
    let graph = model(
        13,
        &inputs,
        vec![
            node("Reshape", &["b", "shape"], &["b2"], &[]),
            node("Gemm", &["a", "b2"], &["y"], &[]),
        ],
        vec![ints("shape", &[2], &[4, 3])],
        &["y"],
    );
    assert_refused(&graph, &inputs, "must be a float constant");
}

#[test]
fn a_bias_of_higher_rank_than_its_product_keeps_the_broadcast_shape() {
    // x [4] times W [4, 3] is [3]; adding a [1, 3] bias makes [1, 3], whose sum over axis 0
    // is [3] again: folded into a [3] value, the sum would be over all three.
    let inputs: [(&str, &[usize]); 1] = [("x", &[4])];
    let graph = model(
        13,
        &inputs,
        vec![
            node("MatMul", &["x", "w"], &["p"], &[]),
            node("Add", &["p", "bias"], &["s"], &[]),
            node(
                "ReduceSum",
                &["s", "axes"],
                &["y"],
                &[("keepdims", Attribute::Int(0))],
            ),
        ],
        vec![
            floats("w", &[4, 3], &weights(12, 3)),
            floats("bias", &[1, 3], &[0.5, -1.0, 2.0]),
            ints("axes", &[1], &[0]),
        ],
        &["y"],
    );
    assert_agrees(&graph, &inputs);
}

#[test]
fn axes_are_read_where_the_opset_keeps_them() {
    let inputs: [(&str, &[usize]); 1] = [("x", &[1, 3, 1, 4])];
    let squeeze = |opset, attribute: bool| {
        let (names, attributes, constants) = if attribute {
            (
                vec!["x"],
                vec![("axes", Attribute::Ints(vec![0, 2]))],
                vec![],
            )
        } else {
            (vec!["x", "axes"], vec![], vec![ints("axes", &[2], &[0, 2])])
        };
        model(
            opset,
            &inputs,
            vec![node("Squeeze", &names, &["y"], &attributes)],
            constants,
            &["y"],
        )
    };
    assert_agrees(&squeeze(11, true), &inputs);
    assert_agrees(&squeeze(13, false), &inputs);
    assert_refused(&squeeze(13, true), &inputs, "axes attribute at opset 13");
    let reduce = |op: &str, opset| {
        model(
            opset,
            &inputs,
            vec![node(
                op,
                &["x"],
                &["y"],
                &[
                    ("axes", Attribute::Ints(vec![1])),
                    ("keepdims", Attribute::Int(0)),
                ],
            )],
            vec![],
            &["y"],
        )
    };
    // ReduceMax keeps an axes attribute until 18, ReduceSum until 13.
    assert_agrees(&reduce("ReduceMax", 13), &inputs);
    assert_agrees(&reduce("ReduceSum", 11), &inputs);
    assert_refused(&reduce("ReduceSum", 13), &inputs, "axes attribute");
}

#[test]
fn a_dense_layer_of_no_inputs_is_refused_not_a_panic() {
    let inputs: [(&str, &[usize]); 1] = [("x", &[1, 4])];
    let graph = model(
        13,
        &inputs,
        vec![
            node("Slice", &["x", "start", "end", "axis"], &["e"], &[]),
            node("MatMul", &["e", "w"], &["y"], &[]),
        ],
        vec![
            ints("start", &[1], &[0]),
            ints("end", &[1], &[0]),
            ints("axis", &[1], &[1]),
            floats("w", &[0, 3], &[]),
        ],
        &["y"],
    );
    for comparison in on_every_isa(&graph, &inputs) {
        assert!(
            !matches!(comparison, Comparison::Agree { .. }),
            "{comparison:?}"
        );
    }
}

// Random small graphs of each operator family.

/// 48 graphs a property natively; `PROPTEST_CASES` overrides it (`cross/test` asks for
/// fewer: under the emulated Atoms every case costs tract's optimisation at emulated speed,
/// and the host has already run the full count on the same code).
fn isa_cases() -> ProptestConfig {
    ProptestConfig {
        cases: std::env::var("PROPTEST_CASES")
            .ok()
            .and_then(|cases| cases.parse().ok())
            .unwrap_or(48),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(isa_cases())]

    #[test]
    fn convolutions_of_any_kernel_stride_and_padding_match_tract(
        channels in 1usize..6,
        filters in 1usize..20,
        kernel in (1usize..6, 1usize..6),
        stride in (1usize..4, 1usize..4),
        pads in (0usize..3, 0usize..3, 0usize..3, 0usize..3),
        size in (6usize..14, 6usize..14),
        relu in any::<bool>(),
        pool in prop::option::of((1usize..3, 1usize..3)),
        seed in any::<u32>(),
    ) {
        let shape = [1, channels, size.0, size.1];
        let inputs: [(&str, &[usize]); 1] = [("x", &shape)];
        let count = filters * channels * kernel.0 * kernel.1;
        let mut nodes = vec![node(
            "Conv",
            &["x", "w", "b"],
            &["c"],
            &[
                ("kernel_shape", Attribute::Ints(vec![kernel.0 as i64, kernel.1 as i64])),
                ("strides", Attribute::Ints(vec![stride.0 as i64, stride.1 as i64])),
                ("pads", Attribute::Ints(vec![pads.0 as i64, pads.1 as i64, pads.2 as i64, pads.3 as i64])),
            ],
        )];
        let mut last = "c";
        if relu {
            nodes.push(node("Relu", &[last], &["r"], &[]));
            last = "r";
        }
        if let Some((k, s)) = pool {
            nodes.push(node(
                "MaxPool",
                &[last],
                &["p"],
                &[
                    ("kernel_shape", Attribute::Ints(vec![k as i64, k as i64])),
                    ("strides", Attribute::Ints(vec![s as i64, s as i64])),
                ],
            ));
            last = "p";
        }
        nodes.push(node("Identity", &[last], &["y"], &[]));
        let graph = model(
            13,
            &inputs,
            nodes,
            vec![
                floats(
                    "w",
                    &[filters as i64, channels as i64, kernel.0 as i64, kernel.1 as i64],
                    &weights(count, seed),
                ),
                floats("b", &[filters as i64], &weights(filters, seed ^ 1)),
            ],
            &["y"],
        );
        on_every_isa(&graph, &inputs);
    }

    #[test]
    fn the_papers_five_by_five_stride_two_convolution_and_pool_match_tract(
        channels in prop::sample::select(vec![1usize, 4, 8, 16]),
        filters in prop::sample::select(vec![8usize, 16, 32]),
        size in (12usize..24, 12usize..30),
        seed in any::<u32>(),
    ) {
        // The Winograd and written-out window paths take exactly these layers.
        let shape = [1, channels, size.0, size.1];
        let inputs: [(&str, &[usize]); 1] = [("x", &shape)];
        let graph = model(
            13,
            &inputs,
            vec![
                node(
                    "Conv",
                    &["x", "w", "b"],
                    &["c"],
                    &[
                        ("strides", Attribute::Ints(vec![2, 2])),
                        ("pads", Attribute::Ints(vec![2, 2, 2, 2])),
                    ],
                ),
                node("Relu", &["c"], &["r"], &[]),
                node(
                    "MaxPool",
                    &["r"],
                    &["y"],
                    &[
                        ("kernel_shape", Attribute::Ints(vec![2, 2])),
                        ("strides", Attribute::Ints(vec![2, 2])),
                    ],
                ),
            ],
            vec![
                floats("w", &[filters as i64, channels as i64, 5, 5], &weights(filters * channels * 25, seed)),
                floats("b", &[filters as i64], &weights(filters, seed ^ 1)),
            ],
            &["y"],
        );
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(matches!(comparison, Comparison::Agree { .. }), "{:?}", comparison);
        }
    }

    #[test]
    fn dense_layers_by_gemm_and_matmul_match_tract(
        rows in 1usize..4,
        k in 1usize..70,
        n in 1usize..140,
        trans_b in any::<bool>(),
        alpha in prop::sample::select(vec![1.0f32, 0.5, -2.0]),
        beta in prop::sample::select(vec![1.0f32, 0.25]),
        bias_shape in 0usize..3,
        relu in any::<bool>(),
        matmul in any::<bool>(),
        seed in any::<u32>(),
    ) {
        let shape = [rows, k];
        let inputs: [(&str, &[usize]); 1] = [("x", &shape)];
        let bias_dims: Vec<i64> = match bias_shape {
            0 => vec![n as i64],
            1 => vec![1, n as i64],
            _ => vec![1],
        };
        let bias_count = if bias_shape == 2 { 1 } else { n };
        let mut nodes = Vec::new();
        let w_dims = if trans_b && !matmul { vec![n as i64, k as i64] } else { vec![k as i64, n as i64] };
        if matmul {
            nodes.push(node("MatMul", &["x", "w"], &["d"], &[]));
            nodes.push(node("Add", &["d", "b"], &["s"], &[]));
        } else {
            nodes.push(node(
                "Gemm",
                &["x", "w", "b"],
                &["s"],
                &[
                    ("transB", Attribute::Int(i64::from(trans_b))),
                    ("alpha", Attribute::Float(alpha)),
                    ("beta", Attribute::Float(beta)),
                ],
            ));
        }
        let last = if relu {
            nodes.push(node("Relu", &["s"], &["y"], &[]));
            "y"
        } else {
            "s"
        };
        let graph = model(
            13,
            &inputs,
            nodes,
            vec![
                floats("w", &w_dims, &weights(k * n, seed)),
                floats("b", &bias_dims, &weights(bias_count, seed ^ 5)),
            ],
            &[last],
        );
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(matches!(comparison, Comparison::Agree { .. }), "{:?}", comparison);
        }
    }

    #[test]
    fn element_wise_operators_broadcast_as_tract_does(
        a in prop::collection::vec(1usize..4, 1..4),
        b_mask in prop::collection::vec(any::<bool>(), 4),
        b_rank_cut in 0usize..2,
        op in prop::sample::select(vec!["Add", "Sub", "Mul", "Div"]),
        constant in any::<bool>(),
        seed in any::<u32>(),
    ) {
        // b: a's shape with some dimensions 1 and maybe fewer leading dimensions.
        let b: Vec<usize> = a
            .iter()
            .zip(&b_mask)
            .map(|(&d, &keep)| if keep { d } else { 1 })
            .skip(b_rank_cut.min(a.len() - 1))
            .collect();
        let inputs_owned: Vec<(&str, Vec<usize>)> = if constant {
            vec![("a", a.clone())]
        } else {
            vec![("a", a.clone()), ("b", b.clone())]
        };
        let inputs: Vec<(&str, &[usize])> =
            inputs_owned.iter().map(|(n, s)| (*n, s.as_slice())).collect();
        let constants = if constant {
            let dims: Vec<i64> = b.iter().map(|&d| d as i64).collect();
            vec![floats("b", &dims, &weights(b.iter().product(), seed))]
        } else {
            vec![]
        };
        let graph = model(13, &inputs, vec![node(op, &["a", "b"], &["y"], &[])], constants, &["y"]);
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(matches!(comparison, Comparison::Agree { .. }), "{:?}", comparison);
        }
    }

    #[test]
    fn reductions_over_any_axes_match_tract(
        shape in prop::collection::vec(1usize..5, 1..5),
        axes in prop::collection::vec(-4i64..4, 0..3),
        keepdims in any::<bool>(),
        max in any::<bool>(),
        opset in prop::sample::select(vec![11i64, 13]),
    ) {
        let rank = shape.len() as i64;
        let mut axes: Vec<i64> = axes.into_iter().filter(|&a| a >= -rank && a < rank).collect();
        axes.sort_by_key(|&a| (a + rank) % rank);
        axes.dedup_by_key(|a| (*a + rank) % rank);
        let inputs: [(&str, &[usize]); 1] = [("x", &shape)];
        let op = if max { "ReduceMax" } else { "ReduceSum" };
        let as_input = !max && opset >= 13;
        let mut attributes = vec![("keepdims", Attribute::Int(i64::from(keepdims)))];
        let (names, constants) = if as_input && !axes.is_empty() {
            (vec!["x", "axes"], vec![ints("axes", &[axes.len() as i64], &axes)])
        } else {
            if !axes.is_empty() {
                attributes.push(("axes", Attribute::Ints(axes.clone())));
            }
            (vec!["x"], vec![])
        };
        let graph = model(opset, &inputs, vec![node(op, &names, &["y"], &attributes)], constants, &["y"]);
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(
                matches!(comparison, Comparison::Agree { .. } | Comparison::EngineRefuses(_)),
                "{:?}", comparison
            );
            // Only a reduction to a scalar is refused.
            if let Comparison::EngineRefuses(why) = &comparison {
                prop_assert!(why.contains("scalar"), "{}", why);
            }
        }
    }

    #[test]
    fn reshapes_transposes_flattens_and_squeezes_move_numbers_as_tract_does(
        shape in prop::collection::vec(1usize..5, 2..5),
        perm_seed in any::<u64>(),
        flatten_axis in -4i64..5,
        seed in any::<u32>(),
    ) {
        let rank = shape.len();
        let mut perm: Vec<i64> = (0..rank as i64).collect();
        let mut state = perm_seed | 1;
        for i in (1..rank).rev() {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            perm.swap(i, (state % (i as u64 + 1)) as usize);
        }
        let flatten_axis = flatten_axis.clamp(-(rank as i64), rank as i64);
        let inputs: [(&str, &[usize]); 1] = [("x", &shape)];
        let total: usize = shape.iter().product();
        let graph = model(
            13,
            &inputs,
            vec![
                node("Transpose", &["x"], &["t"], &[("perm", Attribute::Ints(perm))]),
                node("Mul", &["t", "scale"], &["m"], &[]),
                node("Flatten", &["m"], &["f"], &[("axis", Attribute::Int(flatten_axis))]),
                node("Reshape", &["f", "shape"], &["r"], &[]),
                node("Unsqueeze", &["r", "axes"], &["u"], &[]),
                node("Squeeze", &["u", "axes"], &["y"], &[]),
            ],
            vec![
                floats("scale", &[1], &weights(1, seed)),
                ints("shape", &[2], &[-1, *shape.last().unwrap_or(&1) as i64]),
                ints("axes", &[1], &[0]),
            ],
            &["y"],
        );
        prop_assume!(total > 0);
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(matches!(comparison, Comparison::Agree { .. }), "{:?}", comparison);
        }
    }

    #[test]
    fn concatenations_and_gathers_match_tract(
        shape in prop::collection::vec(1usize..5, 1..4),
        axis_seed in any::<u8>(),
        indices in prop::collection::vec(-4i64..4, 1..4),
    ) {
        let rank = shape.len();
        let axis = usize::from(axis_seed) % rank;
        let dim = shape[axis] as i64;
        let indices: Vec<i64> = indices.into_iter().filter(|&i| i >= -dim && i < dim).collect();
        prop_assume!(!indices.is_empty());
        let inputs: [(&str, &[usize]); 2] = [("a", &shape), ("b", &shape)];
        let graph = model(
            13,
            &inputs,
            vec![
                node("Concat", &["a", "b"], &["c"], &[("axis", Attribute::Int(axis as i64))]),
                node("Gather", &["c", "i"], &["y"], &[("axis", Attribute::Int(axis as i64))]),
            ],
            vec![ints("i", &[indices.len() as i64], &indices)],
            &["y"],
        );
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(matches!(comparison, Comparison::Agree { .. }), "{:?}", comparison);
        }
    }

    #[test]
    fn one_lstm_step_matches_tract(
        features in 1usize..40,
        units in 1usize..20,
        with_bias in any::<bool>(),
        seed in any::<u32>(),
    ) {
        let (x, state) = ([1usize, 1, features], [1usize, 1, units]);
        let inputs: [(&str, &[usize]); 3] = [("x", &x), ("h", &state), ("c", &state)];
        let gates = 4 * units as i64;
        let mut constants = vec![
            floats("w", &[1, gates, features as i64], &weights(4 * units * features, seed)),
            floats("r", &[1, gates, units as i64], &weights(4 * units * units, seed ^ 3)),
        ];
        let bias = if with_bias {
            constants.push(floats("b", &[1, 2 * gates], &weights(8 * units, seed ^ 9)));
            "b"
        } else {
            ""
        };
        let graph = model(
            13,
            &inputs,
            vec![node(
                "LSTM",
                &["x", "w", "r", bias, "", "h", "c"],
                &["", "h_out", "c_out"],
                &[("hidden_size", Attribute::Int(units as i64))],
            )],
            constants,
            &["h_out", "c_out"],
        );
        for comparison in on_every_isa(&graph, &inputs) {
            prop_assert!(matches!(comparison, Comparison::Agree { .. }), "{:?}", comparison);
        }
    }
}
