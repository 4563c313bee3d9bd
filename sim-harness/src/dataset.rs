//! Recorded demonstrations (DESIGN.md, "Dataset"): one compressed NumPy `.npz` per episode,
//! one row per computed command, and a `dataset.json` index beside them.
//!
//! Files are written byte for byte the same for the same episode (fixed zip timestamps,
//! deterministic deflate), to a temporary name first and renamed when complete, so an
//! interrupted recording never leaves a half-written episode behind.
//!
//! Identity: `dataset.json` lists each episode's SHA-256 and a content hash over all of them
//! (SHA-256 of the lines `"{seed} {sha256}\n"` in seed order), so a model's manifest can name
//! the exact data it learned from, and a reader can tell when a file is missing or changed.

use std::collections::BTreeMap;
use std::fs;
use std::io::{Cursor, Read, Write};
use std::path::{Path, PathBuf};

use dribble_controller::{BottomThumbnail, SpeedCommand, TopThumbnail};
use serde::{Deserialize, Serialize};

use crate::expert::Phase;
use crate::pose::FieldPose;

/// A dataset file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.to_owned(),
        source,
    }
}

/// The rows of one episode, in memory until the episode ends.
#[derive(Clone, Debug, Default)]
pub struct EpisodeRecording {
    top: Vec<u8>,
    bottom: Vec<u8>,
    command: Vec<f32>,
    robot_pose: Vec<f32>,
    ball: Vec<f32>,
    time_s: Vec<f64>,
    phase: Vec<u8>,
    /// Rows of a policy-driven episode only: what the policy commanded, and whether the
    /// expert's command was executed instead.
    policy_command: Vec<f32>,
    expert_executed: Vec<u8>,
    /// Rows of an episode recorded with a clean twin only: the thumbnails of the same frames
    /// without camera effects and light.
    top_clean: Vec<u8>,
    bottom_clean: Vec<u8>,
}

/// What a learned policy commanded in a row whose `command` is the expert's label.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PolicyCommand {
    pub speed: SpeedCommand,
    /// The expert's command was executed instead of this one (DAgger's β draw).
    pub expert_executed: bool,
}

/// One computed command and what it was computed from.
#[derive(Clone, Copy, Debug)]
pub struct Row<'a> {
    pub top: &'a TopThumbnail,
    pub bottom: &'a BottomThumbnail,
    pub command: SpeedCommand,
    pub robot: FieldPose,
    pub ball: glam::Vec2,
    pub time_s: f64,
    pub phase: Phase,
    /// In a policy-driven (labelled) episode: the policy's own command; `command` is then
    /// the expert's label for this state. Every row of an episode has one, or none does.
    pub policy_command: Option<PolicyCommand>,
    /// In an episode recorded with a clean twin (`render::CleanTwin`): the thumbnails of the
    /// same frames without camera effects and light. Every row of an episode has them, or none.
    pub clean_twin: Option<(&'a TopThumbnail, &'a BottomThumbnail)>,
}

impl EpisodeRecording {
    pub fn push(&mut self, row: Row<'_>) {
        self.top.extend_from_slice(row.top.as_bytes());
        self.bottom.extend_from_slice(row.bottom.as_bytes());
        self.command.extend_from_slice(&row.command.as_array());
        self.robot_pose
            .extend_from_slice(&[row.robot.x, row.robot.y, row.robot.theta]);
        self.ball.extend_from_slice(&[row.ball.x, row.ball.y]);
        self.time_s.push(row.time_s);
        self.phase.push(row.phase as u8);
        if let Some(policy) = row.policy_command {
            self.policy_command
                .extend_from_slice(&policy.speed.as_array());
            self.expert_executed.push(u8::from(policy.expert_executed));
        }
        if let Some((top, bottom)) = row.clean_twin {
            self.top_clean.extend_from_slice(top.as_bytes());
            self.bottom_clean.extend_from_slice(bottom.as_bytes());
        }
    }

    pub fn rows(&self) -> usize {
        self.time_s.len()
    }

