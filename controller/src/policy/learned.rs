//! The learned policies of the paper: CNN, H-CNN and R-CNN.
//!
//! tract reads, checks and plans every network at load. By default the compiled engine
//! ([`super::engine`]) then runs it: a static plan with every buffer allocated at load, so
//! a step allocates nothing. A network the engine cannot lower, or `Engine::Tract`, runs
//! under tract: its input tensors are allocated once and shared with tract by reference
//! count (a step writes the scaled thumbnails in place), but tract allocates its
//! intermediate tensors on every run. [`OnnxPolicy::engine`] says which ran and why.
//!
//! A model file is input from outside. Before the compiled engine is trusted with a network,
//! its plan runs once at load beside tract on the same pseudo-random inputs
//! ([`engine_agrees_with_tract`]), inside the panic guard: a panic in the lowering or in that
//! pass, or any output that differs from tract's, leaves the network to tract, with the
//! reason in the load log and in [`EngineReport::fallback`].

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::sync::Arc;

use tract_onnx::prelude::{TValue, Tensor};

use super::commitment::HypothesisCommitment;
use super::engine::{CompiledNetwork, Isa};
use super::manifest::{
    BOTTOM_SHAPE, COMMAND_SHAPE, Normalisation, PREVIOUS_SHAPE, PolicyKind, PolicyManifest,
    TOP_SHAPE,
};
use super::network_input::write_network_input;
use super::onnx_network::{Interface, OnnxNetwork, Port, zero_tensor};
use super::{Policy, PolicyError, PolicyInput, PolicyLoadError, PolicyOutput};
use crate::histogram::gating_feature;

/// Which engine runs a policy's networks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Engine {
    /// The compiled engine (allocation-free steps), tract where it cannot lower a network.
    #[default]
    Compiled,
    /// tract for every network (the reference the engine is checked against).
    Tract,
}

impl Engine {
    pub fn name(self) -> &'static str {
        match self {
            Self::Compiled => "compiled",
            Self::Tract => "tract",
        }
    }
}

impl std::str::FromStr for Engine {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "compiled" => Ok(Self::Compiled),
            "tract" => Ok(Self::Tract),
            _ => Err(format!("unknown engine {text:?}; compiled or tract")),
        }
    }
}

/// How to load a policy: the engine, and for the compiled one the instruction set (the
/// widest this CPU runs when `None`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EngineOptions {
    pub engine: Engine,
    pub isa: Option<Isa>,
}

impl EngineOptions {
    /// The instruction set the compiled engine runs: the one named, else the widest this CPU
    /// has; none for tract, which has none to choose.
    pub fn instruction_set(&self) -> Option<Isa> {
        (self.engine == Engine::Compiled).then(|| self.isa.unwrap_or_else(Isa::detect))
    }
}

/// What runs a loaded policy's networks.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EngineReport {
    /// The compiled engine with this instruction set, or tract (`None`).
    pub compiled: Option<Isa>,
    /// Why tract runs a network although the compiled engine was asked for.
    pub fallback: Option<String>,
    /// The multiply-adds of the network one step runs, where the compiled engine runs it
    /// (its count of a lowered plan; tract's plan is not counted).
    pub multiply_adds: Option<u64>,
    /// Whether the compiled engine runs a convolution by Winograd's minimal filtering, which
    /// rounds differently from the direct sum (named in the report: a closed loop's goal
    /// count belongs to the arithmetic that measured it).
    pub winograd: bool,
    /// Whether the compiled engine runs int8 steps (an int8 policy's QDQ network lowered to
    /// integer kernels): its multiply-adds are then mostly 8-bit ones.
    pub int8: bool,
}

impl std::fmt::Display for EngineReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.compiled, &self.fallback) {
            (Some(isa), _) if self.int8 => write!(f, "compiled ({isa}, int8)"),
            (Some(isa), _) if self.winograd => write!(f, "compiled ({isa}, winograd)"),
            (Some(isa), _) => write!(f, "compiled ({isa})"),
            (None, Some(why)) => write!(f, "tract (the compiled engine cannot run it: {why})"),
            (None, None) => f.write_str("tract"),
        }
    }
}

