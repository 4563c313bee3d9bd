//! `policy.toml`: what a model directory tells the robot about its policy (DESIGN.md,
//! "Policies"). Loading checks it against the contract, so that a wrong manifest fails at
//! start-up with a message that names the field, not at the first tick.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::histogram::GATING_FEATURE_LEN;
use crate::speed_command::WalkLimits;
use crate::units::{MetresPerSecond, RadiansPerSecond};

use super::PolicyLoadError;

/// The manifest format this controller reads.
pub const MANIFEST_FORMAT: u32 = 1;
/// Shapes of the tensors the controller feeds and reads (batch 1, one channel).
pub const TOP_SHAPE: [usize; 4] = [1, 1, 120, 160];
pub const BOTTOM_SHAPE: [usize; 4] = [1, 1, 60, 80];
pub const COMMAND_SHAPE: [usize; 2] = [1, 3];
/// The last command sent, as a network input (`[inputs] previous`): normalised, clamped.
pub const PREVIOUS_SHAPE: [usize; 2] = [1, 3];

/// The three policy kinds of the paper.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PolicyKind {
    /// One CNN on both thumbnails.
    Cnn,
    /// K CNNs; the nearest histogram centroid picks one per step.
    Hcnn,
    /// CNN branches and an LSTM whose state is carried between steps.
    Rcnn,
}

impl fmt::Display for PolicyKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Cnn => "CNN",
            Self::Hcnn => "H-CNN",
            Self::Rcnn => "R-CNN",
        })
    }
}

/// The number format the networks compute in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// 32-bit floats throughout (every manifest before `precision` existed).
    #[default]
    Fp32,
    /// Hidden layers in 8-bit integers: the files are QDQ ONNX (`QuantizeLinear` and
    /// `DequantizeLinear` pairs around them), made by `dribble_models.quantize`; output
    /// layers and the LSTM stay in floats.
    Int8,
}

impl fmt::Display for Precision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Fp32 => "fp32",
            Self::Int8 => "int8",
        })
    }
}

/// How an int8 policy was made from its float one: the record a reader (or a test) needs to
/// redo it and to know it never saw a test episode.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Quantization {
    pub method: String,
    /// Bits of the int8 weights' range actually used (7: -64..64, so that SSSE3's
    /// `pmaddubsw` cannot saturate).
    pub weight_bits: u32,
    pub onnxruntime_version: String,
    /// sha256 of each float network it was made from, in `networks` order.
    pub float_networks_sha256: Vec<String>,
    /// Content hash of the dataset the calibration frames came from (the training one).
    pub calibration_dataset_hash: String,
    pub calibration_frames: u32,
    pub calibration_seed: u64,
    /// sha256 of the list of (episode seed, row) pairs that calibrated it.
    pub calibration_rows_sha256: String,
    /// Per network file, the scale of each quantized activation tensor.
    pub networks: Vec<QuantizedNetwork>,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuantizedNetwork {
    pub network: String,
    pub activation_scales: std::collections::BTreeMap<String, f32>,
}

/// A named tensor and its shape.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TensorSpec {
    pub name: String,
    pub shape: Vec<usize>,
}

/// How a thumbnail's u8 pixels become the network's input (see [`super::network_input`]).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normalisation {
    /// The network sees `pixel * scale` (1/255 in DESIGN.md).
    pub scale: f32,
    /// When true, the network sees each thumbnail standardised instead: its own mean
    /// subtracted and divided by its own spread (at least
    /// [`super::network_input::STANDARDISE_FLOOR_LEVELS`]), so a camera's gain, exposure
    /// and contrast leave the input unchanged. `scale` then cancels out. Absent: false.
    #[serde(default)]
    pub standardise: bool,
}

#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Inputs {
    pub top: TensorSpec,
    pub bottom: TensorSpec,
    /// The command the controller sent last, fed back as a third input `[1, 3]`: each
    /// component normalised and clamped to [-1, 1] as the walk received it, a stop where the
    /// controller sent a stop (a failed step, silent cameras), zero at an episode's start.
    /// A CNN only; absent: the network sees the thumbnails alone.
    pub previous: Option<TensorSpec>,
}

