//! The load check: before the compiled engine is trusted with a network from outside, its
//! plan runs beside tract on the same pseudo-random inputs and every output the controller
//! reads must agree within the plan's tolerance.
//!
//! The agreement rule is the engine oracle's ([`oracle::agree`]), so the fuzz target, the
//! property tests and the controller judge a plan alike. The inputs are not the oracle's:
//! the check feeds what the controller feeds (thumbnails through the manifest's
//! normalisation, recurrent states, the last command) through the ports the manifest
//! names, and reads only the outputs the controller reads.

use std::sync::Arc;

use tract_onnx::prelude::{TValue, Tensor};

use super::network::PortNames;
use crate::policy::engine::{CompiledNetwork, oracle};
use crate::policy::manifest::{BOTTOM_SHAPE, PREVIOUS_SHAPE, PolicyManifest, TOP_SHAPE};
use crate::policy::network_input::write_network_input;
use crate::policy::onnx_network::{OnnxNetwork, Port};

/// The pseudo-random numbers of the check (xorshift64: the same draws on every machine).
struct Draws(u64);

impl Draws {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// `count` values in [-1, 1).
    fn signed(&mut self, count: usize) -> Vec<f32> {
        (0..count)
            .map(|_| (self.next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0)
            .collect()
    }

    /// A thumbnail of `shape`'s random pixels through the manifest's normalisation.
    fn thumbnail(&mut self, shape: &[usize], manifest: &PolicyManifest) -> Vec<f32> {
        let pixels: Vec<u8> = (0..shape.iter().product::<usize>())
            .map(|_| (self.next() >> 56) as u8)
            .collect();
        let mut values = vec![0.0; pixels.len()];
        write_network_input(&manifest.normalisation, &pixels, &mut values);
        values
    }
}

/// One input of a probe: its port, its name in the file, its shape and its values.
type Feed<'n> = (Port, &'n str, &'n [usize], Vec<f32>);

/// A probe's inputs (both thumbnails; the last command, and the recurrent states in
/// [-1, 1], where the network reads them) and the outputs the controller reads, by port
/// and name.
fn probe<'n>(
    draws: &mut Draws,
    names: &'n PortNames,
    manifest: &PolicyManifest,
    state_shape: &'n [usize; 3],
) -> (Vec<Feed<'n>>, Vec<(Port, &'n str)>) {
    let top = draws.thumbnail(&TOP_SHAPE, manifest);
    let bottom = draws.thumbnail(&BOTTOM_SHAPE, manifest);
    let units = state_shape[2];
    let (hidden, cell) = (draws.signed(units), draws.signed(units));
    let previous = draws.signed(PREVIOUS_SHAPE[1]);
    let mut feeds = vec![
        (Port::Top, names.top.as_str(), &TOP_SHAPE[..], top),
        (
            Port::Bottom,
            names.bottom.as_str(),
            &BOTTOM_SHAPE[..],
            bottom,
        ),
    ];
    if let Some(name) = &names.previous {
        feeds.push((Port::Previous, name.as_str(), &PREVIOUS_SHAPE[..], previous));
    }
    let mut expected = vec![(Port::Command, names.command.as_str())];
    if let Some([h_in, c_in, h_out, c_out]) = &names.recurrent {
        feeds.push((Port::Hidden, h_in.as_str(), &state_shape[..], hidden));
        feeds.push((Port::Cell, c_in.as_str(), &state_shape[..], cell));
        expected.push((Port::Hidden, h_out.as_str()));
        expected.push((Port::Cell, c_out.as_str()));
    }
    if let Some((_, commands, logits)) = &names.hypotheses {
        expected.push((Port::Hypotheses, commands.as_str()));
        expected.push((Port::Logits, logits.as_str()));
    }
    (feeds, expected)
}

/// Runs `compiled` and tract's `network` on the same two pseudo-random probes and compares
/// every output the controller reads by the oracle's rule with the plan's tolerance. Leaves
/// the compiled plan's recurrent inputs at zero, as at an episode's start.
pub(super) fn engine_agrees_with_tract(
    compiled: &mut CompiledNetwork,
    network: &mut OnnxNetwork,
    names: &PortNames,
    manifest: &PolicyManifest,
    units: usize,
) -> Result<(), String> {
    let mut draws = Draws(0x9e37_79b9_7f4a_7c15);
    let state_shape = [1, 1, units];
    for check in 0..2 {
        let (feeds, expected) = probe(&mut draws, names, manifest, &state_shape);
        let mut tensors = Vec::new();
        for (port, name, shape, values) in &feeds {
            let input = compiled
                .input_mut(name)
                .filter(|input| input.len() == values.len())
                .ok_or_else(|| {
                    format!("the plan has no input {name:?} of {} values", values.len())
                })?;
            input.copy_from_slice(values);
            let tensor = Tensor::from_shape(shape, values).map_err(|error| format!("{error:#}"))?;
            tensors.push((*port, TValue::from_const(Arc::new(tensor))));
        }
        compiled.run();
        let outputs = network
            .run(|port| {
                tensors
                    .iter()
                    .find(|(p, _)| *p == port)
                    .map_or_else(|| tensors[0].1.clone(), |(_, value)| value.clone())
            })
            .map_err(|error| format!("tract failed on the check's input: {error}"))?;
        for (port, name) in &expected {
            let engine = compiled
                .output(name)
                .ok_or_else(|| format!("the plan has no output {name:?}"))?;
            let tract = outputs
                .iter()
                .find(|(p, _)| p == port)
                .and_then(|(_, value)| value.try_as_plain_ram().ok()?.as_slice::<f32>().ok())
                .ok_or_else(|| format!("tract gave no output {name:?}"))?;
            outputs_agree(name, engine, tract, compiled.tolerance())
                .map_err(|why| format!("{why} (check {check})"))?;
        }
    }
    if let Some([h_in, c_in, _, _]) = &names.recurrent {
        for name in [h_in, c_in] {
            if let Some(values) = compiled.input_mut(name) {
                values.fill(0.0);
            }
        }
    }
    Ok(())
}