/// The network inputs made from the thumbnails as the manifest's normalisation says, and
/// the last command sent where the network reads it.
#[derive(Debug)]
struct ThumbnailTensors {
    top: Arc<Tensor>,
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
struct PortNames {
    top: String,
    bottom: String,
    command: String,
    /// The input fed the last command sent, where the network has one.
    previous: Option<String>,
    /// h_in, c_in, h_out, c_out of a recurrent network.
    recurrent: Option<[String; 4]>,
    /// A modal CNN's hypothesis count and its commands and logits outputs, when the
    /// controller commits to one hypothesis.
    hypotheses: Option<(usize, String, String)>,
}

/// One network, run by tract or by the compiled engine, with the state it carries.
#[derive(Debug)]
enum Network {
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
type Loaded<T> = Result<(T, EngineReport), PolicyLoadError>;

impl Network {
    fn load(
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
    fn step(
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

    fn reset(&mut self) {
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
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|text| (*text).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "no message".to_owned())
}

/// Runs `compiled` and tract's `network` on the same two pseudo-random inputs (thumbnails
/// of random pixels through the manifest's normalisation; random recurrent states and last
/// commands in [-1, 1]) and
/// compares every output the controller reads. Leaves the compiled plan's recurrent inputs
/// at zero, as at an episode's start.
fn engine_agrees_with_tract(
    compiled: &mut CompiledNetwork,
    network: &mut OnnxNetwork,
    names: &PortNames,
    manifest: &PolicyManifest,
    units: usize,
) -> Result<(), String> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let input_of = |pixels: Vec<u8>| -> Vec<f32> {
        let mut values = vec![0.0; pixels.len()];
        write_network_input(&manifest.normalisation, &pixels, &mut values);
        values
    };
    for probe in 0..2 {
        let mut random_pixels = |shape: &[usize]| -> Vec<u8> {
            (0..shape.iter().product::<usize>())
                .map(|_| (next() >> 56) as u8)
                .collect()
        };
        let top = input_of(random_pixels(&TOP_SHAPE));
        let bottom = input_of(random_pixels(&BOTTOM_SHAPE));
        let mut random_state = || -> Vec<f32> {
            (0..units)
                .map(|_| (next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0)
                .collect()
        };
        let (hidden, cell) = (random_state(), random_state());
        let previous: Vec<f32> = (0..PREVIOUS_SHAPE[1])
            .map(|_| (next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0)
            .collect();
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
        let state_shape = [1, 1, units];
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
            if engine.len() != tract.len() {
                return Err(format!(
                    "output {name:?}: {} values from the engine, {} from tract",
                    engine.len(),
                    tract.len()
                ));
            }
            // The plan's tolerance: float graphs differ from tract in summation order only (a
            // few 1e-6 on the shipped models), int8 ones also where a value rounds onto the
            // neighbouring grid step; a wrong lowering by far more.
            let tolerance = compiled.tolerance();
            for (i, (&a, &b)) in engine.iter().zip(tract).enumerate() {
                let agree = a == b
                    || (a.is_nan() && b.is_nan())
                    || (a - b).abs() <= tolerance * (1.0 + b.abs());
                if !agree {
                    return Err(format!(
                        "the engine's output {name:?}[{i}] is {a}, tract's {b} (check {probe})"
                    ));
                }
            }
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

fn port_names(manifest: &PolicyManifest) -> PortNames {
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

/// One CNN on both thumbnails; a modal CNN whose manifest names its hypotheses commits to
/// one of them ([`HypothesisCommitment`]).
#[derive(Debug)]
pub struct CnnPolicy {
    network: Network,
    commitment: Option<HypothesisCommitment>,
}

impl CnnPolicy {
    fn load(manifest: &PolicyManifest, options: EngineOptions) -> Loaded<Self> {
        let path = manifest.directory.join(&manifest.networks[0]);
        let mut names = port_names(manifest);
        names.recurrent = None;
        let (network, report) = Network::load(manifest, &path, names, options)?;
        let commitment = manifest
            .hypotheses
            .as_ref()
            .map(|h| HypothesisCommitment::new(h.count, h.switch_margin));
        Ok((
            Self {
                network,
                commitment,
            },
            report,
        ))
    }

    /// The commitment to a hypothesis, for a modal CNN whose manifest names them.
    pub fn commitment(&self) -> Option<&HypothesisCommitment> {
        self.commitment.as_ref()
    }
}

impl Policy for CnnPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        self.network.step(input, self.commitment.as_mut())
    }

    fn reset(&mut self) {
        if let Some(commitment) = &mut self.commitment {
            commitment.reset();
        }
    }
}

/// K CNNs; the centroid nearest to the thumbnails' histogram feature picks one each step.
#[derive(Debug)]
pub struct HcnnPolicy {
    networks: Vec<Network>,
    centroids: Vec<[f32; 10]>,
    last_network: Option<usize>,
    selections: Vec<u64>,
}

impl HcnnPolicy {
    fn load(manifest: &PolicyManifest, options: EngineOptions) -> Loaded<Self> {
        let mut names = port_names(manifest);
        names.recurrent = None;
        names.hypotheses = None;
        let mut networks = Vec::new();
        let mut report = EngineReport {
            compiled: None,
            fallback: None,
            multiply_adds: None,
            winograd: false,
            int8: false,
        };
        for (index, path) in manifest.network_paths().enumerate() {
            let (network, own) = Network::load(manifest, &path, names.clone(), options)?;
            // The policy's report is its first network's, or the first fallback's.
            if index == 0 || (report.fallback.is_none() && own.fallback.is_some()) {
                report = own;
            }
            networks.push(network);
        }
        let centroids = manifest
            .gating
            .as_ref()
            .map(|gating| gating.centroids.clone())
            .unwrap_or_default();
        Ok((
            Self {
                selections: vec![0; networks.len()],
                networks,
                centroids,
                last_network: None,
            },
            report,
        ))
    }

    /// The network the last step ran, if any step ran.
    pub fn last_network(&self) -> Option<usize> {
        self.last_network
    }

    /// How often each network has been picked.
    pub fn selections(&self) -> &[u64] {
        &self.selections
    }
}

/// Index of the centroid nearest to `feature` (squared Euclidean distance); the first one
/// on a tie, as `numpy.argmin` picks.
pub(crate) fn nearest_centroid(feature: &[f32; 10], centroids: &[[f32; 10]]) -> usize {
    let mut best = (0, f32::INFINITY);
    for (index, centroid) in centroids.iter().enumerate() {
        let distance: f32 = feature
            .iter()
            .zip(centroid)
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        if distance < best.1 {
            best = (index, distance);
        }
    }
    best.0
}

impl Policy for HcnnPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        let feature = gating_feature(input.top, input.bottom);
        let chosen = nearest_centroid(&feature, &self.centroids);
        self.last_network = Some(chosen);
        self.selections[chosen] += 1;
        self.networks[chosen].step(input, None)
    }

    fn reset(&mut self) {}
}

/// CNN branches and an LSTM; its state goes from each step's outputs to the next's inputs
/// and is zero at an episode's start.
#[derive(Debug)]
pub struct RcnnPolicy {
    network: Network,
}

impl RcnnPolicy {
    fn load(manifest: &PolicyManifest, options: EngineOptions) -> Loaded<Self> {
        let path = manifest.directory.join(&manifest.networks[0]);
        if manifest.recurrent.is_none() {
            return Err(PolicyLoadError::Manifest {
                path: manifest.directory.join("policy.toml"),
                problem: "an R-CNN needs a [recurrent] table".into(),
            });
        }
        let (network, report) = Network::load(manifest, &path, port_names(manifest), options)?;
        Ok((Self { network }, report))
    }
}

impl Policy for RcnnPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        self.network.step(input, None)
    }