#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Outputs {
    pub command: TensorSpec,
}

/// What a normalised command of 1.0 means for the walk the policy was trained with.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CommandScale {
    pub forward_mps: f32,
    pub left_mps: f32,
    pub turn_radps: f32,
}

impl CommandScale {
    pub fn walk_limits(&self) -> WalkLimits {
        WalkLimits {
            max_forward: MetresPerSecond(self.forward_mps),
            max_left: MetresPerSecond(self.left_mps),
            max_turn: RadiansPerSecond(self.turn_radps),
        }
    }
}

/// The most LSTM units a manifest may declare (the paper's R-CNN has 64): the state tensors
/// are allocated at load, so an absurd count must be refused before it is.
pub const MAX_RECURRENT_UNITS: usize = 4096;

/// The R-CNN's LSTM state tensors, each `[1, 1, units]`.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recurrent {
    pub units: usize,
    pub h_in: String,
    pub c_in: String,
    pub h_out: String,
    pub c_out: String,
}

/// The H-CNN's gate: one centroid of the 10-value histogram feature per network.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gating {
    pub clusters: usize,
    pub centroids: Vec<[f32; GATING_FEATURE_LEN]>,
}

/// The most command hypotheses a manifest may declare (the modal CNNs have 2).
pub const MAX_HYPOTHESES: usize = 16;

/// A modal CNN's command hypotheses, read by the controller so that it can commit to one
/// ([`super::commitment`]) instead of taking the graph's choice afresh at every frame.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hypotheses {
    /// How many command hypotheses the network answers.
    pub count: usize,
    /// The output holding every hypothesis's normalised command, `[1, count, 3]`.
    pub commands: String,
    /// The output holding one choice logit per hypothesis, `[1, count]`.
    pub logits: String,
    /// By how much (in logits) another hypothesis must beat the held one before the
    /// controller switches to it; 0 takes the largest logit at every frame, as the graph's
    /// own `command` output does.
    pub switch_margin: f32,
}

/// A dataset named by a directory (for people) and its content hash (for checks).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetReference {
    pub name: String,
    pub hash: String,
}

/// Where the weights came from.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingRecord {
    /// What the model learned from, for people (a directory, or what the fixture is).
    pub dataset: String,
    /// The content hash of the training dataset (`dataset.json`'s `content_hash`).
    pub dataset_hash: Option<String>,
    /// Which teacher labelled the training rows (`paper` or `observable`, DESIGN.md
    /// "Teachers"); absent in manifests written before there were two: the paper's.
    pub teacher: Option<String>,
    /// The content hash of the dataset `test_error` was measured on.
    pub test_dataset_hash: Option<String>,
    /// Datasets trained on besides `dataset`, every row of them (DAgger's aggregated
    /// policy-driven episodes); `dataset` alone supplies the validation episodes.
    pub added_datasets: Option<Vec<DatasetReference>>,
    /// Epochs trained, and the one whose weights these are (best validation error).
    pub epochs: u32,
    pub best_epoch: Option<u32>,
    /// Seed of every random choice in training.
    pub seed: Option<u64>,
    /// Training episodes held out to choose the checkpoint.
    pub validation_seeds: Option<Vec<u64>>,
    pub wall_time_s: Option<f64>,
    pub torch_version: Option<String>,
    /// The paper's error (DESIGN.md, "Metrics") on the training, validation and test data.
    pub train_error: Option<f64>,
    pub validation_error: Option<f64>,
    pub test_error: Option<f64>,
    /// Anything else the trainer records about how (augmentation, sampling, data).
    pub notes: Option<String>,
}

/// Another model a policy came from: its directory when it was made, and the sha256 (its
/// first twelve digits) of that model's network then, which still names it after a rename.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelReference {
    pub model: String,
    pub sha256: String,
    /// How it was used where that is not plain: "pruned to these filters, largest L1 norms kept".
    pub how: Option<String>,
}

