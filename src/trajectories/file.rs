//! The trajectories file of `dribble eval --trajectories`: every episode's outcome and 10 Hz
//! robot and ball paths as JSON, with the engine that ran the policy (`null` for the expert,
//! or a controller the run joined). Written by `eval`, read back by `dribble plot`; one
//! definition for both, so that they cannot drift apart. (Fields in alphabetical order and
//! the simulator's `f32`s widened to `f64`: the files come out byte for byte as they did when
//! `serde_json::json!` wrote them, with `first_sighting_s`, `heading` and `walked_m` added since.)

use std::path::Path;

use anyhow::{Context, bail};
use dribble_controller::tick_stats::TickStats;
use dribble_sim::conditions::Conditions;
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::render::Multisampling;
use dribble_sim::runner::EpisodeResult;
use glam::Vec2;
use serde::{Deserialize, Serialize};

#[derive(Debug, Deserialize, Serialize)]
struct RecordedEpisode {
    ball: Vec<[f64; 2]>,
    computed_commands: u64,
    /// The run's conditions, when not clean (`randomized`, or NAME:SEVERITY[,...]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    conditions: Option<String>,
    /// In a randomized run, the conditions this episode drew from its seed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    drawn_conditions: Option<String>,
    duration_s: f64,
    failure: Option<String>,
    /// When the ball was first inside either image, s (absent: never, or an older file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    first_sighting_s: Option<f64>,
    /// The robot's heading at each `robot` point, radians (absent in older files).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    heading: Vec<f64>,
    outcome: Outcome,
    robot: Vec<[f64; 2]>,
    seed: u64,
    /// Absent in files written before it was kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    walked_m: Option<f64>,
}

#[derive(Debug, Deserialize, Serialize)]
struct RecordedEvaluation {
    /// Samples a pixel of the cameras' images (`dribble eval --camera-samples`), absent when
    /// 4 (every file written before the setting existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera_samples: Option<u32>,
    /// The run's conditions (`dribble eval --condition`), absent when clean.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    conditions: Option<String>,
    engine: Option<String>,
    episodes: Vec<RecordedEpisode>,
}

/// How a trajectories file's episodes were played besides their seeds and conditions: what
/// the shares of one run must agree on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlayedWith {
    /// The engine that ran the policy (`None`: the expert, or a controller the run joined).
    pub engine: Option<String>,
    /// Samples a pixel of the cameras' images.
    pub multisampling: Multisampling,
}

/// Writes `results`, played as `played_with` says, to `path`.
pub fn write_trajectories(
    results: &[EpisodeResult],
    played_with: &PlayedWith,
    path: &Path,
) -> anyhow::Result<()> {
    let conditions = results
        .first()
        .map(|r| r.setup.conditions)
        .filter(|c| !c.is_clean())
        .map(|c| c.to_string());
    let multisampling = played_with.multisampling;
    let recorded = RecordedEvaluation {
        camera_samples: (!multisampling.is_default()).then(|| multisampling.samples()),
        conditions,
        engine: played_with.engine.clone(),
        episodes: results.iter().map(recorded_episode).collect(),
    };
    let text = serde_json::to_string(&recorded)?;
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// One episode and the engine that ran it as one line of JSON (no newline): what
/// [`crate::evaluation::journal`] appends as each episode ends. It keeps what the trajectories file
/// keeps, exactly, so that a file written from lines read back is the one an uninterrupted
/// run writes.
pub fn episode_line(result: &EpisodeResult, engine: Option<&str>) -> anyhow::Result<String> {
    Ok(serde_json::to_string(&JournalLine {
        engine: engine.map(str::to_owned),
        episode: recorded_episode(result),
    })?)
}

/// An [`episode_line`] read back: the episode and its engine.
pub fn parse_episode_line(line: &str) -> anyhow::Result<(EpisodeResult, Option<String>)> {
    let line: JournalLine = serde_json::from_str(line)?;
    Ok((episode_result(line.episode), line.engine))
}

#[derive(Debug, Deserialize, Serialize)]
struct JournalLine {
    engine: Option<String>,
    episode: RecordedEpisode,
}

fn recorded_episode(result: &EpisodeResult) -> RecordedEpisode {
    let points = |path: &[Vec2]| path.iter().map(|p| [p.x.into(), p.y.into()]).collect();
    RecordedEpisode {
        ball: points(&result.ball_path),
        computed_commands: result.computed_commands,
        conditions: (!result.setup.conditions.is_clean())
            .then(|| result.setup.conditions.to_string()),
        drawn_conditions: result.setup.conditions.is_randomized().then(|| {
            result
                .setup
                .conditions
                .for_episode(result.setup.seed)
                .to_string()
        }),
        duration_s: result.duration_s.into(),
        failure: result.failure.clone(),
        first_sighting_s: result.first_sighting_s.map(f64::from),
        heading: result.heading_path.iter().map(|&h| h.into()).collect(),
        outcome: result.outcome,
        robot: points(&result.robot_path),
        seed: result.setup.seed,
        walked_m: Some(result.distance_walked_m.into()),
    }
}

/// What the file does not keep, the tick times (and the distance walked in older files), is
/// left empty; the start is the seed's.
fn episode_result(episode: RecordedEpisode) -> EpisodeResult {
    let conditions = episode
        .conditions
        .as_deref()
        .and_then(|text| text.parse::<Conditions>().ok())
        .unwrap_or(Conditions::CLEAN);
    let points = |points: &[[f64; 2]]| {
        points
            .iter()
            .map(|&[x, y]| Vec2::new(x as f32, y as f32))
            .collect()
    };
    EpisodeResult {
        setup: EpisodeSetup::from_seed(episode.seed).under(conditions),
        outcome: episode.outcome,
        duration_s: episode.duration_s as f32,
        distance_walked_m: episode.walked_m.unwrap_or(0.0) as f32,
        robot_path: points(&episode.robot),
        ball_path: points(&episode.ball),
        heading_path: episode.heading.iter().map(|&h| h as f32).collect(),
        first_sighting_s: episode.first_sighting_s.map(|s| s as f32),
        computed_commands: episode.computed_commands,
        tick_times: TickStats::new(std::time::Duration::from_millis(10)),
        failure: episode.failure,
        expert_executed: 0,
    }
}

/// The episodes of a trajectories file, as results to plot; each episode's start is its
/// seed's ([`EpisodeSetup::from_seed`]), as in the run that wrote the file.
pub fn read_trajectories(path: &Path) -> anyhow::Result<Vec<EpisodeResult>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_trajectories(&text).with_context(|| {
        format!(
            "{} is not a trajectories file of `dribble eval --trajectories`",
            path.display()
        )
    })
}