    /// Whether the rows carry the thumbnails of a clean twin.
    pub fn has_clean_twin(&self) -> bool {
        !self.top_clean.is_empty()
    }

    /// Whether the rows carry a policy's own commands (a labelled, policy-driven episode).
    pub fn is_policy_driven(&self) -> bool {
        !self.expert_executed.is_empty()
    }

    /// The episode as `.npz` bytes: `top` u8[T,120,160], `bottom` u8[T,60,80], `command`
    /// f32[T,3], `robot_pose` f32[T,3], `ball` f32[T,2], `time_s` f64[T], `phase` u8[T];
    /// a policy-driven episode adds `policy_command` f32[T,3] and `expert_executed` u8[T]
    /// (`command` is then the expert's label); an episode recorded with a clean twin adds
    /// `top_clean` u8[T,120,160] and `bottom_clean` u8[T,60,80].
    pub fn to_npz(&self) -> Vec<u8> {
        let t = self.rows();
        let mut arrays: Vec<(&str, Vec<u8>)> = vec![
            ("top", npy(&[t, 120, 160], &self.top)),
            ("bottom", npy(&[t, 60, 80], &self.bottom)),
            ("command", npy(&[t, 3], &self.command)),
            ("robot_pose", npy(&[t, 3], &self.robot_pose)),
            ("ball", npy(&[t, 2], &self.ball)),
            ("time_s", npy(&[t], &self.time_s)),
            ("phase", npy(&[t], &self.phase)),
        ];
        if self.is_policy_driven() {
            arrays.push(("policy_command", npy(&[t, 3], &self.policy_command)));
            arrays.push(("expert_executed", npy(&[t], &self.expert_executed)));
        }
        if self.has_clean_twin() {
            arrays.push(("top_clean", npy(&[t, 120, 160], &self.top_clean)));
            arrays.push(("bottom_clean", npy(&[t, 60, 80], &self.bottom_clean)));
        }
        let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated)
            .last_modified_time(zip::DateTime::default());
        for (name, bytes) in arrays {
            // Writing to memory cannot fail.
            let _ = zip.start_file(format!("{name}.npy"), options);
            let _ = zip.write_all(&bytes);
        }
        zip.finish().map(Cursor::into_inner).unwrap_or_default()
    }

    /// Writes the episode to `path` through a temporary file; returns its size and SHA-256.
    pub fn write(&self, path: &Path) -> Result<(u64, String), DatasetError> {
        let bytes = self.to_npz();
        write_atomically(path, &bytes)?;
        Ok((bytes.len() as u64, sha256_hex(&bytes)))
    }
}

/// A `.npy` holding `values` in `shape`, C order, with the element type NumPy uses for `T`
/// (`|u1`, `<f4`, `<f8`): byte for byte what NumPy's `np.save` writes (format 1.0, its
/// header with the spare room it leaves to grow the first axis, spaces up to a multiple of
/// 64 bytes, a newline).
///
/// `npyz` encodes the values and names their type; its file writer is not used, because it
/// lays the shape out its own way (`(3, 4, )`, padded to 16 bytes) and an episode file's
/// SHA-256 is the dataset's identity: the shipped models' manifests name their training and
/// test data by hashes of files with NumPy's header, so a recording made today must give
/// the same bytes for the same episode.
fn npy<T: npyz::AutoSerialize>(shape: &[usize], values: &[T]) -> Vec<u8> {
    use npyz::TypeWrite as _;
    debug_assert_eq!(shape.iter().product::<usize>(), values.len());
    let dtype = T::default_dtype();
    let dims = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let descr = dtype.descr();
    let mut header = format!("{{'descr': {descr}, 'fortran_order': False, 'shape': {dims}, }}");
    // NumPy's room to grow the first axis in place: up to 21 digits in all.
    if let Some(first) = shape.first() {
        header.push_str(&" ".repeat(21usize.saturating_sub(first.to_string().len())));
    }
    // Magic (6) + version (2) + length (2) + header, padded with spaces to 64 bytes, then \n.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + size_of_val(values));
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    // A type's own default dtype always has a writer, and writing to memory cannot fail.
    let written = T::writer(&dtype).map(|writer| {
        for value in values {
            let _ = writer.write_one(&mut bytes, value);
        }
    });
    debug_assert!(written.is_ok(), "{written:?}");
    bytes
}