/// Where a policy came from, so that its name need not say it (an int8 policy's float one
/// is its `[quantization]` record's `float_networks_sha256`).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lineage {
    /// The model whose weights training started from.
    pub started_from: Option<ModelReference>,
    /// The model whose commands were the training labels (distillation).
    pub distilled_from: Option<ModelReference>,
    /// The CNN whose convolutions an R-CNN took (`how`: kept fixed or trained on).
    pub features_from: Option<ModelReference>,
    /// The names the model's directory had before (models/policy/<name>).
    #[serde(default)]
    pub former_names: Vec<String>,
}

/// A parsed and checked `policy.toml`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyManifest {
    pub format: u32,
    pub kind: PolicyKind,
    /// ONNX operator set the files were exported with.
    pub opset: i64,
    /// ONNX files, relative to the manifest's directory; one per H-CNN cluster.
    pub networks: Vec<String>,
    /// fp32 when absent.
    #[serde(default)]
    pub precision: Precision,
    /// Present exactly when `precision` is int8.
    pub quantization: Option<Quantization>,
    pub normalisation: Normalisation,
    pub inputs: Inputs,
    pub outputs: Outputs,
    pub command_scale: CommandScale,
    pub recurrent: Option<Recurrent>,
    pub gating: Option<Gating>,
    /// A modal CNN's hypotheses, when the controller is to commit to one of them.
    pub hypotheses: Option<Hypotheses>,
    /// Which models it came from, for people; absent where it was trained from scratch.
    pub lineage: Option<Lineage>,
    pub training: TrainingRecord,
    /// The directory the manifest was read from; network paths are relative to it.
    #[serde(skip)]
    pub directory: PathBuf,
}

