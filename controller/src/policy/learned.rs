//! The learned policies of the paper, run by tract: CNN, H-CNN and R-CNN.
//!
//! Each network is optimised and planned once at load. The input tensors are allocated once
//! and shared with tract by reference count: a step writes the scaled thumbnails into them in
//! place and hands tract a new reference, not a copy. tract itself still allocates its
//! intermediate tensors on every run; that is measured and reported, and stays inside it.

use std::path::Path;
use std::sync::Arc;

use tract_onnx::prelude::{TValue, Tensor};

use super::manifest::{BOTTOM_SHAPE, COMMAND_SHAPE, PolicyKind, PolicyManifest, TOP_SHAPE};
use super::onnx_network::{Interface, OnnxNetwork, Port, zero_tensor};
use super::{Policy, PolicyError, PolicyInput, PolicyLoadError, PolicyOutput};
use crate::histogram::gating_feature;

/// The network inputs made from the thumbnails: `pixel * scale` as f32.
#[derive(Debug)]
struct ThumbnailTensors {
    top: Arc<Tensor>,
    bottom: Arc<Tensor>,
    scale: f32,
}

impl ThumbnailTensors {
    fn new(manifest: &PolicyManifest, path: &Path) -> Result<Self, PolicyLoadError> {
        Ok(Self {
            top: zero_tensor(path, &TOP_SHAPE)?,
            bottom: zero_tensor(path, &BOTTOM_SHAPE)?,
            scale: manifest.normalisation.scale,
        })
    }

    /// Writes the scaled thumbnails in place. tract has dropped its references after the
    /// last run, so `make_mut` finds the tensors unshared and copies nothing.
    fn fill(&mut self, input: PolicyInput<'_>) -> Result<(), PolicyError> {
        let scale = self.scale;
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
            for (value, &pixel) in values.iter_mut().zip(pixels) {
                *value = f32::from(pixel) * scale;
            }
        }
        Ok(())
    }

    fn value(&self, port: Port) -> Option<TValue> {
        match port {
            Port::Top => Some(TValue::from_const(Arc::clone(&self.top))),
            Port::Bottom => Some(TValue::from_const(Arc::clone(&self.bottom))),
            _ => None,
        }
    }
}

/// The inputs and output a CNN (and each H-CNN network) must have.
fn cnn_interface(manifest: &PolicyManifest) -> [[(Port, &str, &[usize]); 2]; 2] {
    [
        [
            (Port::Top, manifest.inputs.top.name.as_str(), &TOP_SHAPE),
            (
                Port::Bottom,
                manifest.inputs.bottom.name.as_str(),
                &BOTTOM_SHAPE,
            ),
        ],
        [
            (
                Port::Command,
                manifest.outputs.command.name.as_str(),
                &COMMAND_SHAPE,
            ),
            (
                Port::Command,
                manifest.outputs.command.name.as_str(),
                &COMMAND_SHAPE,
            ),
        ],
    ]
}

fn load_cnn_network(
    manifest: &PolicyManifest,
    path: &Path,
) -> Result<OnnxNetwork, PolicyLoadError> {
    let [inputs, outputs] = cnn_interface(manifest);
    let interface = Interface {
        inputs: &inputs,
        outputs: &outputs[..1],
        opset: manifest.opset,
    };
    OnnxNetwork::load(path, &interface)
}

/// Reads the command from a network's outputs.
fn command_of(outputs: &[(Port, TValue)]) -> Result<PolicyOutput, PolicyError> {
    let (_, value) = outputs
        .iter()
        .find(|(port, _)| *port == Port::Command)
        .ok_or_else(|| PolicyError::Inference("no command output".into()))?;
    let values = value
        .try_as_plain_ram()
        .and_then(|view| view.as_slice::<f32>())
        .map_err(|error| PolicyError::Inference(format!("{error:#}")))?;
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
    // Every port a CNN network asks for is a thumbnail port (checked at load).
    move |port| {
        tensors
            .value(port)
            .unwrap_or_else(|| TValue::from_const(Arc::clone(&tensors.top)))
    }
}

/// One CNN on both thumbnails.
#[derive(Debug)]
pub struct CnnPolicy {
    network: OnnxNetwork,
    tensors: ThumbnailTensors,
}

impl CnnPolicy {
    fn load(manifest: &PolicyManifest) -> Result<Self, PolicyLoadError> {
        let path = manifest.directory.join(&manifest.networks[0]);
        Ok(Self {
            network: load_cnn_network(manifest, &path)?,
            tensors: ThumbnailTensors::new(manifest, &path)?,
        })
    }
}

impl Policy for CnnPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        self.tensors.fill(input)?;
        let outputs = self.network.run(network_feed(&self.tensors))?;
        command_of(&outputs)
    }

    fn reset(&mut self) {}
}

/// K CNNs; the centroid nearest to the thumbnails' histogram feature picks one each step.
#[derive(Debug)]
pub struct HcnnPolicy {
    networks: Vec<OnnxNetwork>,
    centroids: Vec<[f32; 10]>,
    tensors: ThumbnailTensors,
    last_network: Option<usize>,
    selections: Vec<u64>,
}

impl HcnnPolicy {
    fn load(manifest: &PolicyManifest) -> Result<Self, PolicyLoadError> {
        let networks = manifest
            .network_paths()
            .map(|path| load_cnn_network(manifest, &path))
            .collect::<Result<Vec<_>, _>>()?;
        let centroids = manifest
            .gating
            .as_ref()
            .map(|gating| gating.centroids.clone())
            .unwrap_or_default();
        let first = manifest.directory.join(&manifest.networks[0]);
        Ok(Self {
            selections: vec![0; networks.len()],
            networks,
            centroids,
            tensors: ThumbnailTensors::new(manifest, &first)?,
            last_network: None,
        })
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
        self.tensors.fill(input)?;
        let outputs = self.networks[chosen].run(network_feed(&self.tensors))?;
        command_of(&outputs)
    }

