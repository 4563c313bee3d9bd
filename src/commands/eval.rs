//! `dribble eval`: a driver plays episodes in closed loop; a table, the goal count, the
//! controller's latency and a trajectory plot come out.
//!
//! A learned policy runs in the controller, in lock-step with the simulator: by default
//! the `dribble-controller` process over iceoryx2 shared memory (started here unless one
//! already runs in the domain), or with `--transport in-process` the same controller code
//! in a thread over channels. The scripted expert reads ground truth, so it always runs
//! inside the simulator.

use std::path::{Path, PathBuf};

use clap::Args;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_sim::conditions::Conditions;
use dribble_sim::dataset::Outcome;
use dribble_sim::render::Multisampling;
use dribble_sim::runner::{EpisodeConfig, EpisodeResult};

use crate::controller_session::ControllerOptions;
use crate::episodes::Episodes;
use crate::evaluation::closed_loop::{Played, play_here, print_header, print_row, report};
use crate::evaluation::jobs::{JobPlan, play};
use crate::evaluation::journal::{EvalJournal, RunSettings};
use crate::foxglove_episodes::FoxgloveArgs;
use dribble_sim::expert::Teacher;

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// `teacher` for the scripted teacher that `--teacher` names (`expert` is accepted for
    /// the same), or the path of a policy's `policy.toml` (it sees the rendered cameras).
    #[arg(long, default_value = crate::episodes::TEACHER_DRIVER)]
    pub(crate) driver: String,
    /// `test` (seeds 10000..10019), `train` (0..99) or a seed range such as `10000..10005`.
    #[arg(long, default_value = "test")]
    pub(crate) episodes: Episodes,
    /// What the cameras see the episodes under: `clean` (the paper's render), one condition
    /// or several as NAME:SEVERITY[,NAME:SEVERITY...] with severities 1 (slight) to 5
    /// (harsh), e.g. `noise:3` or `light:2,venue:4`, or `randomized` (each episode draws
    /// its own from its seed, as training does). Names: exposure, contrast, noise,
    /// white-balance, motion-blur, lens, light, venue, unseen-venue, robots. Written into
    /// the trajectories file.
    #[arg(long, visible_alias = "conditions", default_value = "clean")]
    pub(crate) condition: Conditions,
    /// Samples a pixel of the cameras' images: 4 (the paper's render and every shipped
    /// result's) or 1 (a clean episode in about two fifths of the CPU time on lavapipe,
    /// models/performance/episode-rate.md; frames differ along object edges). Written into
    /// the trajectories file when not 4; a journal or share of the other count is not merged
    /// with this run.
    #[arg(long, default_value_t = Multisampling::Four)]
    pub(crate) camera_samples: Multisampling,
    /// Where to write the trajectory plot.
    #[arg(long, default_value = "eval_trajectories.png")]
    pub(crate) plot: PathBuf,
    /// Also write every episode's outcome and robot and ball paths (10 Hz) as JSON.
    #[arg(long)]
    pub(crate) trajectories: Option<PathBuf>,
    /// Render the cameras even for the teacher (slower; it does not look at them).
    #[arg(long)]
    pub(crate) render: bool,
    /// Which teacher `--driver teacher` is: `paper` (reads the ball's true position),
    /// `observable` (knows the ball only while a camera shows it, and where it last saw it),
    /// `orbit` (the observable one, which also walks straight to the ball and circles it to the
    /// left until the top camera shows the target goal), `detector` (the observable one seeing
    /// the ball only where enough of it is unoccluded in an image) or `detector-one-way` (the
    /// detector one, going around the ball always clockwise where it must go around it).
    #[arg(long, alias = "expert", default_value_t = Teacher::Paper)]
    pub(crate) teacher: Teacher,
    /// Time limit per episode, simulated seconds (positive and finite).
    #[arg(long, default_value_t = 90.0, value_parser = crate::episodes::time_limit)]
    pub(crate) time_limit: f32,
    /// Play the episodes in this many processes at once, each with its own simulator,
    /// controller and iceoryx2 domain (`<domain>-job<k>`); the table, plot and trajectories
    /// are merged in seed order and the outcomes are a serial run's. About one job per core.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub(crate) jobs: u16,
    /// Continue a run that was cut off (a session's end, a killed job): keep the episodes
    /// its journal `TRAJECTORIES.partial` holds for the same settings (policy files, teacher,
    /// time limit, engine, instruction set, transport) and play only the rest (and, once
    /// more, any whose controller was lost); the files come out as an uninterrupted run's. Needs
    /// --trajectories. Every run with --trajectories keeps that journal while it runs (with
    /// --jobs, in `TRAJECTORIES.jobs/`).
    #[arg(long, requires = "trajectories")]
    pub(crate) resume: bool,
    /// Set by a parent run for its --jobs children: keep the journal when done (the parent
    /// removes it with its other scratch files once the merged file is written).
    #[arg(long, hide = true)]
    pub(crate) keep_journal: bool,
    #[command(flatten)]
    pub(crate) controller: ControllerOptions,
    #[command(flatten)]
    pub(crate) foxglove: FoxgloveArgs,
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        multisampling: args.camera_samples,
        ..EpisodeConfig::default()
    };
    let policy_path =
        (!crate::episodes::is_teacher_driver(&args.driver)).then(|| PathBuf::from(&args.driver));
    describe_driver(args, policy_path.as_deref())?;
    if !args.condition.is_clean() {
        println!("conditions: {}", args.condition);
    }
    if !args.camera_samples.is_default() {
        println!("camera samples: {}", args.camera_samples);
    }
    let seeds = args.episodes.0.clone();
    if args.jobs > 1 && seeds.end - seeds.start > 1 {
        return run_in_jobs(args, seeds, policy_path.is_some());
    }
    let mut journal = match &args.trajectories {
        Some(path) => {
            let settings = run_settings(args, policy_path.as_deref())?;
            Some(EvalJournal::start(path, &settings, &seeds, args.resume)?)
        }
        None => None,
    };
    let played = play_here(
        args,
        &config,
        policy_path.as_deref(),
        journal
            .as_mut()
            .map(|(journal, kept)| (journal, std::mem::take(kept))),
    )?;
    report(args, policy_path.is_some(), &played)?;
    if let Some((journal, _)) = journal
        && !args.keep_journal
    {
        refuse_lost_controllers(&played.results)?;
        journal.finish()?;
    }
    Ok(())
}