impl PolicyManifest {
    /// Reads and checks the manifest at `path`.
    pub fn load(path: &Path) -> Result<Self, PolicyLoadError> {
        let text = std::fs::read_to_string(path).map_err(|source| PolicyLoadError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and checks manifest `text`; `path` locates the network files and the errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, PolicyLoadError> {
        let mut manifest: Self =
            toml::from_str(text).map_err(|error| PolicyLoadError::Manifest {
                path: path.to_owned(),
                problem: error.to_string(),
            })?;
        manifest.directory = path.parent().map(Path::to_owned).unwrap_or_default();
        manifest
            .check()
            .map_err(|problem| PolicyLoadError::Manifest {
                path: path.to_owned(),
                problem,
            })?;
        Ok(manifest)
    }

    /// Paths of the network files.
    pub fn network_paths(&self) -> impl Iterator<Item = PathBuf> + '_ {
        self.networks.iter().map(|name| self.directory.join(name))
    }

    fn check(&self) -> Result<(), String> {
        if self.format != MANIFEST_FORMAT {
            return Err(format!(
                "format {} is not the format {MANIFEST_FORMAT} this controller reads",
                self.format
            ));
        }
        check_shape("inputs.top", &self.inputs.top, &TOP_SHAPE)?;
        check_shape("inputs.bottom", &self.inputs.bottom, &BOTTOM_SHAPE)?;
        if let Some(previous) = &self.inputs.previous {
            check_shape("inputs.previous", previous, &PREVIOUS_SHAPE)?;
            if self.kind != PolicyKind::Cnn {
                return Err(format!(
                    "inputs.previous belongs to a CNN, not to an {}",
                    self.kind
                ));
            }
            let (top, bottom) = (&self.inputs.top.name, &self.inputs.bottom.name);
            if previous.name == *top || previous.name == *bottom {
                return Err(format!(
                    "inputs.previous ({:?}) must name another input than the thumbnails",
                    previous.name
                ));
            }
        }
        check_shape("outputs.command", &self.outputs.command, &COMMAND_SHAPE)?;
        let scale = self.normalisation.scale;
        if !(scale.is_finite() && scale > 0.0) {
            return Err(format!(
                "normalisation.scale must be positive, found {scale}"
            ));
        }
        let limits = [
            self.command_scale.forward_mps,
            self.command_scale.left_mps,
            self.command_scale.turn_radps,
        ];
        if !limits.iter().all(|l| l.is_finite() && *l > 0.0) {
            return Err(format!(
                "command_scale values must be positive, found {limits:?}"
            ));
        }
        for name in &self.networks {
            // A model directory names only files inside itself: no absolute path, no `..`.
            let inside = !name.is_empty()
                && Path::new(name)
                    .components()
                    .all(|part| matches!(part, std::path::Component::Normal(_)));
            if !inside {
                return Err(format!(
                    "network file {name:?} is not a file inside the model's directory"
                ));
            }
        }
        self.check_quantization()?;
        self.check_hypotheses()?;
        let networks = self.networks.len();
        match self.kind {
            PolicyKind::Cnn | PolicyKind::Rcnn if networks != 1 => {
                return Err(format!(
                    "a {} has one network file, found {networks}",
                    self.kind
                ));
            }
            PolicyKind::Rcnn => match &self.recurrent {
                None => return Err("an R-CNN needs a [recurrent] table".into()),
                Some(recurrent) if !(1..=MAX_RECURRENT_UNITS).contains(&recurrent.units) => {
                    return Err(format!(
                        "recurrent.units must be from 1 to {MAX_RECURRENT_UNITS}, found {}",
                        recurrent.units
                    ));
                }
                Some(_) => {}
            },
            PolicyKind::Hcnn => {
                let Some(gating) = &self.gating else {
                    return Err("an H-CNN needs a [gating] table with centroids".into());
                };
                if gating.clusters == 0
                    || gating.centroids.len() != gating.clusters
                    || networks != gating.clusters
                {
                    return Err(format!(
                        "gating.clusters is {}, with {} centroids and {networks} network files: \
                         all three must be equal and positive",
                        gating.clusters,
                        gating.centroids.len()
                    ));
                }
                if gating.centroids.iter().flatten().any(|v| !v.is_finite()) {
                    return Err("gating.centroids must be finite".into());
                }
            }
            PolicyKind::Cnn => {}
        }
        Ok(())
    }
}

impl PolicyManifest {
    fn check_hypotheses(&self) -> Result<(), String> {
        let Some(hypotheses) = &self.hypotheses else {
            return Ok(());
        };
        if self.kind != PolicyKind::Cnn {
            return Err(format!(
                "a [hypotheses] table belongs to a CNN, not to an {}",
                self.kind
            ));
        }
        if !(2..=MAX_HYPOTHESES).contains(&hypotheses.count) {
            return Err(format!(
                "hypotheses.count must be from 2 to {MAX_HYPOTHESES}, found {}",
                hypotheses.count
            ));
        }
        let margin = hypotheses.switch_margin;
        if !(margin.is_finite() && margin >= 0.0) {
            return Err(format!(
                "hypotheses.switch_margin must be finite and not negative, found {margin}"
            ));
        }
        let command = self.outputs.command.name.as_str();
        let (commands, logits) = (hypotheses.commands.as_str(), hypotheses.logits.as_str());
        if commands == logits || commands == command || logits == command {
            return Err(format!(
                "hypotheses.commands ({commands:?}), hypotheses.logits ({logits:?}) and \
                 outputs.command ({command:?}) must name three different outputs"
            ));
        }
        Ok(())
    }

