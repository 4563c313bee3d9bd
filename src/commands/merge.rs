//! `dribble merge`: the shares of one recording or one evaluation, played apart (on the nodes
//! of a Ray cluster, `dribble_models.cluster`), put back together as one run of all their
//! seeds writes them: a dataset directory whose `dataset.json` and episode files are a serial
//! `dribble record`'s byte for byte, or a trajectories file that is a serial `dribble eval
//! --trajectories`'s, with its table, goal count and plot.
//!
//! The shares must agree on everything but their seeds (simulator, cameras, teacher, driver;
//! the engine, the conditions and the camera samples for an evaluation) and must not share a
//! seed; every episode file is checked against the hash its share recorded before it is
//! copied.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail, ensure};
use clap::{Args, Subcommand};
use dribble_sim::dataset::{DatasetIndex, Outcome};
use dribble_sim::runner::EpisodeResult;

use crate::evaluation::closed_loop::{print_header, print_row};
use crate::trajectories::file::{read_played_with, read_trajectories, write_trajectories};
use crate::trajectories::plot::{plot_trajectories, title};

#[derive(Debug, Args)]
pub struct MergeArgs {
    #[command(subcommand)]
    what: MergeWhat,
}

#[derive(Debug, Subcommand)]
enum MergeWhat {
    /// Dataset directories of `dribble record` into one (created, or one recorded with the
    /// same configuration, whose episodes are kept).
    Dataset {
        /// The merged dataset directory.
        #[arg(long)]
        out: PathBuf,
        /// The shares' dataset directories.
        #[arg(required = true)]
        shares: Vec<PathBuf>,
    },
    /// Trajectory files of `dribble eval --trajectories` into one, with the table, the goal
    /// count and the plot a serial run prints.
    Trajectories {
        /// The merged trajectories file.
        #[arg(long)]
        out: PathBuf,
        /// Where to draw the trajectory plot.
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Who drove, for the plot's title (`expert` or the policy's `policy.toml`).
        #[arg(long, default_value = "expert")]
        driver: String,
        /// The shares' trajectory files.
        #[arg(required = true)]
        shares: Vec<PathBuf>,
    },
}

pub fn run(args: &MergeArgs) -> anyhow::Result<()> {
    match &args.what {
        MergeWhat::Dataset { out, shares } => merge_datasets(out, shares),
        MergeWhat::Trajectories {
            out,
            plot,
            driver,
            shares,
        } => merge_trajectories(out, plot.as_deref(), driver, shares),
    }
}

/// What must be equal in every share for their episodes to be one dataset's.
fn configuration(index: &DatasetIndex) -> serde_json::Value {
    serde_json::json!({
        "format": index.format,
        "project_version": index.project_version,
        "simulator": index.simulator,
        "expert": index.expert,
        "driver": index.driver,
        "teacher": index.teacher.as_deref().unwrap_or("paper"),
        "conditions": index.conditions.as_deref().unwrap_or("clean"),
    })
}

fn merge_datasets(out: &Path, shares: &[PathBuf]) -> anyhow::Result<()> {
    let mut merged: Option<DatasetIndex> = DatasetIndex::load(out)?;
    if let Some(index) = &merged {
        index
            .verify(out)
            .with_context(|| format!("the dataset already in {}", out.display()))?;
    }
    let mut copies = Vec::new();
    for share in shares {
        let index = DatasetIndex::load(share)?
            .with_context(|| format!("{} holds no dataset.json", share.display()))?;
        index.verify(share)?;
        let target = merged.get_or_insert_with(|| DatasetIndex {
            episodes: Vec::new(),
            content_hash: None,
            ..index.clone()
        });
        ensure!(
            configuration(target) == configuration(&index),
            "{} was recorded with another configuration than the rest (simulator, cameras, \
             teacher or driver):\n  {}\n  {}",
            share.display(),
            configuration(target),
            configuration(&index)
        );
        for entry in &index.episodes {
            if target.episodes.iter().any(|e| e.seed == entry.seed) {
                bail!(
                    "episode {} is in {} and in another share (or already in {})",
                    entry.seed,
                    share.display(),
                    out.display()
                );
            }
            copies.push((share.join(&entry.file), out.join(&entry.file)));
            target.insert(entry.clone());
        }
    }
    let Some(merged) = merged else {
        bail!("nothing to merge");
    };
    fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    for (from, to) in &copies {
        fs::copy(from, to)
            .with_context(|| format!("copying {} to {}", from.display(), to.display()))?;
    }
    // The copies come from files checked against their hashes above; not read again.
    merged.save(out)?;
    let goals = merged
        .episodes
        .iter()
        .filter(|e| e.outcome == Outcome::Goal)
        .count();
    println!(
        "{}: {} episodes ({} from {} shares), {} goals, {} rows, content hash {}",
        out.join(DatasetIndex::FILE).display(),
        merged.episodes.len(),
        copies.len(),
        shares.len(),
        goals,
        merged.episodes.iter().map(|e| e.rows).sum::<usize>(),
        merged
            .compute_content_hash()
            .as_deref()
            .unwrap_or("(incomplete)")
    );
    Ok(())
}