/// With a journal: an episode whose controller was lost says nothing of the policy, so the
/// run does not end as if it were done; the journal stays and `--resume` plays it again.
fn refuse_lost_controllers(results: &[EpisodeResult]) -> anyhow::Result<()> {
    let lost: Vec<String> = results
        .iter()
        .filter(|r| r.outcome == Outcome::ControllerLost)
        .map(|r| r.setup.seed.to_string())
        .collect();
    anyhow::ensure!(
        lost.is_empty(),
        "seeds {} lost their controller: the journal is kept; run the same command with \
         --resume to play them again",
        lost.join(", ")
    );
    Ok(())
}

/// `--jobs N`: children play the shards, their files are merged here.
fn run_in_jobs(args: &EvalArgs, seeds: std::ops::Range<u64>, policy: bool) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.foxglove.live.is_none(),
        "--live serves one run: leave out --jobs"
    );
    let arguments: Vec<String> = std::env::args()
        .skip_while(|argument| argument != "eval")
        .skip(1)
        .collect();
    let domain = args
        .controller
        .domain
        .clone()
        .or_else(|| std::env::var("DRIBBLE_DOMAIN").ok())
        .unwrap_or_else(|| format!("dribble-eval-{}", std::process::id()));
    // Beside the trajectories file when there is one, so that a cut run's jobs resume.
    let scratch = match &args.trajectories {
        Some(path) => {
            let mut name = path.as_os_str().to_owned();
            name.push(".jobs");
            PathBuf::from(name)
        }
        None => std::env::temp_dir().join(format!("dribble-eval-jobs-{}", std::process::id())),
    };
    let plan = JobPlan {
        seeds,
        jobs: usize::from(args.jobs),
        arguments: &arguments,
        domain,
        controller_log: &args.controller.controller_log,
        scratch: scratch.clone(),
    };
    let (results, engine) = play(&plan)?;
    println!();
    print_header();
    for result in &results {
        print_row(result);
    }
    let played = Played {
        results,
        engine,
        latency: None,
    };
    report(args, policy, &played)?;
    if args.trajectories.is_some() {
        refuse_lost_controllers(&played.results)?;
    }
    // The children's files and journals, once the merged file is written.
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(())
}

/// What decides this run's episodes besides their seeds (a journal of other settings is not
/// resumed from).
fn run_settings(args: &EvalArgs, policy_path: Option<&Path>) -> anyhow::Result<RunSettings> {
    Ok(RunSettings {
        driver: match policy_path {
            Some(path) => RunSettings::policy_hash(path)?,
            // The journals' word since the first evaluations: resumes keep matching.
            None => "expert".to_owned(),
        },
        teacher: args.teacher.name().to_owned(),
        time_limit_s: args.time_limit,
        engine: format!("{:?}", args.controller.engine),
        isa: format!("{:?}", args.controller.isa),
        transport: format!("{:?}", args.controller.transport),
        conditions: args.condition.to_string(),
        camera_samples: args.camera_samples.samples(),
    })
}

fn describe_driver(args: &EvalArgs, policy_path: Option<&std::path::Path>) -> anyhow::Result<()> {
    match policy_path {
        None => match args.teacher {
            Teacher::Paper => println!("driver: the paper's expert (ground truth)"),
            Teacher::Observable => println!(
                "driver: the observable teacher (the ball only through its cameras, its own pose from ground truth)"
            ),
            Teacher::Orbit => println!(
                "driver: the orbiting teacher (the observable one, and the goal's direction only while the top camera shows the goal)"
            ),
            Teacher::Detector => println!(
                "driver: the detector teacher (the observable one, seeing the ball only where enough of it is unoccluded in an image)"
            ),
            Teacher::DetectorOneWay => println!(
                "driver: the one-way detector teacher (the detector one, going around the ball always clockwise)"
            ),
        },
        Some(path) => {
            let manifest = PolicyManifest::load(path)?;
            println!(
                "driver: {} policy {} (trained on {:?}, test error {}), transport {}",
                manifest.kind,
                path.display(),
                manifest.training.dataset,
                manifest
                    .training
                    .test_error
                    .map_or("not recorded".into(), |e| format!("{e:.3}")),
                args.controller.describe()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::journal::tests::episode;

    fn ended(seed: u64, outcome: Outcome) -> EpisodeResult {
        EpisodeResult {
            outcome,
            ..episode(seed)
        }
    }

    #[test]
    fn a_run_with_lost_controllers_fails_and_names_their_seeds() {
        let done = [ended(3, Outcome::Goal), ended(4, Outcome::TimeLimit)];
        assert!(refuse_lost_controllers(&done).is_ok());
        let lost = [
            ended(3, Outcome::Goal),
            ended(4, Outcome::ControllerLost),
            ended(6, Outcome::ControllerLost),
        ];
        let error = refuse_lost_controllers(&lost)
            .expect_err("refused")
            .to_string();
        assert!(
            error.contains("seeds 4, 6 lost their controller"),
            "{error}"
        );
        assert!(error.contains("--resume"), "{error}");
    }
}
