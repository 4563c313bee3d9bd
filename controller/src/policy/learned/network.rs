//! One network of a policy, run by tract or by the compiled engine, with the state it
//! carries: the thumbnail tensors tract reads by reference count, the recurrent state, and
//! the port names the manifest gives. [`Network::load`] lowers a network to the compiled
//! engine only where the load check ([`super::load_check`]) finds it agrees with tract.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::sync::Arc;

use tract_onnx::prelude::{TValue, Tensor};

use super::engine_choice::{EngineOptions, EngineReport};
use super::load_check::engine_agrees_with_tract;
use crate::policy::commitment::HypothesisCommitment;
use crate::policy::engine::CompiledNetwork;
use crate::policy::manifest::{
    BOTTOM_SHAPE, COMMAND_SHAPE, Normalisation, PREVIOUS_SHAPE, PolicyManifest, TOP_SHAPE,
};
use crate::policy::network_input::write_network_input;
use crate::policy::onnx_network::{Interface, OnnxNetwork, Port, zero_tensor};
use crate::policy::{PolicyError, PolicyInput, PolicyLoadError, PolicyOutput};

/// The network inputs made from the thumbnails as the manifest's normalisation says, and
/// the last command sent where the network reads it.
#[derive(Debug)]
pub(super) struct ThumbnailTensors {
    pub(super) top: Arc<Tensor>,
    bottom: Arc<Tensor>,
    previous: Option<Arc<Tensor>>,
    normalisation: Normalisation,
}

impl ThumbnailTensors {
    fn new(
        manifest: &PolicyManifest,
        path: &Path,
        previous: bool,
    ) -> Result<Self, PolicyLoadError> {
        Ok(Self {
            top: zero_tensor(path, &TOP_SHAPE)?,
            bottom: zero_tensor(path, &BOTTOM_SHAPE)?,
            previous: previous
                .then(|| zero_tensor(path, &PREVIOUS_SHAPE))
                .transpose()?,
            normalisation: manifest.normalisation,
        })
    }

    /// Writes the normalised thumbnails in place. tract has dropped its references after the
    /// last run, so `make_mut` finds the tensors unshared and copies nothing.
    fn fill(&mut self, input: PolicyInput<'_>) -> Result<(), PolicyError> {
        for (tensor, pixels) in [
            (&mut self.top, input.top.as_bytes()),
            (&mut self.bottom, input.bottom.as_bytes()),
        ] {
            let mut view = Arc::make_mut(tensor)
                .try_as_plain_ram_mut()
                .map_err(|error| PolicyError::Inference(format!("{error:#}")))?;
            let values = view
                .as_slice_mut::<f32>()
                .map_err(|error| PolicyError::Inference(format!("{error:#}")))?;
            write_network_input(&self.normalisation, pixels, values);
        }
        if let Some(tensor) = &mut self.previous {
            let mut view = Arc::make_mut(tensor)
                .try_as_plain_ram_mut()
                .map_err(|error| PolicyError::Inference(format!("{error:#}")))?;
            view.as_slice_mut::<f32>()
                .map_err(|error| PolicyError::Inference(format!("{error:#}")))?
                .copy_from_slice(&input.previous.as_array());
        }
        Ok(())
    }

    fn value(&self, port: Port) -> Option<TValue> {
        match port {
            Port::Top => Some(TValue::from_const(Arc::clone(&self.top))),
            Port::Bottom => Some(TValue::from_const(Arc::clone(&self.bottom))),
            Port::Previous => self
                .previous
                .as_ref()
                .map(|tensor| TValue::from_const(Arc::clone(tensor))),
            _ => None,
        }
    }
}

/// The values of output `port` among a network's outputs.
fn values_of(outputs: &[(Port, TValue)], port: Port) -> Result<&[f32], PolicyError> {
    let (_, value) = outputs.iter().find(|(p, _)| *p == port).ok_or_else(|| {
        PolicyError::Inference(format!("no {} output", format!("{port:?}").to_lowercase()))
    })?;
    value
        .try_as_plain_ram()
        .and_then(|view| view.as_slice::<f32>())
        .map_err(|error| PolicyError::Inference(format!("{error:#}")))
}

/// Reads the command from a network's outputs.
fn command_of(outputs: &[(Port, TValue)]) -> Result<PolicyOutput, PolicyError> {
    let values = values_of(outputs, Port::Command)?;
    match *values {
        [forward, left, turn] => Ok(PolicyOutput {
            forward,
            left,
            turn,
        }),
        _ => Err(PolicyError::Inference(format!(
            "command has {} values, not 3",
            values.len()
        ))),
    }
}

fn network_feed(tensors: &ThumbnailTensors) -> impl Fn(Port) -> TValue + '_ {
    // Every port a CNN network asks for is a thumbnail port or the last command, whose
    // tensor exists exactly when the network has that input (checked at load).
    move |port| {
        tensors
            .value(port)
            .unwrap_or_else(|| TValue::from_const(Arc::clone(&tensors.top)))
    }
}