fn merge_trajectories(
    out: &Path,
    plot: Option<&Path>,
    driver: &str,
    shares: &[PathBuf],
) -> anyhow::Result<()> {
    let mut results: Vec<EpisodeResult> = Vec::new();
    let mut played = Vec::new();
    for share in shares {
        let episodes = read_trajectories(share)?;
        for episode in &episodes {
            ensure!(
                !results.iter().any(|r| r.setup.seed == episode.setup.seed),
                "episode {} is in {} and in another share",
                episode.setup.seed,
                share.display()
            );
        }
        played.push(read_played_with(share)?);
        results.extend(episodes);
    }
    played.dedup();
    ensure!(
        played.len() == 1,
        "the shares ran different engines or camera samples: {played:?}"
    );
    // One run's conditions (a randomized run's draws differ by seed, its name does not).
    let mut conditions: Vec<String> = results
        .iter()
        .map(|r| r.setup.conditions.to_string())
        .collect();
    conditions.sort();
    conditions.dedup();
    ensure!(
        conditions.len() <= 1,
        "the shares ran under different conditions: {}",
        conditions.join(", ")
    );
    results.sort_by_key(|r| r.setup.seed);
    let played_with = played.pop().context("no share")?;
    write_trajectories(&results, &played_with, out)?;
    print_header();
    for result in &results {
        print_row(result);
    }
    let goals = results
        .iter()
        .filter(|r| r.outcome == Outcome::Goal)
        .count();
    if let Some(engine) = &played_with.engine {
        println!("engine: {engine}");
    }
    if !played_with.multisampling.is_default() {
        println!("camera samples: {}", played_with.multisampling);
    }
    let (low, high) = crate::evaluation::goal_rate::wilson_interval(goals, results.len());
    println!(
        "goals: {goals} of {} (95 % Wilson interval {low:.2}-{high:.2})",
        results.len()
    );
    if let Some(plot) = plot {
        plot_trajectories(&results, &title(driver, &results), plot)?;
        println!("trajectory plot: {}", plot.display());
    }
    println!("trajectories: {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-episode trajectories file of `seed` under `conditions` (absent: clean).
    fn share(dir: &Path, seed: u64, conditions: Option<&str>) -> PathBuf {
        let path = dir.join(format!("share-{seed}.json"));
        let mut file = serde_json::json!({"engine": "compiled (avx2+fma)", "episodes": [{
            "seed": seed, "outcome": "goal", "duration_s": 30.0, "computed_commands": 900,
            "failure": null, "robot": [[0.0, 0.0]], "ball": [[1.0, 0.0]]}]});
        if let Some(conditions) = conditions {
            // As `dribble eval` writes them: the run's, and each episode's.
            file["conditions"] = conditions.into();
            file["episodes"][0]["conditions"] = conditions.into();
        }
        fs::write(&path, file.to_string()).expect("written");
        path
    }

    #[test]
    fn shares_under_different_conditions_are_not_merged() {
        let dir = std::env::temp_dir().join(format!("dribble-merge-{}", std::process::id()));
        fs::create_dir_all(&dir).expect("dir");
        let out = dir.join("merged.json");
        let light = share(&dir, 30_000, Some("light:3"));
        let blur = share(&dir, 30_020, Some("motion-blur:3"));
        let error = merge_trajectories(&out, None, "expert", &[light.clone(), blur])
            .expect_err("different conditions");
        assert!(
            format!("{error:#}").contains("different conditions"),
            "{error:#}"
        );
        assert!(!out.exists());
        let clean = share(&dir, 30_040, None);
        assert!(merge_trajectories(&out, None, "expert", &[light.clone(), clean]).is_err());
        let more_light = share(&dir, 30_060, Some("light:3"));
        merge_trajectories(&out, None, "expert", &[light, more_light]).expect("one run's shares");
        let merged: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(&out).expect("read")).expect("json");
        assert_eq!(merged["conditions"], "light:3");
        assert_eq!(merged["episodes"].as_array().map(Vec::len), Some(2));
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn shares_of_different_camera_samples_are_not_merged() {
        let dir = std::env::temp_dir().join(format!("dribble-merge-ms-{}", std::process::id()));
        fs::create_dir_all(&dir).expect("dir");
        let out = dir.join("merged.json");
        let four = share(&dir, 30_000, None);
        let one = share(&dir, 30_020, None);
        let mut file: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(&one).expect("read")).expect("json");
        file["camera_samples"] = 1.into();
        fs::write(&one, file.to_string()).expect("written");
        let error = merge_trajectories(&out, None, "expert", &[four, one.clone()])
            .expect_err("different samples");
        assert!(format!("{error:#}").contains("camera samples"), "{error:#}");
        assert!(!out.exists());
        let another_one = share(&dir, 30_040, None);
        fs::write(&another_one, file.to_string().replace("30020", "30040")).expect("written");
        merge_trajectories(&out, None, "expert", &[one, another_one]).expect("one run's shares");
        let merged: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(&out).expect("read")).expect("json");
        assert_eq!(merged["camera_samples"], 1);
        let _ = fs::remove_dir_all(&dir);
    }
}