/// An array read back from a `.npz`.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub descr: String,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

impl NpyArray {
    pub fn as_f32(&self) -> Vec<f32> {
        self.data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    }
}

/// Reads every array of a `.npz` written by [`EpisodeRecording::write`].
pub fn read_npz(path: &Path) -> Result<BTreeMap<String, NpyArray>, DatasetError> {
    let format = |message: String| DatasetError::Format {
        path: path.to_owned(),
        message,
    };
    let bytes = fs::read(path).map_err(io_error(path))?;
    let mut archive =
        zip::ZipArchive::new(Cursor::new(bytes)).map_err(|e| format(e.to_string()))?;
    let mut arrays = BTreeMap::new();
    for i in 0..archive.len() {
        let mut file = archive.by_index(i).map_err(|e| format(e.to_string()))?;
        let name = file
            .name()
            .map_err(|e| format(e.to_string()))?
            .trim_end_matches(".npy")
            .to_owned();
        let mut raw = Vec::new();
        file.read_to_end(&mut raw).map_err(io_error(path))?;
        arrays.insert(
            name.clone(),
            parse_npy(&raw).map_err(|m| format(format!("{name}: {m}")))?,
        );
    }
    Ok(arrays)
}

/// The size in bytes of one element of a `.npy` type this crate writes; `None` for any other.
fn item_size(descr: &str) -> Option<usize> {
    match descr {
        "|u1" | "|i1" | "|b1" => Some(1),
        "<f4" | "<i4" | "<u4" => Some(4),
        "<f8" | "<i8" | "<u8" => Some(8),
        _ => None,
    }
}

/// Parses a `.npy`: `npyz` reads the header, then every field is checked against the bytes.
/// A header that lies about its shape, its type or its length is an error, never a panic or a
/// huge allocation (the files come from disk and may be truncated or hostile).
fn parse_npy(raw: &[u8]) -> Result<NpyArray, String> {
    let mut reader = Cursor::new(raw);
    let header = npyz::NpyHeader::from_reader(&mut reader).map_err(|e| e.to_string())?;
    let descr = match header.dtype() {
        npyz::DType::Plain(type_str) => type_str.to_string(),
        other => return Err(format!("unsupported element type {}", other.descr())),
    };
    let item = item_size(&descr).ok_or(format!("unsupported element type {descr:?}"))?;
    if header.order() != npyz::Order::C {
        return Err("Fortran-ordered arrays are not supported".into());
    }
    let shape = header
        .shape()
        .iter()
        .map(|&dim| usize::try_from(dim).map_err(|_| "shape overflows".to_owned()))
        .collect::<Result<Vec<_>, _>>()?;
    let bytes = shape
        .iter()
        .try_fold(item, |total, &dim| total.checked_mul(dim))
        .ok_or("shape overflows")?;
    let data = raw
        .get(usize::try_from(reader.position()).unwrap_or(usize::MAX)..)
        .unwrap_or_default();
    if data.len() != bytes {
        return Err(format!(
            "shape {shape:?} of {descr} needs {bytes} bytes, the file holds {}",
            data.len()
        ));
    }
    Ok(NpyArray {
        descr,
        shape,
        data: data.to_vec(),
    })
}

/// How an episode ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Goal,
    BallOut,
    TimeLimit,
    /// The controller died or stopped answering: the episode failed.
    ControllerLost,
    /// Stopped from outside before it ended (a Gymnasium environment reset in the middle of
    /// an episode, [`crate::episode_observer::EpisodeObserver::abandon`]); never recorded
    /// or evaluated.
    Abandoned,
}

impl Outcome {
    pub fn name(self) -> &'static str {
        match self {
            Self::Goal => "goal",
            Self::BallOut => "ball out",
            Self::TimeLimit => "time limit",
            Self::ControllerLost => "controller lost",
            Self::Abandoned => "abandoned",
        }
    }
}

