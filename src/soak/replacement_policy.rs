//! The network the soak's "policy replaced" fault writes over the running policy's file: of
//! the same contract as the fixture's, answering one constant command.

use dribble_controller::policy::engine::onnx_builder::{Attribute, floats, model, node};
use prost::Message as _;

/// The command the replacement network answers whatever it sees (normalised forward, left,
/// turn); the running fixture or trained policy never computes exactly this.
pub const REPLACEMENT: [f32; 3] = [0.5, -0.375, 0.25];

/// A network of the fixture's contract (top [1,1,120,160], bottom [1,1,60,80] in, command
/// [1,3] out) that answers [`REPLACEMENT`]: both images are read (their maxima times zero),
/// so a loader takes it as it would take a trained one.
pub fn replacement_network() -> Vec<u8> {
    let keep = [("keepdims", Attribute::Int(1))];
    model(
        17,
        &[("top", &[1, 1, 120, 160]), ("bottom", &[1, 1, 60, 80])],
        vec![
            node("ReduceMax", &["top"], &["top_max"], &keep),
            node("ReduceMax", &["bottom"], &["bottom_max"], &keep),
            node("Add", &["top_max", "bottom_max"], &["both"], &[]),
            node(
                "Flatten",
                &["both"],
                &["flat"],
                &[("axis", Attribute::Int(1))],
            ),
            node("Mul", &["flat", "zero"], &["nothing"], &[]),
            node("Add", &["nothing", "answer"], &["command"], &[]),
        ],
        vec![
            floats("zero", &[], &[0.0]),
            floats("answer", &[1, 3], &REPLACEMENT),
        ],
        &["command"],
    )
    .encode_to_vec()
}
