//! What a recording keeps between runs: its dataset index, created or opened to resume (with
//! the configuration it was recorded under, which a resumed run must repeat), the episodes it
//! keeps and the report at the end.

use std::path::PathBuf;

use anyhow::ensure;
use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_sim::dataset::{DatasetIndex, EpisodeEntry, EpisodeRecording, episode_file};
use dribble_sim::expert::ExpertConfig;
use dribble_sim::runner::{EpisodeConfig, EpisodeResult};
use indicatif::{ProgressBar, ProgressStyle};

use crate::commands::record::RecordArgs;
use crate::evaluation::journal::RunSettings;

pub(crate) fn episode_progress(episodes: usize) -> ProgressBar {
    let progress = ProgressBar::new(episodes as u64);
    progress.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} episodes, {elapsed} elapsed, eta {eta}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    progress
}

/// One line per recorded episode.
pub(crate) fn announce(
    seed: u64,
    result: &EpisodeResult,
    recording: &EpisodeRecording,
    bytes: u64,
    policy_drove: bool,
) {
    let executed = if policy_drove {
        format!(
            ", expert's command executed {} of {} times",
            result.expert_executed,
            recording.rows()
        )
    } else {
        String::new()
    };
    println!(
        "episode {seed}: {} after {:.1} s, {} rows, {:.1} MB{executed}",
        result.outcome.name(),
        result.duration_s,
        recording.rows(),
        bytes as f64 / 1e6
    );
}

pub(crate) fn configuration(
    args: &RecordArgs,
    config: &EpisodeConfig,
    expert_config: &ExpertConfig,
    policy: Option<&(PathBuf, PolicyManifest)>,
) -> anyhow::Result<(
    serde_json::Value,
    serde_json::Value,
    Option<serde_json::Value>,
)> {
    let mut simulator = serde_json::json!({
        "world": format!("{:?}", config.world),
        "walk": format!("{:?}", config.walk),
        "cameras": serde_json::to_value(config.cameras)?,
        "control": format!("{:?}", config.control),
        "time_limit_s": config.time_limit_s,
    });
    if args.clean_twin {
        // Named only when on, so that datasets recorded before it resume as they were; a
        // resumed run must repeat it (every episode has the twin's thumbnails, or none).
        simulator["clean_twin"] =
            serde_json::json!("no camera effect or light; venue and robots kept");
    }
    if !config.multisampling.is_default() {
        // Named only when not the default four, as the clean twin is.
        simulator["camera_samples"] = config.multisampling.samples().into();
    }
    let expert = serde_json::json!(format!("{expert_config:?}"));
    let driver = policy
        .map(|(path, manifest)| driver_record(args, path, manifest))
        .transpose()?;
    Ok((simulator, expert, driver))
}

/// Who drove a policy-driven recording. A closed loop's states are a function of the engine's
/// arithmetic too (each instruction set adds up in its own order), so the record names the
/// network's bytes, the engine and the instruction set besides the mixing rule: a round
/// recorded again reproduces its hash only where all of them are the same.
fn driver_record(
    args: &RecordArgs,
    path: &std::path::Path,
    manifest: &PolicyManifest,
) -> anyhow::Result<serde_json::Value> {
    let engine = args.controller.engine_options();
    Ok(serde_json::json!({
        "policy": path.display().to_string(),
        "policy_hash": RunSettings::policy_hash(path)?,
        "engine": engine.engine.name(),
        "isa": engine.instruction_set().map(Isa::name),
        "kind": manifest.kind.to_string(),
        "trained_on": manifest.training.dataset,
        "dataset_hash": manifest.training.dataset_hash,
        "label_with": "expert",
        "beta": args.beta,
        "mixing": "per computed command, the expert's command is executed with probability \
                   beta (held until the next computed command); draws seeded by the episode",
    }))
}

/// Writes the episode's file and lists it in the index (saved at once, so that an
/// interrupted recording keeps it); returns the file's size.
pub(crate) fn keep_episode(
    args: &RecordArgs,
    index: &mut DatasetIndex,
    seed: u64,
    result: &EpisodeResult,
    recording: &EpisodeRecording,
) -> anyhow::Result<u64> {
    let file = episode_file(seed);
    let (bytes, sha256) = recording.write(&args.out.join(&file))?;
    index.insert(EpisodeEntry {
        seed,
        file,
        outcome: result.outcome,
        rows: recording.rows(),
        duration_s: f64::from(result.duration_s),
        bytes,
        sha256: Some(sha256),
        conditions: (!args.condition.is_clean())
            .then(|| args.condition.for_episode(seed).to_string()),
    });
    index.save(&args.out)?;
    Ok(bytes)
}