/// The engine and the camera samples a trajectories file names.
pub fn read_played_with(path: &Path) -> anyhow::Result<PlayedWith> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let recorded: RecordedEvaluation = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a trajectories file", path.display()))?;
    let multisampling = match recorded.camera_samples {
        None => Multisampling::Four,
        Some(samples) => Multisampling::try_from(samples)
            .with_context(|| format!("{} names camera samples", path.display()))?,
    };
    Ok(PlayedWith {
        engine: recorded.engine,
        multisampling,
    })
}

/// Every episode of the file, in its order ([`episode_result`]).
fn parse_trajectories(text: &str) -> anyhow::Result<Vec<EpisodeResult>> {
    let recorded: RecordedEvaluation = serde_json::from_str(text)?;
    if recorded.episodes.is_empty() {
        bail!("it holds no episodes");
    }
    Ok(recorded.episodes.into_iter().map(episode_result).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectories::plot::title;

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
            "the scripted expert: 1 of 1 goals (0.21-1.00), seeds 10003..10003"
        );
    }

    #[test]
    fn what_is_written_reads_back_and_is_what_json_macro_wrote() {
        let path = std::env::temp_dir().join(format!("dribble-traj-{}.json", std::process::id()));
        let mut results = parse_trajectories(
            r#"{"engine": null, "episodes": [{"seed": 7, "outcome": "ball_out", "duration_s": 3.0,
                "computed_commands": 90, "failure": null, "robot": [[0.0, 0.0]], "ball": [[1.0, 2.0]]}]}"#,
        )
        .expect("parses");
        results[0].robot_path = vec![Vec2::new(0.1, -2.6696692)];
        results[0].distance_walked_m = 1.25;
        let four = PlayedWith {
            engine: Some("compiled (avx2+fma)".to_owned()),
            multisampling: Multisampling::Four,
        };
        write_trajectories(&results, &four, &path).expect("written");
        let text = std::fs::read_to_string(&path).expect("read");
        assert_eq!(
            text,
            serde_json::json!({"engine": "compiled (avx2+fma)", "episodes": [{
                "seed": 7u64, "outcome": Outcome::BallOut, "duration_s": 3.0f32,
                "computed_commands": 90u64, "failure": null,
                "robot": [[0.1f32, -2.6696692f32]], "ball": [[1.0f32, 2.0f32]],
                "walked_m": 1.25f32}]})
            .to_string()
        );
        let back = read_trajectories(&path).expect("reads");
        assert_eq!(back[0].robot_path, results[0].robot_path);
        assert_eq!(back[0].distance_walked_m, 1.25);
        assert_eq!(read_played_with(&path).expect("reads"), four);

        // One sample a pixel is named, and read back.
        let one = PlayedWith {
            multisampling: Multisampling::One,
            ..four
        };
        write_trajectories(&results, &one, &path).expect("written");
        let written: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
        assert_eq!(written["camera_samples"], 1);
        assert_eq!(read_played_with(&path).expect("reads"), one);
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn conditions_come_back_as_the_run_named_them() {
        let path = std::env::temp_dir().join(format!("dribble-cond-{}.json", std::process::id()));
        for text in ["noise:3", "randomized"] {
            let conditions: Conditions = text.parse().expect("parses");
            let mut results = parse_trajectories(
                r#"{"engine": null, "episodes": [{"seed": 7, "outcome": "goal", "duration_s": 3.0,
                    "computed_commands": 90, "failure": null, "robot": [[0.0, 0.0]], "ball": [[1.0, 2.0]]}]}"#,
            )
            .expect("parses");
            results[0].setup = results[0].setup.under(conditions);
            let played_with = PlayedWith {
                engine: None,
                multisampling: Multisampling::Four,
            };
            write_trajectories(&results, &played_with, &path).expect("written");
            let written: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
            assert_eq!(written["conditions"], text);
            assert_eq!(
                written["episodes"][0].get("drawn_conditions").is_some(),
                text == "randomized"
            );
            let back = read_trajectories(&path).expect("reads");
            assert_eq!(back[0].setup.conditions, conditions);
            // A journal line carries them too, so a resumed or merged run names them again.
            let line = episode_line(&back[0], None).expect("line");
            assert_eq!(
                parse_episode_line(&line).expect("parses").0.setup,
                back[0].setup
            );
        }
        let _ = std::fs::remove_file(&path);
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