    fn check_quantization(&self) -> Result<(), String> {
        let record = match (self.precision, &self.quantization) {
            (Precision::Fp32, None) => return Ok(()),
            (Precision::Fp32, Some(_)) => {
                return Err("a [quantization] table belongs to precision = \"int8\" only".into());
            }
            (Precision::Int8, None) => {
                return Err(
                    "precision = \"int8\" needs the [quantization] table that made it".into(),
                );
            }
            (Precision::Int8, Some(record)) => record,
        };
        if !(2..=8).contains(&record.weight_bits) {
            return Err(format!(
                "quantization.weight_bits must be from 2 to 8, found {}",
                record.weight_bits
            ));
        }
        let named: Vec<&str> = record.networks.iter().map(|n| n.network.as_str()).collect();
        if named != self.networks.iter().map(String::as_str).collect::<Vec<_>>()
            || record.float_networks_sha256.len() != self.networks.len()
        {
            return Err(format!(
                "quantization.networks ({named:?}) and float_networks_sha256 ({} of them) must \
                 follow networks ({:?})",
                record.float_networks_sha256.len(),
                self.networks
            ));
        }
        for network in &record.networks {
            if let Some((tensor, scale)) = network
                .activation_scales
                .iter()
                .find(|(_, scale)| !(scale.is_finite() && **scale > 0.0))
            {
                return Err(format!(
                    "quantization: the scale of {tensor:?} in {} must be positive, found {scale}",
                    network.network
                ));
            }
        }
        Ok(())
    }
}

fn check_shape(field: &str, spec: &TensorSpec, expected: &[usize]) -> Result<(), String> {
    if spec.shape != expected {
        return Err(format!(
            "{field} ({:?}) has shape {:?}; the controller feeds and reads {expected:?}",
            spec.name, spec.shape
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const CNN: &str = r#"
format = 1
kind = "cnn"
opset = 17
networks = ["policy.onnx"]
[normalisation]
scale = 0.00392156862745098
[inputs]
top = { name = "top", shape = [1, 1, 120, 160] }
bottom = { name = "bottom", shape = [1, 1, 60, 80] }
[outputs]
command = { name = "command", shape = [1, 3] }
[command_scale]
forward_mps = 0.25
left_mps = 0.15
turn_radps = 1.0
[training]
dataset = "test"
epochs = 3
test_error = 0.16
"#;

    fn parse(text: &str) -> Result<PolicyManifest, String> {
        PolicyManifest::parse(text, Path::new("/robot/models/cnn/policy.toml"))
            .map_err(|error| error.to_string())
    }

    #[test]
    fn reads_a_lineage_and_refuses_unknown_keys_in_it() {
        let lineage = "[lineage]\nstarted_from = { model = \"models/policy/a\", sha256 = \"0a6a900608e7\" }\n\
                       distilled_from = { model = \"models/policy/b\", sha256 = \"2160409187d4\", how = \"x\" }\n\
                       features_from = { model = \"models/policy/c\", sha256 = \"620420762658\" }\n\
                       former_names = [\"old\"]\n";
        let text = CNN.replace("[training]", &format!("{lineage}[training]"));
        let manifest = parse(&text).expect("valid manifest");
        let read = manifest.lineage.expect("a lineage");
        assert_eq!(
            read.started_from.map(|m| m.model).as_deref(),
            Some("models/policy/a")
        );
        assert_eq!(
            read.distilled_from.and_then(|m| m.how).as_deref(),
            Some("x")
        );
        assert_eq!(
            read.features_from.map(|m| m.sha256).as_deref(),
            Some("620420762658")
        );
        assert_eq!(read.former_names, vec!["old".to_string()]);
        assert!(parse(CNN).expect("valid manifest").lineage.is_none());
        assert!(parse(&text.replace("former_names", "formerly")).is_err());
    }

    #[test]
    fn reads_a_cnn_manifest() {
        let manifest = parse(CNN).expect("valid manifest");
        assert_eq!(manifest.kind, PolicyKind::Cnn);
        assert_eq!(
            manifest.network_paths().collect::<Vec<_>>(),
            [PathBuf::from("/robot/models/cnn/policy.onnx")]
        );
        assert_eq!(manifest.training.test_error, Some(0.16));
        assert_eq!(manifest.command_scale.walk_limits(), WalkLimits::default());
    }

    const QUANTIZATION: &str = r#"
[quantization]
method = "onnxruntime quantize_static, QDQ"
weight_bits = 7
onnxruntime_version = "1.32.0"
float_networks_sha256 = ["d4a2"]
calibration_dataset_hash = "9b6e"
calibration_frames = 256
calibration_seed = 0
calibration_rows_sha256 = "a60f"
[[quantization.networks]]
network = "policy.onnx"
activation_scales = { "top" = 0.0039, "/features/Concat_output_0" = 0.0052 }
"#;

    #[test]
    fn precision_is_fp32_unless_the_manifest_says_int8_with_its_record() {
        assert_eq!(parse(CNN).expect("fp32").precision, Precision::Fp32);
        let int8 = CNN.replace(
            "networks = [\"policy.onnx\"]",
            "networks = [\"policy.onnx\"]\nprecision = \"int8\"",
        );
        let manifest = parse(&format!("{int8}{QUANTIZATION}")).expect("int8");
        assert_eq!(manifest.precision, Precision::Int8);
        let record = manifest.quantization.expect("record");
        assert_eq!(record.networks[0].activation_scales["top"], 0.0039);
        assert_eq!(record.calibration_frames, 256);

        let error = parse(&int8).expect_err("int8 without its record");
        assert!(error.contains("needs the [quantization] table"), "{error}");
        let error = parse(&format!("{CNN}{QUANTIZATION}")).expect_err("a record on fp32");
        assert!(error.contains("belongs to precision"), "{error}");
        let error = parse(&format!("{int8}{}", QUANTIZATION.replace("0.0039", "-1.0")))
            .expect_err("negative scale");
        assert!(
            error.contains("\"top\" in policy.onnx must be positive"),
            "{error}"
        );
        let error = parse(&format!(
            "{int8}{}",
            QUANTIZATION.replace("network = \"policy.onnx\"", "network = \"other.onnx\"")
        ))
        .expect_err("another network");
        assert!(error.contains("must follow networks"), "{error}");
        let error = parse(&CNN.replace(
            "networks = [\"policy.onnx\"]",
            "networks = [\"policy.onnx\"]\nprecision = \"int4\"",
        ))
        .expect_err("unknown precision");
        assert!(error.contains("int4"), "{error}");
    }

    #[test]
    fn network_files_outside_the_model_directory_are_refused() {
        for name in [
            "../../../../etc/passwd",
            "/etc/passwd",
            "",
            "nets/../../x.onnx",
            ".",
        ] {
            let text = CNN.replace("\"policy.onnx\"", &format!("{name:?}"));
            let error = parse(&text).expect_err(name);
            assert!(
                error.contains("is not a file inside the model's directory"),
                "{name}: {error}"
            );
        }
        let nested = CNN.replace("\"policy.onnx\"", "\"nets/policy.onnx\"");
        assert!(parse(&nested).is_ok(), "a subdirectory is inside");
    }

    #[test]
    fn a_wrong_input_shape_names_the_field_and_both_shapes() {
        let text = CNN.replace("[1, 1, 120, 160]", "[1, 1, 240, 320]");
        let error = parse(&text).expect_err("wrong shape");
        assert!(
            error.contains(
                "inputs.top (\"top\") has shape [1, 1, 240, 320]; the controller feeds and reads [1, 1, 120, 160]"
            ),
            "{error}"
        );
        assert!(error.contains("/robot/models/cnn/policy.toml"), "{error}");
    }

    #[test]
    fn an_unknown_kind_or_field_is_refused() {
        assert!(parse(&CNN.replace("\"cnn\"", "\"transformer\"")).is_err());
        let error = parse(&CNN.replace("epochs = 3", "epochs = 3\nlearning_rate = 0.1"))
            .expect_err("unknown field");
        assert!(error.contains("learning_rate"), "{error}");
    }

    #[test]
    fn the_last_command_input_is_a_cnns_with_the_commands_shape() {
        let with = |spec: &str| {
            CNN.replace(
                "bottom = { name = \"bottom\", shape = [1, 1, 60, 80] }",
                &format!("bottom = {{ name = \"bottom\", shape = [1, 1, 60, 80] }}\n{spec}"),
            )
        };
        let manifest = parse(&with("previous = { name = \"previous\", shape = [1, 3] }"))
            .expect("a CNN with the last command");
        assert_eq!(
            manifest.inputs.previous.map(|p| p.name),
            Some("previous".to_owned())
        );
        assert_eq!(parse(CNN).expect("without").inputs.previous, None);
        let error = parse(&with("previous = { name = \"previous\", shape = [1, 4] }"))
            .expect_err("wrong shape");
        assert!(
            error.contains("inputs.previous (\"previous\") has shape [1, 4]"),
            "{error}"
        );
        let error = parse(&with("previous = { name = \"bottom\", shape = [1, 3] }"))
            .expect_err("a thumbnail's name");
        assert!(
            error.contains("another input than the thumbnails"),
            "{error}"
        );
        let rcnn = with("previous = { name = \"previous\", shape = [1, 3] }")
            .replace("\"cnn\"", "\"rcnn\"");
        let error = parse(&rcnn).expect_err("an R-CNN");
        assert!(
            error.contains("belongs to a CNN, not to an R-CNN"),
            "{error}"
        );
    }

    #[test]
    fn an_rcnn_needs_its_state_table() {
        let error = parse(&CNN.replace("\"cnn\"", "\"rcnn\"")).expect_err("no state");
        assert!(error.contains("[recurrent]"), "{error}");
    }

    #[test]
    fn an_hcnn_needs_one_centroid_per_network() {
        let text = CNN.replace("\"cnn\"", "\"hcnn\"").replace(
            "[training]",
            "[gating]\nclusters = 2\ncentroids = [[0.1, 0.2, 0.3, 0.2, 0.2, 0.1, 0.2, 0.3, 0.2, 0.2]]\n[training]",
        );
        let error = parse(&text).expect_err("one centroid for two clusters");
        assert!(
            error.contains("gating.clusters is 2, with 1 centroids and 1 network files"),
            "{error}"
        );
    }

    const HYPOTHESES: &str = r#"
[hypotheses]
count = 2
commands = "hypotheses"
logits = "logits"
switch_margin = 1.5
"#;

    #[test]
    fn a_cnn_may_name_its_hypotheses_and_a_switch_margin() {
        let text = CNN.replace("[training]", &format!("{HYPOTHESES}[training]"));
        let hypotheses = parse(&text).expect("valid").hypotheses.expect("table");
        assert_eq!(hypotheses.count, 2);
        assert_eq!(hypotheses.switch_margin, 1.5);
        assert_eq!(parse(CNN).expect("valid").hypotheses, None);

        let cases = [
            (
                "count = 2",
                "count = 1",
                "hypotheses.count must be from 2 to 16, found 1",
            ),
            ("count = 2", "count = 17", "found 17"),
            (
                "switch_margin = 1.5",
                "switch_margin = -0.5",
                "must be finite and not negative",
            ),
            (
                "switch_margin = 1.5",
                "switch_margin = nan",
                "must be finite and not negative",
            ),
            (
                "logits = \"logits\"",
                "logits = \"command\"",
                "three different outputs",
            ),
            (
                "logits = \"logits\"",
                "logits = \"hypotheses\"",
                "three different outputs",
            ),
        ];
        for (from, to, expected) in cases {
            let table = HYPOTHESES.replace(from, to);
            let error =
                parse(&CNN.replace("[training]", &format!("{table}[training]"))).expect_err(to);
            assert!(error.contains(expected), "{to}: {error}");
        }
        let rcnn = CNN
            .replace("\"cnn\"", "\"rcnn\"")
            .replace("[training]", &format!("{HYPOTHESES}[training]"));
        let error = parse(&rcnn).expect_err("hypotheses on an R-CNN");
        assert!(
            error.contains("belongs to a CNN, not to an R-CNN"),
            "{error}"
        );
    }

    #[test]
    fn a_nonsense_scale_is_refused() {
        assert!(parse(&CNN.replace("forward_mps = 0.25", "forward_mps = -1.0")).is_err());
        assert!(parse(&CNN.replace("scale = 0.00392156862745098", "scale = 0.0")).is_err());
    }
}