/// One episode in `dataset.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeEntry {
    pub seed: u64,
    pub file: String,
    pub outcome: Outcome,
    pub rows: usize,
    pub duration_s: f64,
    pub bytes: u64,
    /// SHA-256 of the `.npz` file, lowercase hex.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// The conditions the episode was seen under (`crate::conditions`), absent when clean.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conditions: Option<String>,
}

/// SHA-256 of `bytes` as lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// A dataset whose files do not match its index.
#[derive(Debug, thiserror::Error)]
pub enum DatasetIntegrityError {
    #[error("{directory}: episode {seed} is listed in dataset.json but {file} is missing")]
    Missing {
        directory: PathBuf,
        seed: u64,
        file: String,
    },
    #[error(
        "{directory}: {file} (episode {seed}) is not the file dataset.json lists: its SHA-256 is {found}, expected {expected}; re-record it with `dribble record`"
    )]
    Changed {
        directory: PathBuf,
        seed: u64,
        file: String,
        expected: String,
        found: String,
    },
    #[error(
        "{directory}: dataset.json lists no hash for episode {seed}; re-record it with `dribble record`"
    )]
    Unhashed { directory: PathBuf, seed: u64 },
    #[error("{directory}: the episodes {missing:?} were asked for but are not in this dataset")]
    SeedsAbsent {
        directory: PathBuf,
        missing: Vec<u64>,
    },
    #[error(transparent)]
    Dataset(#[from] DatasetError),
}

/// `dataset.json`: the episodes and how they were made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetIndex {
    pub format: u32,
    pub project_version: String,
    pub simulator: serde_json::Value,
    pub expert: serde_json::Value,
    pub episodes: Vec<EpisodeEntry>,
    /// SHA-256 over the episodes' hashes (module documentation); kept current by `save`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub content_hash: Option<String>,
    /// Who drove, when not the expert: the policy, its identity, who labelled the rows and
    /// the mixing rule (DAgger). Absent for the expert's demonstrations.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub driver: Option<serde_json::Value>,
    /// The teacher whose commands label the rows (`paper` or `observable`, DESIGN.md
    /// "Teachers"); absent in files written before there were two, which the paper's labelled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub teacher: Option<String>,
    /// The conditions the recording ran under (`clean` when absent; `randomized`: each
    /// episode names its own draw).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conditions: Option<String>,
}

impl DatasetIndex {
    pub const FILE: &'static str = "dataset.json";

    pub fn load(directory: &Path) -> Result<Option<Self>, DatasetError> {
        let path = directory.join(Self::FILE);
        match fs::read_to_string(&path) {
            Ok(text) => serde_json::from_str(&text)
                .map(Some)
                .map_err(|e| DatasetError::Format {
                    path,
                    message: e.to_string(),
                }),
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(DatasetError::Io { path, source }),
        }
    }

    /// The index of a recorded dataset that lists at least one episode: what a reader of
    /// `directory` needs (a missing or empty index is an error that says so).
    pub fn load_recorded(directory: &Path) -> Result<Self, DatasetError> {
        let path = directory.join(Self::FILE);
        let Some(index) = Self::load(directory)? else {
            return Err(DatasetError::Format {
                path,
                message: "no such file: not a dataset (record one with `dribble record`)".into(),
            });
        };
        if index.episodes.is_empty() {
            return Err(DatasetError::Format {
                path,
                message: "lists no episodes".into(),
            });
        }
        Ok(index)
    }

    /// The content hash of the listed episodes, if every one of them has a hash.
    pub fn compute_content_hash(&self) -> Option<String> {
        let mut lines = String::new();
        for entry in &self.episodes {
            lines.push_str(&format!("{} {}\n", entry.seed, entry.sha256.as_ref()?));
        }
        Some(sha256_hex(lines.as_bytes()))
    }