    fn reset(&mut self) {
        self.network.reset();
    }
}

/// Any of the three learned policies, as its manifest says.
#[derive(Debug)]
pub enum OnnxPolicy {
    Cnn(CnnPolicy, EngineReport),
    Hcnn(HcnnPolicy, EngineReport),
    Rcnn(RcnnPolicy, EngineReport),
}

impl OnnxPolicy {
    /// Loads the policy whose `policy.toml` is at `manifest_path` with the default engine.
    pub fn load(manifest_path: &Path) -> Result<(Self, PolicyManifest), PolicyLoadError> {
        Self::load_with(manifest_path, EngineOptions::default())
    }

    /// Loads the policy whose `policy.toml` is at `manifest_path`: reads and checks the
    /// manifest and every network, and prepares them for the engine `options` name.
    ///
    /// A panic inside a dependency while loading (tract on a hostile ONNX file) is caught
    /// and returned as [`PolicyLoadError::Onnx`] naming the manifest: loading happens once
    /// at start-up, where unwinding is safe, and a bad file must not take the robot down
    /// with a backtrace instead of a reason.
    pub fn load_with(
        manifest_path: &Path,
        options: EngineOptions,
    ) -> Result<(Self, PolicyManifest), PolicyLoadError> {
        catch_unwind(AssertUnwindSafe(|| {
            Self::load_unguarded(manifest_path, options)
        }))
        .unwrap_or_else(|payload| {
            let message = panic_message(payload.as_ref());
            Err(PolicyLoadError::Onnx {
                path: manifest_path.to_owned(),
                problem: format!("made the model loader panic ({message}): not a usable policy"),
            })
        })
    }

