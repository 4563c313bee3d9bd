//! The learned policies of the paper: CNN, H-CNN and R-CNN.
//!
//! tract reads, checks and plans every network at load. By default the compiled engine
//! ([`crate::policy::engine`]) then runs it: a static plan with every buffer allocated at
//! load, so a step allocates nothing. A network the engine cannot lower, or `Engine::Tract`,
//! runs under tract: its input tensors are allocated once and shared with tract by reference
//! count (a step writes the scaled thumbnails in place), but tract allocates its
//! intermediate tensors on every run. [`OnnxPolicy::engine`] says which ran and why.
//!
//! A model file is input from outside. Before the compiled engine is trusted with a network,
//! its plan runs once at load beside tract on the same pseudo-random inputs
//! ([`load_check`]), inside the panic guard: a panic in the lowering or in that pass, or any
//! output that differs from tract's, leaves the network to tract, with the reason in the
//! load log and in [`EngineReport::fallback`].
//!
//! - [`engine_choice`]: which engine runs a policy, and the report of what ran;
//! - [`network`]: one network under either engine, with its tensors, state and port names;
//! - [`load_check`]: the compiled plan held against tract at load;
//! - this module: the CNN, H-CNN and R-CNN policies built from those networks.

mod engine_choice;
mod load_check;
mod network;

pub use engine_choice::{Engine, EngineOptions, EngineReport};

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use network::{Loaded, Network, port_names};

use super::commitment::HypothesisCommitment;
use super::engine::CompiledNetwork;
use super::manifest::{PolicyKind, PolicyManifest};
use super::{Policy, PolicyError, PolicyInput, PolicyLoadError, PolicyOutput};
use crate::histogram::gating_feature;

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
            let message = network::panic_message(payload.as_ref());
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
    use std::sync::Arc;

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