/// The names a network's ports have in its file (from the manifest).
#[derive(Clone, Debug)]
pub(super) struct PortNames {
    pub(super) top: String,
    pub(super) bottom: String,
    pub(super) command: String,
    /// The input fed the last command sent, where the network has one.
    pub(super) previous: Option<String>,
    /// h_in, c_in, h_out, c_out of a recurrent network.
    pub(super) recurrent: Option<[String; 4]>,
    /// A modal CNN's hypothesis count and its commands and logits outputs, when the
    /// controller commits to one hypothesis.
    pub(super) hypotheses: Option<(usize, String, String)>,
}

/// One network, run by tract or by the compiled engine, with the state it carries.
#[derive(Debug)]
pub(super) enum Network {
    Tract {
        network: OnnxNetwork,
        tensors: ThumbnailTensors,
        /// The recurrent state fed back, and the zero it starts from (R-CNN only).
        state: Option<(TValue, TValue, Arc<Tensor>)>,
    },
    Compiled {
        network: Box<CompiledNetwork>,
        names: PortNames,
        normalisation: Normalisation,
    },
}

/// A loaded network or policy and what its engine reported, or why it could not load.
pub(super) type Loaded<T> = Result<(T, EngineReport), PolicyLoadError>;

impl Network {
    pub(super) fn load(
        manifest: &PolicyManifest,
        path: &Path,
        names: PortNames,
        options: EngineOptions,
    ) -> Loaded<Self> {
        let units = manifest.recurrent.as_ref().map_or(0, |r| r.units);
        let state_shape = [1, 1, units];
        let mut inputs = vec![
            (Port::Top, names.top.as_str(), &TOP_SHAPE[..]),
            (Port::Bottom, names.bottom.as_str(), &BOTTOM_SHAPE[..]),
        ];
        if let Some(previous) = &names.previous {
            inputs.push((Port::Previous, previous.as_str(), &PREVIOUS_SHAPE[..]));
        }
        let count = names.hypotheses.as_ref().map_or(0, |h| h.0);
        let (commands_shape, logits_shape) = ([1, count, 3], [1, count]);
        let mut outputs = vec![(Port::Command, names.command.as_str(), &COMMAND_SHAPE[..])];
        if let Some([h_in, c_in, h_out, c_out]) = &names.recurrent {
            inputs.push((Port::Hidden, h_in.as_str(), &state_shape[..]));
            inputs.push((Port::Cell, c_in.as_str(), &state_shape[..]));
            outputs.push((Port::Hidden, h_out.as_str(), &state_shape[..]));
            outputs.push((Port::Cell, c_out.as_str(), &state_shape[..]));
        }
        if let Some((_, commands, logits)) = &names.hypotheses {
            outputs.push((Port::Hypotheses, commands.as_str(), &commands_shape[..]));
            outputs.push((Port::Logits, logits.as_str(), &logits_shape[..]));
        }
        let interface = Interface {
            inputs: &inputs,
            outputs: &outputs,
            opset: manifest.opset,
        };
        // tract reads, checks and plans the file in any case: it is the loader and the oracle.
        let (mut network, proto) = OnnxNetwork::load(path, &interface)?;
        let mut fallback = None;
        if let Some(isa) = options.instruction_set() {
            let shapes: Vec<(&str, &[usize])> = inputs
                .iter()
                .map(|&(_, name, shape)| (name, shape))
                .collect();
            // The lowering and the check run inside the panic guard: a panic in either is a
            // fault of the engine on this file, and tract runs it instead.
            let lowered = catch_unwind(AssertUnwindSafe(|| {
                let mut compiled =
                    CompiledNetwork::lower(path, &proto, &shapes, isa).map_err(|why| why.0)?;
                engine_agrees_with_tract(&mut compiled, &mut network, &names, manifest, units)?;
                Ok::<_, String>(compiled)
            }))
            .unwrap_or_else(|payload| {
                Err(format!(
                    "the engine panicked on this network ({})",
                    panic_message(payload.as_ref())
                ))
            });
            match lowered {
                Ok(compiled) => {
                    let report = EngineReport {
                        compiled: Some(isa),
                        fallback: None,
                        multiply_adds: Some(compiled.multiply_adds()),
                        winograd: compiled.winograd_layers() > 0,
                        int8: compiled.int8_steps() > 0,
                    };
                    let network = Self::Compiled {
                        network: Box::new(compiled),
                        names,
                        normalisation: manifest.normalisation,
                    };
                    return Ok((network, report));
                }
                Err(why) => {
                    tracing::warn!(
                        event = "engine_fallback",
                        network = %path.display(),
                        reason = %why,
                        action = "tract runs this network",
                    );
                    fallback = Some(why);
                }
            }
        }
        let state = match &names.recurrent {
            Some(_) => {
                let zero = zero_tensor(path, &state_shape)?;
                let value = TValue::from_const(Arc::clone(&zero));
                Some((value.clone(), value, zero))
            }
            None => None,
        };
        let network = Self::Tract {
            network,
            tensors: ThumbnailTensors::new(manifest, path, names.previous.is_some())?,
            state,
        };
        Ok((
            network,
            EngineReport {
                compiled: None,
                fallback,
                multiply_adds: None,
                winograd: false,
                int8: false,
            },
        ))
    }