    fn load_unguarded(
        manifest_path: &Path,
        options: EngineOptions,
    ) -> Result<(Self, PolicyManifest), PolicyLoadError> {
        let manifest = PolicyManifest::load(manifest_path)?;
        let policy = match manifest.kind {
            PolicyKind::Cnn => {
                let (policy, report) = CnnPolicy::load(&manifest, options)?;
                Self::Cnn(policy, report)
            }
            PolicyKind::Hcnn => {
                let (policy, report) = HcnnPolicy::load(&manifest, options)?;
                Self::Hcnn(policy, report)
            }
            PolicyKind::Rcnn => {
                let (policy, report) = RcnnPolicy::load(&manifest, options)?;
                Self::Rcnn(policy, report)
            }
        };
        Ok((policy, manifest))
    }

    pub fn kind(&self) -> PolicyKind {
        match self {
            Self::Cnn(..) => PolicyKind::Cnn,
            Self::Hcnn(..) => PolicyKind::Hcnn,
            Self::Rcnn(..) => PolicyKind::Rcnn,
        }
    }

    /// A CNN policy's network where the compiled engine runs it (None for tract, and for
    /// the H-CNN's and R-CNN's several or stateful networks): for per-layer timing and
    /// counting (`dribble-controller forward --layer`).
    pub fn compiled_cnn_mut(&mut self) -> Option<&mut CompiledNetwork> {
        match self {
            Self::Cnn(
                CnnPolicy {
                    network: Network::Compiled { network, .. },
                    ..
                },
                _,
            ) => Some(network),
            _ => None,
        }
    }

    /// Which engine runs the networks, and why tract does where it does.
    pub fn engine(&self) -> &EngineReport {
        match self {
            Self::Cnn(_, report) | Self::Hcnn(_, report) | Self::Rcnn(_, report) => report,
        }
    }
}

impl Policy for OnnxPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        match self {
            Self::Cnn(policy, _) => policy.step(input),
            Self::Hcnn(policy, _) => policy.step(input),
            Self::Rcnn(policy, _) => policy.step(input),
        }
    }

    fn reset(&mut self) {
        match self {
            Self::Cnn(policy, _) => policy.reset(),
            Self::Hcnn(policy, _) => policy.reset(),
            Self::Rcnn(policy, _) => policy.reset(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thumbnail::{BottomThumbnail, TopThumbnail};

    #[test]
    fn steps_reuse_the_input_tensors_instead_of_copying_them() {
        let manifest = crate::package_dir().join("../models/fixtures/cnn/policy.toml");
        let options = EngineOptions {
            engine: Engine::Tract,
            isa: None,
        };
        let (policy, _) = OnnxPolicy::load_with(&manifest, options).expect("fixture loads");
        let OnnxPolicy::Cnn(mut policy, _) = policy else {
            panic!("the cnn fixture is a CNN");
        };
        let tensors = |policy: &CnnPolicy| match &policy.network {
            Network::Tract { tensors, .. } => Arc::clone(&tensors.top),
            Network::Compiled { .. } => panic!("tract was asked for"),
        };
        let before = Arc::as_ptr(&tensors(&policy));
        let (top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
        for _ in 0..3 {
            policy
                .step(PolicyInput::at_rest(&top, &bottom))
                .expect("step");
            // One reference here, one in the policy: tract kept none.
            assert_eq!(
                Arc::strong_count(&tensors(&policy)),
                2,
                "tract kept a reference"
            );
        }
        assert_eq!(
            Arc::as_ptr(&tensors(&policy)),
            before,
            "the tensor was copied"
        );
    }

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

    #[test]
    fn the_nearest_centroid_wins_and_ties_go_to_the_first() {
        let a = [0.0; 10];
        let mut b = [0.0; 10];
        b[0] = 1.0;
        let mut feature = [0.0; 10];
        feature[0] = 0.9;
        assert_eq!(nearest_centroid(&feature, &[a, b]), 1);
        feature[0] = 0.5;
        assert_eq!(nearest_centroid(&feature, &[a, b]), 0);
    }
}