    /// Checks that every listed episode's file is there and is the file that was recorded.
    pub fn verify(&self, directory: &Path) -> Result<(), DatasetIntegrityError> {
        for entry in &self.episodes {
            let path = directory.join(&entry.file);
            let bytes = match fs::read(&path) {
                Ok(bytes) => bytes,
                Err(error) if error.kind() == std::io::ErrorKind::NotFound => {
                    return Err(DatasetIntegrityError::Missing {
                        directory: directory.to_owned(),
                        seed: entry.seed,
                        file: entry.file.clone(),
                    });
                }
                Err(source) => return Err(DatasetError::Io { path, source }.into()),
            };
            let Some(expected) = &entry.sha256 else {
                return Err(DatasetIntegrityError::Unhashed {
                    directory: directory.to_owned(),
                    seed: entry.seed,
                });
            };
            let found = sha256_hex(&bytes);
            if &found != expected {
                return Err(DatasetIntegrityError::Changed {
                    directory: directory.to_owned(),
                    seed: entry.seed,
                    file: entry.file.clone(),
                    expected: expected.clone(),
                    found,
                });
            }
        }
        Ok(())
    }

    /// Fails unless every seed of `seeds` is in the dataset.
    pub fn require_seeds(
        &self,
        directory: &Path,
        seeds: impl IntoIterator<Item = u64>,
    ) -> Result<(), DatasetIntegrityError> {
        let missing: Vec<u64> = seeds
            .into_iter()
            .filter(|s| !self.episodes.iter().any(|e| e.seed == *s))
            .collect();
        if missing.is_empty() {
            Ok(())
        } else {
            Err(DatasetIntegrityError::SeedsAbsent {
                directory: directory.to_owned(),
                missing,
            })
        }
    }

    pub fn save(&self, directory: &Path) -> Result<(), DatasetError> {
        let path = directory.join(Self::FILE);
        let mut index = self.clone();
        index.content_hash = self.compute_content_hash();
        let text = serde_json::to_string_pretty(&index).map_err(|e| DatasetError::Format {
            path: path.clone(),
            message: e.to_string(),
        })?;
        write_atomically(&path, format!("{text}\n").as_bytes())
    }

    /// Records `entry`, replacing an earlier entry of the same seed; keeps seed order.
    pub fn insert(&mut self, entry: EpisodeEntry) {
        self.episodes.retain(|e| e.seed != entry.seed);
        self.episodes.push(entry);
        self.episodes.sort_by_key(|e| e.seed);
    }
}

/// The file name of an episode.
pub fn episode_file(seed: u64) -> String {
    format!("episode_{seed:05}.npz")
}

fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    let temporary = path.with_extension("partial");
    let mut file = fs::File::create(&temporary).map_err(io_error(&temporary))?;
    file.write_all(bytes).map_err(io_error(&temporary))?;
    file.sync_all().map_err(io_error(&temporary))?;
    fs::rename(&temporary, path).map_err(io_error(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_files_are_those_numpy_writes() {
        // `np.save` of NumPy 2.4 for zeros of these shapes and types, header and values.
        let header = |text: &str| {
            let mut bytes = b"\x93NUMPY\x01\x00v\x00".to_vec();
            bytes.extend_from_slice(format!("{text:<117}\n").as_bytes());
            bytes
        };
        let mut f32s = header("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }");
        f32s.extend_from_slice(&[0; 24]);
        assert_eq!(npy(&[2, 3], &[0.0f32; 6]), f32s);
        let mut f64s = header("{'descr': '<f8', 'fortran_order': False, 'shape': (5,), }");
        f64s.extend_from_slice(&[0; 40]);
        assert_eq!(npy(&[5], &[0.0f64; 5]), f64s);
        let mut pixels =
            header("{'descr': '|u1', 'fortran_order': False, 'shape': (7, 120, 160), }");
        pixels.extend_from_slice(&[0; 7 * 120 * 160]);
        assert_eq!(npy(&[7, 120, 160], &[0u8; 7 * 120 * 160]), pixels);
        // Values are written as they are, little-endian.
        let one = npy(&[1], &[1.5f32]);
        assert_eq!(one[one.len() - 4..], 1.5f32.to_le_bytes());
    }

    #[test]
    fn npy_headers_are_64_byte_aligned_and_parse_back() {
        let bytes = npy(&[2, 3], &[0.0f32; 6]);
        let header_end = 10 + usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
        assert_eq!(header_end % 64, 0);
        assert_eq!(bytes[header_end - 1], b'\n');
        let array = parse_npy(&bytes).expect("parses");
        assert_eq!(array.descr, "<f4");
        assert_eq!(array.shape, vec![2, 3]);
        let one_dimensional = parse_npy(&npy(&[5], &[0.0f64; 5])).expect("parses");
        assert_eq!(one_dimensional.descr, "<f8");
        assert_eq!(one_dimensional.shape, vec![5]);
    }

    /// Three rows of a small episode, built from scratch on every call.
    fn small_recording() -> EpisodeRecording {
        let mut recording = EpisodeRecording::default();
        let (mut top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
        top.as_bytes_mut()[7] = 99;
        for i in 0..3 {
            recording.push(Row {
                top: &top,
                bottom: &bottom,
                command: SpeedCommand::new(0.5, -0.25, i as f32 * 0.1).expect("finite"),
                robot: FieldPose::new(1.0, 2.0, 0.5),
                ball: glam::Vec2::new(3.0, -1.0),
                time_s: f64::from(i) / 30.0,
                phase: Phase::Dribble,
                policy_command: None,
                clean_twin: None,
            });
        }
        recording
    }

    #[test]
    fn an_episode_round_trips_and_two_recordings_are_byte_identical() {
        let directory = std::env::temp_dir().join(format!("dribble-npz-{}", std::process::id()));
        fs::create_dir_all(&directory).expect("dir");
        let (first, second) = (directory.join("first.npz"), directory.join("second.npz"));
        small_recording().write(&first).expect("write");
        small_recording().write(&second).expect("write");
        let bytes = fs::read(&first).expect("read");
        assert!(bytes == fs::read(&second).expect("read"), "byte-identical");
        let arrays = read_npz(&first).expect("read back");
        assert_eq!(arrays["top"].shape, vec![3, 120, 160]);
        assert_eq!(arrays["top"].data[7], 99);
        assert_eq!(arrays["command"].as_f32()[..3], [0.5, -0.25, 0.0]);
        assert_eq!(arrays["phase"].data, vec![3, 3, 3]);
        assert_eq!(arrays["time_s"].descr, "<f8");
        fs::remove_dir_all(directory).expect("clean up");
    }

    #[test]
    fn npy_headers_that_lie_are_errors() {
        let good = npy(&[2, 3], &[0.0f32; 6]);
        let header_end = 10 + usize::from(u16::from_le_bytes([good[8], good[9]]));
        let with_header = |header: &str| {
            let mut bytes = good[..10].to_vec();
            let padded = format!("{header:<width$}", width = header_end - 10);
            bytes.extend_from_slice(padded.as_bytes());
            bytes.extend_from_slice(&good[header_end..]);
            bytes
        };
        let cases = [
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 4), }",
                "needs 32 bytes",
            ),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (9999999999999, 9999999999), }",
                "overflows",
            ),
            (
                "{'descr': '<c16', 'fortran_order': False, 'shape': (2, 3), }",
                "element type",
            ),
            (
                "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }",
                "Fortran",
            ),
        ];
        for (header, expected) in cases {
            let error = parse_npy(&with_header(header)).expect_err(header);
            assert!(error.contains(expected), "{header}: {error}");
        }
        assert!(
            parse_npy(&good[..good.len() - 1])
                .expect_err("short")
                .contains("holds 23")
        );
        assert!(parse_npy(&good[..20]).is_err(), "truncated header");
        // Headers that are not Python literals of the right form: npyz refuses them.
        for header in [
            "{'descr': '<f4', 'fortran_order': False, 'shape': ), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (, }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, x), }",
            "{'descr': '<f4', 'fortran_order': False, }",
            "not a dict at all",
        ] {
            assert!(parse_npy(&with_header(header)).is_err(), "{header}");
        }
        assert!(
            parse_npy(&with_header(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"
            ))
            .is_ok()
        );
    }
}