    /// One step; with `commitment`, the command is the committed hypothesis's, not the
    /// graph's own choice.
    pub(super) fn step(
        &mut self,
        input: PolicyInput<'_>,
        commitment: Option<&mut HypothesisCommitment>,
    ) -> Result<PolicyOutput, PolicyError> {
        match self {
            Self::Tract {
                network,
                tensors,
                state,
            } => {
                tensors.fill(input)?;
                let outputs = match state {
                    None => network.run(network_feed(tensors))?,
                    Some((hidden, cell, _)) => network.run(|port| match port {
                        Port::Hidden => hidden.clone(),
                        Port::Cell => cell.clone(),
                        _ => network_feed(tensors)(port),
                    })?,
                };
                let mut command = command_of(&outputs)?;
                if let Some(commitment) = commitment {
                    let (commands, logits) = (
                        values_of(&outputs, Port::Hypotheses)?,
                        values_of(&outputs, Port::Logits)?,
                    );
                    command = commitment.choose(commands, logits)?;
                }
                if let Some((hidden, cell, _)) = state {
                    for (port, value) in outputs {
                        match port {
                            Port::Hidden => *hidden = value,
                            Port::Cell => *cell = value,
                            _ => {}
                        }
                    }
                }
                Ok(command)
            }
            Self::Compiled {
                network,
                names,
                normalisation,
            } => {
                for (name, pixels) in [
                    (&names.top, input.top.as_bytes()),
                    (&names.bottom, input.bottom.as_bytes()),
                ] {
                    let values = network.input_mut(name).ok_or(PolicyError::Engine(
                        "a thumbnail input of the plan is missing",
                    ))?;
                    write_network_input(normalisation, pixels, values);
                }
                if let Some(name) = &names.previous {
                    network
                        .input_mut(name)
                        .filter(|values| values.len() == PREVIOUS_SHAPE[1])
                        .ok_or(PolicyError::Engine(
                            "the last command's input of the plan is missing",
                        ))?
                        .copy_from_slice(&input.previous.as_array());
                }
                // The plan ran once at load (`engine_agrees_with_tract`) and its shapes do not
                // change; a panic here all the same is a failed inference (a stop), not a
                // crash. The guard costs nothing while nothing panics.
                if catch_unwind(AssertUnwindSafe(|| network.run())).is_err() {
                    return Err(PolicyError::Engine("the compiled engine panicked"));
                }
                let mut command = match network.output(&names.command) {
                    Some(&[forward, left, turn]) => PolicyOutput {
                        forward,
                        left,
                        turn,
                    },
                    _ => {
                        return Err(PolicyError::Engine("the command output is not 3 values"));
                    }
                };
                if let (Some(commitment), Some((_, commands, logits))) =
                    (commitment, &names.hypotheses)
                {
                    let (Some(commands), Some(logits)) =
                        (network.output(commands), network.output(logits))
                    else {
                        return Err(PolicyError::Engine("the hypotheses outputs are missing"));
                    };
                    command = commitment.choose(commands, logits)?;
                }
                if let Some([h_in, c_in, h_out, c_out]) = &names.recurrent
                    && !(network.carry(h_out, h_in) && network.carry(c_out, c_in))
                {
                    return Err(PolicyError::Engine("the recurrent state cannot be carried"));
                }
                Ok(command)
            }
        }
    }

    pub(super) fn reset(&mut self) {
        match self {
            Self::Tract {
                state: Some((hidden, cell, zero)),
                ..
            } => {
                *hidden = TValue::from_const(Arc::clone(zero));
                *cell = TValue::from_const(Arc::clone(zero));
            }
            Self::Tract { state: None, .. } => {}
            Self::Compiled { network, names, .. } => {
                if let Some([h_in, c_in, _, _]) = &names.recurrent {
                    for name in [h_in, c_in] {
                        if let Some(values) = network.input_mut(name) {
                            values.fill(0.0);
                        }
                    }
                }
            }
        }
    }
}

/// The text of a caught panic.
pub(super) fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|text| (*text).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "no message".to_owned())
}

/// The names of a network's ports in its file, as the manifest gives them.
pub(super) fn port_names(manifest: &PolicyManifest) -> PortNames {
    PortNames {
        top: manifest.inputs.top.name.clone(),
        bottom: manifest.inputs.bottom.name.clone(),
        command: manifest.outputs.command.name.clone(),
        previous: manifest.inputs.previous.as_ref().map(|p| p.name.clone()),
        recurrent: manifest.recurrent.as_ref().map(|r| {
            [
                r.h_in.clone(),
                r.c_in.clone(),
                r.h_out.clone(),
                r.c_out.clone(),
            ]
        }),
        hypotheses: manifest
            .hypotheses
            .as_ref()
            .map(|h| (h.count, h.commands.clone(), h.logits.clone())),
    }
}
