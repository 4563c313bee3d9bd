//! The journal of `dribble eval --trajectories FILE`: `FILE.partial`, the run's settings on
//! its first line and every finished episode on a line of its own, appended as the episode
//! ends. A run cut off (a session's end, a killed job) continues with `--resume`: the
//! episodes the journal holds for the same settings are kept and only the others are
//! played. Episodes are deterministic in their seed and a journal line keeps exactly what the
//! trajectories file keeps ([`crate::trajectories::file::episode_line`]), so the file a resumed
//! run writes is an uninterrupted run's byte for byte (`tests/cli_episodes.rs` checks it).
//! The tick latencies of kept episodes are not kept: a resumed run reports the latency of
//! the episodes it played itself.
//!
//! The settings are what decides an episode besides its seed: the policy's files by content
//! (the manifest and its networks), the teacher, the time limit, the engine, instruction set
//! and transport. A journal of other settings is not resumed from (it is said why, and the
//! run starts over); a torn last line (a kill while it was written) is dropped.
//!
//! An episode whose controller was lost (it died, or stopped answering within the lock-step
//! timeout, as on a machine starved by other work) is not kept: it says nothing of the policy
//! and is played again. A controller that dies on its own dies again and is recorded again. A
//! run that ends with such episodes keeps its journal (with --jobs, its `.jobs/` directory)
//! and fails, so that the next `--resume` plays them.

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};

use anyhow::Context;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_sim::dataset::Outcome;
use dribble_sim::runner::EpisodeResult;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::trajectories::file::{episode_line, parse_episode_line};

/// What decides an episode's outcome besides its seed: a journal is resumed from only when
/// it names the same.
#[derive(Clone, Debug, Deserialize, PartialEq, Serialize)]
pub struct RunSettings {
    /// `expert`, or the policy's content hash (its manifest and network files, SHA-256).
    pub driver: String,
    pub teacher: String,
    pub time_limit_s: f32,
    pub engine: String,
    pub isa: String,
    pub transport: String,
    /// The conditions the episodes are seen under (`clean` in journals written before).
    #[serde(default = "clean")]
    pub conditions: String,
    /// Samples a pixel of the cameras' images (4 in journals written before).
    #[serde(default = "four")]
    pub camera_samples: u32,
}

fn clean() -> String {
    "clean".to_owned()
}

fn four() -> u32 {
    dribble_sim::render::Multisampling::Four.samples()
}

impl RunSettings {
    /// The content hash of the policy whose `policy.toml` is `manifest`: its manifest's bytes
    /// and each network file's, in the manifest's order.
    pub fn policy_hash(manifest: &Path) -> anyhow::Result<String> {
        let loaded = PolicyManifest::load(manifest)
            .with_context(|| format!("cannot read the policy {}", manifest.display()))?;
        let mut hash = Sha256::new();
        let mut add = |path: &Path| -> anyhow::Result<()> {
            let bytes =
                fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
            hash.update((bytes.len() as u64).to_le_bytes());
            hash.update(&bytes);
            Ok(())
        };
        add(manifest)?;
        for network in loaded.network_paths() {
            add(&network)?;
        }
        let digest = hash.finalize();
        Ok(digest.iter().map(|byte| format!("{byte:02x}")).collect())
    }
}

/// `FILE.partial` for the trajectories file `FILE`.
pub fn journal_path(trajectories: &Path) -> PathBuf {
    let mut name = trajectories.as_os_str().to_owned();
    name.push(".partial");
    PathBuf::from(name)
}

/// An episode a cut run left, and the engine that ran it.
pub type KeptEpisode = (EpisodeResult, Option<String>);

/// The journal being written.
#[derive(Debug)]
pub struct EvalJournal {
    path: PathBuf,
    file: File,
}

impl EvalJournal {
    /// Starts the journal of a run of `settings` over `seeds` for the trajectories file
    /// `trajectories`. With `resume`, first takes the episodes of those seeds that a cut run
    /// of the same settings left (in seed order, each seed once), and says what it kept or
    /// why it kept nothing.
    pub fn start(
        trajectories: &Path,
        settings: &RunSettings,
        seeds: &Range<u64>,
        resume: bool,
    ) -> anyhow::Result<(Self, Vec<KeptEpisode>)> {
        let path = journal_path(trajectories);
        let kept = if resume {
            read_kept(&path, settings, seeds)?
        } else {
            Vec::new()
        };
        // The journal afresh: the settings, then what is kept (a torn line is gone).
        let mut text = serde_json::to_string(settings)?;
        text.push('\n');
        for (result, engine) in &kept {
            text.push_str(&episode_line(result, engine.as_deref())?);
            text.push('\n');
        }
        let temporary = path.with_extension("partial.new");
        fs::write(&temporary, text)
            .with_context(|| format!("cannot write {}", temporary.display()))?;
        fs::rename(&temporary, &path)
            .with_context(|| format!("cannot write {}", path.display()))?;
        let file = OpenOptions::new()
            .append(true)
            .open(&path)
            .with_context(|| format!("cannot append to {}", path.display()))?;
        Ok((Self { path, file }, kept))
    }