    fn reset(&mut self) {}
}

/// CNN branches and an LSTM; its state goes from each step's outputs to the next's inputs
/// and is zero at an episode's start.
#[derive(Debug)]
pub struct RcnnPolicy {
    network: OnnxNetwork,
    tensors: ThumbnailTensors,
    zero_state: Arc<Tensor>,
    hidden: TValue,
    cell: TValue,
}

impl RcnnPolicy {
    fn load(manifest: &PolicyManifest) -> Result<Self, PolicyLoadError> {
        let path = manifest.directory.join(&manifest.networks[0]);
        let Some(recurrent) = &manifest.recurrent else {
            return Err(PolicyLoadError::Manifest {
                path: manifest.directory.join("policy.toml"),
                problem: "an R-CNN needs a [recurrent] table".into(),
            });
        };
        let state_shape = [1, 1, recurrent.units];
        let [[top, bottom], [command, _]] = cnn_interface(manifest);
        let inputs = [
            top,
            bottom,
            (Port::Hidden, recurrent.h_in.as_str(), &state_shape[..]),
            (Port::Cell, recurrent.c_in.as_str(), &state_shape[..]),
        ];
        let outputs = [
            command,
            (Port::Hidden, recurrent.h_out.as_str(), &state_shape[..]),
            (Port::Cell, recurrent.c_out.as_str(), &state_shape[..]),
        ];
        let interface = Interface {
            inputs: &inputs,
            outputs: &outputs,
            opset: manifest.opset,
        };
        let network = OnnxNetwork::load(&path, &interface)?;
        let zero_state = zero_tensor(&path, &state_shape)?;
        Ok(Self {
            network,
            tensors: ThumbnailTensors::new(manifest, &path)?,
            hidden: TValue::from_const(Arc::clone(&zero_state)),
            cell: TValue::from_const(Arc::clone(&zero_state)),
            zero_state,
        })
    }
}

impl Policy for RcnnPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        self.tensors.fill(input)?;
        let (tensors, hidden, cell) = (&self.tensors, &self.hidden, &self.cell);
        let outputs = self.network.run(|port| match port {
            Port::Hidden => hidden.clone(),
            Port::Cell => cell.clone(),
            _ => network_feed(tensors)(port),
        })?;
        let command = command_of(&outputs)?;
        for (port, value) in outputs {
            match port {
                Port::Hidden => self.hidden = value,
                Port::Cell => self.cell = value,
                _ => {}
            }
        }
        Ok(command)
    }

    fn reset(&mut self) {
        self.hidden = TValue::from_const(Arc::clone(&self.zero_state));
        self.cell = TValue::from_const(Arc::clone(&self.zero_state));
    }
}

/// Any of the three learned policies, as its manifest says.
#[derive(Debug)]
pub enum OnnxPolicy {
    Cnn(CnnPolicy),
    Hcnn(HcnnPolicy),
    Rcnn(RcnnPolicy),
}

impl OnnxPolicy {
    /// Loads the policy whose `policy.toml` is at `manifest_path`: reads and checks the
    /// manifest and every network, optimises and plans them.
    pub fn load(manifest_path: &Path) -> Result<(Self, PolicyManifest), PolicyLoadError> {
        let manifest = PolicyManifest::load(manifest_path)?;
        let policy = match manifest.kind {
            PolicyKind::Cnn => Self::Cnn(CnnPolicy::load(&manifest)?),
            PolicyKind::Hcnn => Self::Hcnn(HcnnPolicy::load(&manifest)?),
            PolicyKind::Rcnn => Self::Rcnn(RcnnPolicy::load(&manifest)?),
        };
        Ok((policy, manifest))
    }

    pub fn kind(&self) -> PolicyKind {
        match self {
            Self::Cnn(_) => PolicyKind::Cnn,
            Self::Hcnn(_) => PolicyKind::Hcnn,
            Self::Rcnn(_) => PolicyKind::Rcnn,
        }
    }
}

impl Policy for OnnxPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        match self {
            Self::Cnn(policy) => policy.step(input),
            Self::Hcnn(policy) => policy.step(input),
            Self::Rcnn(policy) => policy.step(input),
        }
    }

    fn reset(&mut self) {
        match self {
            Self::Cnn(policy) => policy.reset(),
            Self::Hcnn(policy) => policy.reset(),
            Self::Rcnn(policy) => policy.reset(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thumbnail::{BottomThumbnail, TopThumbnail};

    #[test]
    fn steps_reuse_the_input_tensors_instead_of_copying_them() {
        let manifest =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/fixtures/cnn/policy.toml");
        let (policy, _) = OnnxPolicy::load(&manifest).expect("fixture loads");
        let OnnxPolicy::Cnn(mut policy) = policy else {
            panic!("the cnn fixture is a CNN");
        };
        let before = Arc::as_ptr(&policy.tensors.top);
        let (top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
        for _ in 0..3 {
            policy
                .step(PolicyInput {
                    top: &top,
                    bottom: &bottom,
                })
                .expect("step");
            assert_eq!(
                Arc::strong_count(&policy.tensors.top),
                1,
                "tract kept a reference"
            );
        }
        assert_eq!(
            Arc::as_ptr(&policy.tensors.top),
            before,
            "the tensor was copied"
        );
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
