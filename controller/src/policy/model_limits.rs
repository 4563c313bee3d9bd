//! What a model file may declare, checked before tract sees the file.
//!
//! tract trusts some attributes, and a hostile value takes the controller down at load
//! (both found by the engine fuzzer, `controller/examples/fuzz_engine.rs`):
//! - a convolution's or pooling's padding of `i64::MAX`: its planner walks the padded range
//!   element by element (`tract_core::ops::cnn::patch_axis::make_invalid_regions` never
//!   returns); other huge sizes make it panic. No network of this project needs a padding,
//!   stride, dilation or kernel past [`MAX_SPATIAL`].
//! - a Transpose whose `perm` is not a permutation (`[0, 2, 1, 0]`): its
//!   `change_axes::perm_to_cycles` grows a list without end (4.8 GB in six seconds, then the
//!   kernel kills the process).
//!
//! The loader refuses such a file with the node and the value ([`check`]), so neither tract
//! nor the engine ever plans it.

use tract_onnx::pb;

/// The largest padding, stride, dilation or kernel size a node may declare (the cameras'
/// images are 640 pixels wide; the networks see at most 160).
pub const MAX_SPATIAL: i64 = 1 << 16;

/// The attributes that size a window or its steps.
const SPATIAL: [&str; 6] = [
    "pads",
    "strides",
    "dilations",
    "kernel_shape",
    "output_padding",
    "output_shape",
];

/// Checks every node (in the graph and in any subgraph an attribute holds): spatial
/// attributes within `0..=MAX_SPATIAL`, a Transpose's `perm` a permutation. Returns the
/// first node and value that is not.
pub fn check(model: &pb::ModelProto) -> Result<(), String> {
    model.graph.as_ref().map_or(Ok(()), check_graph)
}

fn check_graph(graph: &pb::GraphProto) -> Result<(), String> {
    for node in &graph.node {
        for attribute in &node.attribute {
            if node.op_type == "Transpose" && attribute.name == "perm" {
                let mut sorted = attribute.ints.clone();
                sorted.sort_unstable();
                if sorted.iter().enumerate().any(|(i, &p)| p != i as i64) {
                    return Err(format!(
                        "node {:?} (Transpose) declares perm = {:?}: not a permutation",
                        node.name, attribute.ints
                    ));
                }
            }
            if SPATIAL.contains(&attribute.name.as_str())
                && let Some(&bad) = attribute
                    .ints
                    .iter()
                    .find(|&&v| !(0..=MAX_SPATIAL).contains(&v))
            {
                return Err(format!(
                    "node {:?} ({}) declares {} = {bad}: sizes from 0 to {MAX_SPATIAL} only",
                    node.name, node.op_type, attribute.name
                ));
            }
            for subgraph in attribute.g.iter().chain(&attribute.graphs) {
                check_graph(subgraph)?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::engine::onnx_builder::{Attribute, model, node};

    fn conv(pads: Vec<i64>) -> pb::ModelProto {
        model(
            13,
            &[("x", &[1, 1, 4, 4])],
            vec![node(
                "Conv",
                &["x", "w"],
                &["y"],
                &[("pads", Attribute::Ints(pads))],
            )],
            vec![],
            &["y"],
        )
    }

    #[test]
    fn sizes_past_the_limit_or_negative_are_refused_with_the_node() {
        assert_eq!(check(&conv(vec![0, 1, 2, MAX_SPATIAL])), Ok(()));
        for bad in [MAX_SPATIAL + 1, i64::MAX, -1, i64::MIN] {
            let why = check(&conv(vec![0, bad, 0, 0])).expect_err("refused");
            assert!(
                why.contains("Conv") && why.contains(&bad.to_string()),
                "{why}"
            );
        }
    }

    #[test]
    fn a_transpose_must_permute() {
        let transpose = |perm: Vec<i64>| {
            model(
                13,
                &[("x", &[1, 2, 3, 4])],
                vec![node(
                    "Transpose",
                    &["x"],
                    &["y"],
                    &[("perm", Attribute::Ints(perm))],
                )],
                vec![],
                &["y"],
            )
        };
        assert_eq!(check(&transpose(vec![0, 3, 1, 2])), Ok(()));
        for bad in [vec![0, 2, 1, 0], vec![0, 1, 2, 4], vec![-1, 0, 1, 2]] {
            let why = check(&transpose(bad.clone())).expect_err("refused");
            assert!(why.contains("not a permutation"), "{bad:?}: {why}");
        }
    }
}