    /// Appends a finished episode (one write of one line, so a kill leaves whole lines and at
    /// most one torn last line).
    pub fn append(&mut self, result: &EpisodeResult, engine: Option<&str>) -> anyhow::Result<()> {
        let mut line = episode_line(result, engine)?;
        line.push('\n');
        self.file
            .write_all(line.as_bytes())
            .with_context(|| format!("cannot append to {}", self.path.display()))
    }

    /// The run has written its trajectories file: the journal goes.
    pub fn finish(self) -> anyhow::Result<()> {
        drop(self.file);
        fs::remove_file(&self.path)
            .with_context(|| format!("cannot remove {}", self.path.display()))
    }
}

/// The episodes of `seeds` in the journal at `path` when it names `settings`.
fn read_kept(
    path: &Path,
    settings: &RunSettings,
    seeds: &Range<u64>,
) -> anyhow::Result<Vec<KeptEpisode>> {
    let text = match fs::read_to_string(path) {
        Ok(text) => text,
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => {
            println!("resume: no journal {} (nothing to keep)", path.display());
            return Ok(Vec::new());
        }
        Err(error) => {
            return Err(error).with_context(|| format!("cannot read {}", path.display()));
        }
    };
    let mut lines = text.lines();
    let theirs: Option<RunSettings> = lines
        .next()
        .and_then(|line| serde_json::from_str(line).ok());
    if theirs.as_ref() != Some(settings) {
        println!(
            "resume: {} was left by a run of other settings, so every episode is played \
             (it: {}; this run: {})",
            path.display(),
            theirs.map_or_else(|| "unreadable".to_owned(), |s| format!("{s:?}")),
            format_args!("{settings:?}")
        );
        return Ok(Vec::new());
    }
    let mut kept: Vec<KeptEpisode> = Vec::new();
    for line in lines {
        let Ok((result, engine)) = parse_episode_line(line) else {
            println!("resume: a torn line in {} is dropped", path.display());
            break;
        };
        let seed = result.setup.seed;
        if result.outcome == Outcome::ControllerLost {
            println!(
                "resume: seed {seed} lost its controller ({}): played again",
                result.failure.as_deref().unwrap_or("no reason given")
            );
            continue;
        }
        if seeds.contains(&seed) && kept.iter().all(|(k, _)| k.setup.seed != seed) {
            kept.push((result, engine));
        }
    }
    kept.sort_by_key(|(result, _)| result.setup.seed);
    println!(
        "resume: {} episode(s) kept from {}",
        kept.len(),
        path.display()
    );
    Ok(kept)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use dribble_controller::tick_stats::TickStats;
    use dribble_sim::episode::EpisodeSetup;
    use glam::Vec2;

    fn settings(driver: &str) -> RunSettings {
        RunSettings {
            driver: driver.to_owned(),
            teacher: "paper".to_owned(),
            time_limit_s: 90.0,
            engine: "Compiled".to_owned(),
            isa: "Some(Portable)".to_owned(),
            transport: "Iceoryx2".to_owned(),
            conditions: "clean".to_owned(),
            camera_samples: 4,
        }
    }

    /// An empty scratch directory of this test process.
    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("dribble-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).expect("scratch");
        dir
    }

    /// A finished episode of `seed` (a goal), for tests here and elsewhere.
    pub(crate) fn episode(seed: u64) -> EpisodeResult {
        EpisodeResult {
            setup: EpisodeSetup::from_seed(seed),
            outcome: Outcome::Goal,
            duration_s: 12.5,
            distance_walked_m: 3.25,
            robot_path: vec![Vec2::new(0.1, -2.6696692)],
            ball_path: vec![Vec2::new(1.0, 2.0)],
            heading_path: vec![0.3],
            first_sighting_s: Some(0.5),
            computed_commands: 300,
            tick_times: TickStats::new(std::time::Duration::from_millis(10)),
            failure: None,
            expert_executed: 0,
        }
    }

    #[test]
    fn a_cut_journal_of_the_same_settings_is_kept_and_of_others_is_not() {
        let dir = scratch("journal");
        let trajectories = dir.join("t.json");
        let (mut journal, kept) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), true).expect("starts");
        assert!(kept.is_empty());
        for seed in [6, 5, 20] {
            journal
                .append(&episode(seed), Some("compiled"))
                .expect("appends");
        }
        drop(journal);
        // A kill while the next line was written.
        let path = journal_path(&trajectories);
        let mut file = OpenOptions::new().append(true).open(&path).expect("open");
        file.write_all(b"{\"engine\": \"comp").expect("torn");
        drop(file);

        let (journal, kept) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), true).expect("resumes");
        let seeds: Vec<u64> = kept.iter().map(|(r, _)| r.setup.seed).collect();
        assert_eq!(seeds, [5, 6], "in order, only the run's seeds");
        assert_eq!(kept[0].1.as_deref(), Some("compiled"));
        let back = &kept[0].0;
        assert_eq!(back.robot_path, episode(5).robot_path);
        assert_eq!(back.distance_walked_m, 3.25);
        assert_eq!(back.first_sighting_s, Some(0.5));
        drop(journal);
        // The torn line is gone: reading it again keeps the same.
        let (_, again) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), true).expect("resumes");
        assert_eq!(again.len(), 2);

        let (journal, other) =
            EvalJournal::start(&trajectories, &settings("b"), &(5..9), true).expect("starts");
        assert!(other.is_empty(), "another policy's episodes are not kept");
        let (_, none) =
            EvalJournal::start(&trajectories, &settings("b"), &(5..9), false).expect("starts");
        assert!(none.is_empty());
        journal.finish().expect("removed");
        assert!(!path.exists());
        fs::remove_dir_all(dir).expect("clean up");
    }

    #[test]
    fn a_journal_of_other_camera_samples_is_not_kept_and_an_older_one_reads_as_four() {
        let dir = scratch("journal-samples");
        let trajectories = dir.join("t.json");
        let (mut journal, _) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), false).expect("starts");
        journal
            .append(&episode(5), Some("compiled"))
            .expect("appends");
        drop(journal);
        let one_sample = RunSettings {
            camera_samples: 1,
            ..settings("a")
        };
        let (_, kept) =
            EvalJournal::start(&trajectories, &one_sample, &(5..9), true).expect("starts");
        assert!(
            kept.is_empty(),
            "episodes seen with four samples are not one sample's"
        );

        // A journal written before the setting existed names no count: four.
        let mut older = serde_json::to_value(settings("a")).expect("json");
        older
            .as_object_mut()
            .expect("object")
            .remove("camera_samples");
        let path = journal_path(&trajectories);
        let line = episode_line(&episode(6), Some("compiled")).expect("line");
        fs::write(&path, format!("{older}\n{line}\n")).expect("older journal");
        let (_, kept) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), true).expect("resumes");
        assert_eq!(kept.len(), 1);
        fs::remove_dir_all(dir).expect("clean up");
    }

    #[test]
    fn an_episode_whose_controller_was_lost_is_played_again() {
        let dir = scratch("lost");
        let trajectories = dir.join("t.json");
        let (mut journal, _) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), true).expect("starts");
        let mut lost = episode(6);
        lost.outcome = Outcome::ControllerLost;
        lost.failure = Some("the controller did not answer tick 203 within 2s".to_owned());
        for result in [episode(5), lost, episode(7)] {
            journal.append(&result, Some("compiled")).expect("appends");
        }
        drop(journal);
        let (_, kept) =
            EvalJournal::start(&trajectories, &settings("a"), &(5..9), true).expect("resumes");
        let seeds: Vec<u64> = kept.iter().map(|(r, _)| r.setup.seed).collect();
        assert_eq!(seeds, [5, 7]);
        fs::remove_dir_all(dir).expect("clean up");
    }

    #[test]
    fn the_policy_hash_changes_with_any_network_byte() {
        let dir = scratch("hash");
        let shipped = crate::package_dir().join("models/policy/cnn");
        for name in ["policy.toml", "policy.onnx"] {
            fs::copy(shipped.join(name), dir.join(name)).expect("copy");
        }
        let manifest = dir.join("policy.toml");
        let before = RunSettings::policy_hash(&manifest).expect("hashes");
        assert_eq!(before.len(), 64);
        assert_eq!(before, RunSettings::policy_hash(&manifest).expect("hashes"));
        let network = dir.join("policy.onnx");
        let mut bytes = fs::read(&network).expect("read");
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        fs::write(&network, bytes).expect("write");
        assert_ne!(before, RunSettings::policy_hash(&manifest).expect("hashes"));
        fs::remove_dir_all(dir).expect("clean up");
    }
}