/// The engine's and tract's values of output `name` agree by the oracle's rule: float
/// graphs differ from tract in summation order only (a few 1e-6 on the shipped models),
/// int8 ones also where a value rounds onto the neighbouring grid step; a wrong lowering by
/// far more.
fn outputs_agree(name: &str, engine: &[f32], tract: &[f32], tolerance: f32) -> Result<(), String> {
    if engine.len() != tract.len() {
        return Err(format!(
            "output {name:?}: {} values from the engine, {} from tract",
            engine.len(),
            tract.len()
        ));
    }
    let scale = oracle::scale(tract);
    match engine
        .iter()
        .zip(tract)
        .position(|(&a, &b)| !oracle::agree(a, b, scale, tolerance))
    {
        Some(i) => Err(format!(
            "the engine's output {name:?}[{i}] is {}, tract's {}",
            engine[i], tract[i]
        )),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::super::network::port_names;
    use super::*;
    use crate::policy::engine::Isa;
    use crate::policy::manifest::COMMAND_SHAPE;
    use crate::policy::onnx_network::Interface;

    /// The CNN fixture's manifest, its network under tract and its parsed file.
    fn cnn_fixture_network() -> (
        PolicyManifest,
        PortNames,
        OnnxNetwork,
        tract_onnx::pb::ModelProto,
    ) {
        let manifest = crate::package_dir().join("../models/fixtures/cnn/policy.toml");
        let manifest = PolicyManifest::load(&manifest).expect("manifest");
        let mut names = port_names(&manifest);
        names.recurrent = None;
        let path = manifest.directory.join(&manifest.networks[0]);
        let inputs = [
            (Port::Top, names.top.as_str(), &TOP_SHAPE[..]),
            (Port::Bottom, names.bottom.as_str(), &BOTTOM_SHAPE[..]),
        ];
        let outputs = [(Port::Command, names.command.as_str(), &COMMAND_SHAPE[..])];
        let interface = Interface {
            inputs: &inputs,
            outputs: &outputs,
            opset: manifest.opset,
        };
        let (network, proto) = OnnxNetwork::load(&path, &interface).expect("loads");
        (manifest, names, network, proto)
    }

    #[test]
    fn the_load_check_refuses_a_plan_that_computes_another_network() {
        let (manifest, names, mut network, mut proto) = cnn_fixture_network();
        let path = manifest.directory.join(&manifest.networks[0]);
        let shapes = [
            (names.top.as_str(), &TOP_SHAPE[..]),
            (names.bottom.as_str(), &BOTTOM_SHAPE[..]),
        ];
        for isa in Isa::available() {
            let mut same = CompiledNetwork::lower(&path, &proto, &shapes, isa).expect("lowers");
            engine_agrees_with_tract(&mut same, &mut network, &names, &manifest, 0)
                .unwrap_or_else(|why| panic!("{isa}: the fixture's own plan: {why}"));
        }
        // The plan of a file whose last bias differs by 0.01 from the one tract runs: as
        // a lowering that misread one number would compute.
        let graph = proto.graph.as_mut().expect("graph");
        let bias = graph
            .initializer
            .iter_mut()
            .rfind(|tensor| tensor.dims == [3])
            .expect("the last layer's bias");
        if bias.raw_data.is_empty() {
            bias.float_data[1] += 0.01;
        } else {
            let value = f32::from_le_bytes([
                bias.raw_data[4],
                bias.raw_data[5],
                bias.raw_data[6],
                bias.raw_data[7],
            ]) + 0.01;
            bias.raw_data[4..8].copy_from_slice(&value.to_le_bytes());
        }
        for isa in Isa::available() {
            let mut other = CompiledNetwork::lower(&path, &proto, &shapes, isa).expect("lowers");
            let why = engine_agrees_with_tract(&mut other, &mut network, &names, &manifest, 0)
                .expect_err("a different network");
            assert!(why.contains("\"command\"[1]"), "{isa}: {why}");
        }
    }
}