/// The dataset's index: the one in `args.out` when its simulator, expert, driver and teacher
/// are this run's (resuming), or a new one.
pub(crate) fn open_index(
    args: &RecordArgs,
    simulator: serde_json::Value,
    expert: serde_json::Value,
    driver: Option<serde_json::Value>,
) -> anyhow::Result<DatasetIndex> {
    Ok(match DatasetIndex::load(&args.out)? {
        Some(index) => {
            // Resuming: the new episodes must come from the same simulator and expert.
            let mut differences = Vec::new();
            let recorded_teacher = index.teacher.as_deref().unwrap_or("paper");
            if recorded_teacher != args.teacher.name() {
                differences.push(format!(
                    "teacher: {recorded_teacher} there, {} now",
                    args.teacher
                ));
            }
            let recorded_conditions = index.conditions.as_deref().unwrap_or("clean");
            if recorded_conditions != args.condition.to_string() {
                differences.push(format!(
                    "conditions: {recorded_conditions} there, {} now",
                    args.condition
                ));
            }
            config_differences("", &index.simulator, &simulator, &mut differences);
            config_differences("expert", &index.expert, &expert, &mut differences);
            let recorded_driver = index.driver.clone().unwrap_or_default();
            let driver_now = driver.clone().unwrap_or_default();
            config_differences("driver", &recorded_driver, &driver_now, &mut differences);
            ensure!(
                differences.is_empty(),
                "{} was recorded with another simulator, camera or expert configuration \
                 ({}); record into a new directory",
                args.out.display(),
                differences.join("; ")
            );
            index
        }
        None => DatasetIndex {
            format: 1,
            project_version: env!("CARGO_PKG_VERSION").into(),
            simulator,
            expert,
            episodes: Vec::new(),
            content_hash: None,
            driver,
            teacher: Some(args.teacher.name().into()),
            conditions: (!args.condition.is_clean()).then(|| args.condition.to_string()),
        },
    })
}

/// Saves the index if this run changed it and prints what the dataset holds.
pub(crate) fn report_dataset(
    args: &RecordArgs,
    index: &mut DatasetIndex,
    recorded: bool,
) -> anyhow::Result<()> {
    let goals = index
        .episodes
        .iter()
        .filter(|e| e.outcome == dribble_sim::dataset::Outcome::Goal)
        .count();
    // Saved only when something changed, so that a finished dataset's index keeps its time.
    if recorded || index.content_hash != index.compute_content_hash() {
        index.save(&args.out)?;
    }
    println!(
        "{}: {} episodes, {} goals, {} rows, content hash {}",
        args.out.join(DatasetIndex::FILE).display(),
        index.episodes.len(),
        goals,
        index.episodes.iter().map(|e| e.rows).sum::<usize>(),
        index
            .compute_content_hash()
            .as_deref()
            .unwrap_or("(incomplete)")
    );
    Ok(())
}

/// Where two recorded configurations differ, one `path: recorded A, now B` per leaf.
pub(crate) fn config_differences(
    path: &str,
    recorded: &serde_json::Value,
    now: &serde_json::Value,
    out: &mut Vec<String>,
) {
    use serde_json::Value;
    match (recorded, now) {
        (Value::Object(a), Value::Object(b)) => {
            let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
            keys.sort();
            keys.dedup();
            for key in keys {
                let child = if path.is_empty() {
                    key.clone()
                } else {
                    format!("{path}.{key}")
                };
                let missing = Value::Null;
                config_differences(
                    &child,
                    a.get(key).unwrap_or(&missing),
                    b.get(key).unwrap_or(&missing),
                    out,
                );
            }
        }
        (a, b) if a != b => out.push(format!("{path}: recorded {a}, now {b}")),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Command {
        #[command(flatten)]
        record: RecordArgs,
    }

    fn record_args(extra: &[&str], out: &std::path::Path) -> RecordArgs {
        let policy = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/models/fixtures/cnn/policy.toml"
        );
        let out = out.to_str().expect("utf-8 path");
        let mut words = vec!["record", "--driver", policy, "--label-with", "teacher"];
        words.extend_from_slice(&["--beta", "0.5", "--out", out]);
        words.extend_from_slice(extra);
        Command::parse_from(words).record
    }

    fn driver_of(args: &RecordArgs) -> serde_json::Value {
        let path = PathBuf::from(&args.driver);
        let manifest = PolicyManifest::load(&path).expect("the fixture loads");
        let (_, _, driver) = configuration(
            args,
            &EpisodeConfig::default(),
            &ExpertConfig::default(),
            Some(&(path, manifest)),
        )
        .expect("a configuration");
        driver.expect("a policy drove")
    }

    #[test]
    fn a_policy_driven_recording_names_the_network_engine_and_instruction_set() {
        let out =
            std::env::temp_dir().join(format!("dribble-driver-record-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let portable = record_args(&["--isa", "portable"], &out);
        let driver = driver_of(&portable);
        assert_eq!(driver["engine"], "compiled");
        assert_eq!(driver["isa"], "portable");
        let hash = driver["policy_hash"].as_str().expect("a hash");
        assert_eq!(hash.len(), 64, "{hash}");
        let tract = driver_of(&record_args(&["--engine", "tract"], &out));
        assert_eq!(tract["engine"], "tract");
        assert!(tract["isa"].is_null(), "tract chooses no instruction set");
        let widest = driver_of(&record_args(&[], &out));
        assert_eq!(
            widest["isa"],
            Isa::detect().name(),
            "the widest this CPU runs"
        );

        // A round recorded on one instruction set is not resumed on another.
        std::fs::create_dir_all(&out).expect("scratch");
        let (simulator, expert, _) = configuration(
            &portable,
            &EpisodeConfig::default(),
            &ExpertConfig::default(),
            None,
        )
        .expect("a configuration");
        let index = open_index(&portable, simulator.clone(), expert.clone(), Some(driver))
            .expect("a new index");
        index.save(&out).expect("saved");
        let sse2 = record_args(&["--isa", "sse2"], &out);
        let refused = open_index(&sse2, simulator, expert, Some(driver_of(&sse2)))
            .expect_err("another instruction set");
        assert!(refused.to_string().contains("driver.isa"), "{refused}");
        let _ = std::fs::remove_dir_all(&out);
    }
}
