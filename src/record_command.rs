//! `dribble record`: the expert plays episodes while both cameras are rendered; every
//! computed command is stored with the thumbnails it was computed from.

use std::fs;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, ensure};
use clap::Args;
use dribble_sim::dataset::{DatasetIndex, EpisodeEntry, EpisodeRecording, episode_file};
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, run_episode};
use indicatif::{ProgressBar, ProgressStyle};

use crate::episodes::Episodes;

#[derive(Debug, Args)]
pub struct RecordArgs {
    /// `train` (seeds 0..99), `test` (10000..10019) or a seed range such as `0..10`.
    #[arg(long, default_value = "train")]
    episodes: Episodes,
    /// Dataset directory: one `episode_SEED.npz` per episode and `dataset.json`. Episodes
    /// already there are kept and skipped, so an interrupted recording resumes.
    #[arg(long, default_value = "dataset")]
    out: PathBuf,
    /// Time limit per episode, simulated seconds.
    #[arg(long, default_value_t = 90.0)]
    time_limit: f32,
}

pub fn run(args: &RecordArgs) -> anyhow::Result<()> {
    fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        ..EpisodeConfig::default()
    };
    let expert_config = ExpertConfig::default();
    let simulator = serde_json::json!({
        "world": format!("{:?}", config.world),
        "walk": format!("{:?}", config.walk),
        "cameras": serde_json::to_value(config.cameras)?,
        "control": format!("{:?}", config.control),
        "time_limit_s": config.time_limit_s,
    });
    let expert = serde_json::json!(format!("{expert_config:?}"));
    let mut index = match DatasetIndex::load(&args.out)? {
        Some(index) => {
            // Resuming: the new episodes must come from the same simulator and expert.
            let mut differences = Vec::new();
            config_differences("", &index.simulator, &simulator, &mut differences);
            config_differences("expert", &index.expert, &expert, &mut differences);
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
        },
    };
    let done = |seed: u64| {
        index
            .episodes
            .iter()
            .any(|e| e.seed == seed && args.out.join(&e.file).is_file())
    };
    let todo: Vec<u64> = args.episodes.0.clone().filter(|&s| !done(s)).collect();
    let skipped = args.episodes.0.clone().count() - todo.len();
    if skipped > 0 {
        println!(
            "{skipped} episode(s) already recorded in {}, kept",
            args.out.display()
        );
    }
    let mut renderer = Renderer::new(
        &FieldGeometry::SPL,
        config.world.goal_depth,
        &config.cameras,
    )?;
    println!("adapter: {}", renderer.adapter());

    let progress = ProgressBar::new(todo.len() as u64);
    progress.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} episodes, {elapsed} elapsed, eta {eta}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let started = Instant::now();
    let (mut simulated, mut bytes_written) = (0.0f64, 0u64);
    for seed in todo.iter().copied() {
        progress.set_message(format!("seed {seed}"));
        let setup = EpisodeSetup::from_seed(seed);
        let mut recording = EpisodeRecording::default();
        let expert = Expert::new(expert_config, FieldGeometry::SPL);
        let result = run_episode(
            &setup,
            &config,
            Driver::Expert(expert),
            Some(&mut renderer),
            Some(&mut recording),
        )
        .with_context(|| format!("episode {seed}"))?;
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
        });
        index.save(&args.out)?;
        simulated += f64::from(result.duration_s);
        bytes_written += bytes;
        progress.suspend(|| {
            println!(
                "episode {seed}: {} after {:.1} s, {} rows, {:.1} MB",
                result.outcome.name(),
                result.duration_s,
                recording.rows(),
                bytes as f64 / 1e6
            )
        });
        progress.inc(1);
    }
    progress.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();
    if !todo.is_empty() {
        println!(
            "recorded {} episodes in {:.1} s: {:.1} episodes per minute, {:.1} simulated seconds per wall second, {:.1} MB",
            todo.len(),
            wall,
            todo.len() as f64 / wall * 60.0,
            simulated / wall,
            bytes_written as f64 / 1e6
        );
    }
    let goals = index
        .episodes
        .iter()
        .filter(|e| e.outcome == dribble_sim::dataset::Outcome::Goal)
        .count();
    index.save(&args.out)?;
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
fn config_differences(
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
