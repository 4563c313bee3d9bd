//! `dribble plot`: the trajectory figure drawn again from the JSON that `dribble eval
//! --trajectories` wrote, without playing the episodes again (a closed-loop evaluation of
//! twenty episodes takes minutes to an hour; a figure takes a second). Each episode's start
//! is its seed's ([`EpisodeSetup::from_seed`]), as in the run that wrote the file.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use dribble_controller::tick_stats::TickStats;
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::runner::EpisodeResult;
use glam::Vec2;
use serde::Deserialize;

use crate::trajectory_plot::{plot_trajectories, title};

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The JSON written by `dribble eval --trajectories`.
    #[arg(long)]
    trajectories: PathBuf,
    /// Where to write the figure (PNG).
    #[arg(long, default_value = "eval_trajectories.png")]
    plot: PathBuf,
    /// Who drove, for the title: the driver given to `dribble eval` (`expert`, or the
    /// policy's `policy.toml`). The JSON does not record it.
    #[arg(long)]
    driver: String,
}

/// One episode as `dribble eval --trajectories` writes it.
#[derive(Debug, Deserialize)]
struct RecordedEpisode {
    seed: u64,
    outcome: Outcome,
    duration_s: f32,
    computed_commands: u64,
    failure: Option<String>,
    robot: Vec<[f32; 2]>,
    ball: Vec<[f32; 2]>,
}

#[derive(Debug, Deserialize)]
struct RecordedEvaluation {
    episodes: Vec<RecordedEpisode>,
}

pub fn run(args: &PlotArgs) -> anyhow::Result<()> {
    let results = read_trajectories(&args.trajectories)?;
    let goals = results
        .iter()
        .filter(|r| r.outcome == Outcome::Goal)
        .count();
    plot_trajectories(&results, &title(&args.driver, &results), &args.plot)?;
    println!(
        "{goals} of {} goals; trajectory plot: {}",
        results.len(),
        args.plot.display()
    );
    Ok(())
}

/// The episodes of a trajectories file, as results to plot.
fn read_trajectories(path: &Path) -> anyhow::Result<Vec<EpisodeResult>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_trajectories(&text).with_context(|| {
        format!(
            "{} is not a trajectories file of `dribble eval --trajectories`",
            path.display()
        )
    })
}

/// What the file does not keep, the distance walked and the tick times, is left empty.
fn parse_trajectories(text: &str) -> anyhow::Result<Vec<EpisodeResult>> {
    let recorded: RecordedEvaluation = serde_json::from_str(text)?;
    if recorded.episodes.is_empty() {
        bail!("it holds no episodes");
    }
    let points = |points: &[[f32; 2]]| points.iter().map(|&[x, y]| Vec2::new(x, y)).collect();
    Ok(recorded
        .episodes
        .into_iter()
        .map(|episode| EpisodeResult {
            setup: EpisodeSetup::from_seed(episode.seed),
            outcome: episode.outcome,
            duration_s: episode.duration_s,
            distance_walked_m: 0.0,
            robot_path: points(&episode.robot),
            ball_path: points(&episode.ball),
            computed_commands: episode.computed_commands,
            tick_times: TickStats::new(std::time::Duration::from_millis(10)),
            failure: episode.failure,
            expert_executed: 0,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn episodes_come_back_with_their_seeds_starts() {
        let results = parse_trajectories(
            r#"{"engine": "compiled (avx2+fma)", "episodes": [
                {"seed": 10003, "outcome": "goal", "duration_s": 41.5, "computed_commands": 1200,
                 "failure": null, "robot": [[0.5, 1.0], [0.6, 1.1]], "ball": [[2.0, -1.0]]}]}"#,
        )
        .expect("parses");
        assert_eq!(results.len(), 1);
        let result = &results[0];
        assert_eq!(result.setup, EpisodeSetup::from_seed(10_003));
        assert_eq!(result.outcome, Outcome::Goal);
        assert_eq!(result.duration_s, 41.5);
        assert_eq!(
            result.robot_path,
            vec![Vec2::new(0.5, 1.0), Vec2::new(0.6, 1.1)]
        );
        assert_eq!(result.ball_path, vec![Vec2::new(2.0, -1.0)]);
        assert_eq!(
            title("expert", &results),
            "the scripted expert: 1 of 1 goals, seeds 10003..10003"
        );
    }

    #[test]
    fn a_file_that_is_not_one_is_refused_with_its_name() {
        let path = std::env::temp_dir().join(format!("dribble-plot-{}.json", std::process::id()));
        for text in ["{\"episodes\": []}", "[1, 2]", "not json"] {
            std::fs::write(&path, text).expect("written");
            let error = format!("{:#}", read_trajectories(&path).expect_err(text));
            assert!(error.contains(&path.display().to_string()), "{error}");
        }
        let _ = std::fs::remove_file(&path);
    }
}
