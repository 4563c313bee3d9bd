//! `dribble eval`: a driver plays episodes in closed loop; a table, the goal count, the
//! controller's latency and a trajectory plot come out.
//!
//! A learned policy runs in the controller, in lock-step with the simulator: by default
//! the `dribble-controller` process over iceoryx2 shared memory (started here unless one
//! already runs in the domain), or with `--transport in-process` the same controller code
//! in a thread over channels. The scripted expert reads ground truth, so it always runs
//! inside the simulator.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_controller::tick_stats::TickStats;
use dribble_sim::conditions::Conditions;
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::episode_observer::{EpisodeObserver, NoObserver};
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, EpisodeResult, run_episode_observed};

use crate::controller_session::{ControllerOptions, ControllerSession};
use crate::episodes::Episodes;
use crate::evaluation::jobs::{JobPlan, play};
use crate::evaluation::journal::{EvalJournal, KeptEpisode, RunSettings};
use crate::foxglove_episodes::FoxgloveArgs;
use crate::trajectories::file::write_trajectories;
use crate::trajectories::plot::{plot_trajectories, title};
use dribble_sim::expert::Teacher;

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// `expert` for the scripted expert (ground truth), or the path of a policy's
    /// `policy.toml` (it sees the rendered cameras).
    #[arg(long, default_value = "expert")]
    driver: String,
    /// `test` (seeds 10000..10019), `train` (0..99) or a seed range such as `10000..10005`.
    #[arg(long, default_value = "test")]
    episodes: Episodes,
    /// What the cameras see the episodes under: `clean` (the paper's render), one condition
    /// or several as NAME:SEVERITY[,NAME:SEVERITY...] with severities 1 (slight) to 5
    /// (harsh), e.g. `noise:3` or `light:2,venue:4`, or `randomized` (each episode draws
    /// its own from its seed, as training does). Names: exposure, contrast, noise,
    /// white-balance, motion-blur, lens, light, venue, unseen-venue, robots. Written into
    /// the trajectories file.
    #[arg(long, visible_alias = "conditions", default_value = "clean")]
    condition: Conditions,
    /// Where to write the trajectory plot.
    #[arg(long, default_value = "eval_trajectories.png")]
    plot: PathBuf,
    /// Also write every episode's outcome and robot and ball paths (10 Hz) as JSON.
    #[arg(long)]
    trajectories: Option<PathBuf>,
    /// Render the cameras even for the expert (slower; it does not look at them).
    #[arg(long)]
    render: bool,
    /// Which teacher `--driver expert` is: `paper` (reads the ball's true position),
    /// `observable` (knows the ball only while a camera shows it, and where it last saw it) or
    /// `orbit` (the observable one, which also walks straight to the ball and circles it to the
    /// left until the top camera shows the target goal).
    #[arg(long, default_value_t = Teacher::Paper)]
    expert: Teacher,
    /// Time limit per episode, simulated seconds (positive and finite).
    #[arg(long, default_value_t = 90.0, value_parser = crate::episodes::time_limit)]
    time_limit: f32,
    /// Play the episodes in this many processes at once, each with its own simulator,
    /// controller and iceoryx2 domain (`<domain>-job<k>`); the table, plot and trajectories
    /// are merged in seed order and the outcomes are a serial run's. About one job per core.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    jobs: u16,
    /// Continue a run that was cut off (a session's end, a killed job): keep the episodes
    /// its journal `TRAJECTORIES.partial` holds for the same settings (policy files, teacher,
    /// time limit, engine, instruction set, transport) and play only the rest; the files come
    /// out as an uninterrupted run's. Needs --trajectories. Every run with --trajectories
    /// keeps that journal while it runs (with --jobs, in `TRAJECTORIES.jobs/`).
    #[arg(long, requires = "trajectories")]
    resume: bool,
    /// Set by a parent run for its --jobs children: keep the journal when done (the parent
    /// removes it with its other scratch files once the merged file is written).
    #[arg(long, hide = true)]
    keep_journal: bool,
    #[command(flatten)]
    controller: ControllerOptions,
    #[command(flatten)]
    foxglove: FoxgloveArgs,
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        ..EpisodeConfig::default()
    };
    let policy_path = (args.driver != "expert").then(|| PathBuf::from(&args.driver));
    describe_driver(args, policy_path.as_deref())?;
    if !args.condition.is_clean() {
        println!("conditions: {}", args.condition);
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
        journal.finish()?;
    }
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
            None => "expert".to_owned(),
        },
        teacher: args.expert.name().to_owned(),
        time_limit_s: args.time_limit,
        engine: format!("{:?}", args.controller.engine),
        isa: format!("{:?}", args.controller.isa),
        transport: format!("{:?}", args.controller.transport),
        conditions: args.condition.to_string(),
    })
}

/// What a run played: every episode, the engine that ran the policy, the controller's latency.
struct Played {
    results: Vec<EpisodeResult>,
    engine: Option<String>,
    /// Not known for a run in jobs (each child prints its own); of the played episodes only
    /// in a resumed run.
    latency: Option<TickStats>,
}

fn describe_driver(args: &EvalArgs, policy_path: Option<&std::path::Path>) -> anyhow::Result<()> {
    match policy_path {
        None => match args.expert {
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

pub(crate) fn print_header() {
    println!(
        "{:>6}  {:<15}  {:>9}  {:>9}  {:>8}",
        "seed", "outcome", "time (s)", "walked (m)", "commands"
    );
}

pub(crate) fn print_row(result: &EpisodeResult) {
    println!(
        "{:>6}  {:<15}  {:>9.1}  {:>9.2}  {:>8}",
        result.setup.seed,
        result.outcome.name(),
        result.duration_s,
        result.distance_walked_m,
        result.computed_commands
    );
    if let Some(failure) = &result.failure {
        println!("        {failure}");
    }
}

/// Plays every episode in this process, one after the other.
/// Plays the episodes of `args` in this process; with a journal, the episodes it kept from
/// a cut run are taken as they are and every played one is appended to it.
fn play_here(
    args: &EvalArgs,
    config: &EpisodeConfig,
    policy_path: Option<&Path>,
    journal: Option<(&mut EvalJournal, Vec<KeptEpisode>)>,
) -> anyhow::Result<Played> {
    let (mut journal, kept) = match journal {
        Some((journal, kept)) => (Some(journal), kept),
        None => (None, Vec::new()),
    };
    let mut kept_engines: Vec<Option<String>> = kept.iter().map(|(_, e)| e.clone()).collect();
    kept_engines.dedup();
    anyhow::ensure!(
        kept_engines.len() <= 1,
        "the journal's episodes name different engines: {kept_engines:?}"
    );
    let kept_engine = kept_engines.pop();
    let mut kept: std::collections::BTreeMap<u64, EpisodeResult> = kept
        .into_iter()
        .map(|(result, _)| (result.setup.seed, result))
        .collect();
    let mut renderer = if policy_path.is_some() || args.render {
        let renderer = Renderer::new(
            &FieldGeometry::SPL,
            config.world.goal_depth,
            &config.cameras,
        )?;
        println!("adapter: {}", renderer.adapter());
        Some(renderer)
    } else {
        None
    };
    println!();
    print_header();
    let mut results: Vec<EpisodeResult> = Vec::new();
    let mut latency = TickStats::new(config.control.budget);
    let mut session: Option<ControllerSession> = None;
    let mut engine: Option<String> = None;
    if policy_path.is_some() {
        args.controller.start_log()?;
    }
    let mut foxglove = args.foxglove.observer(renderer.is_some())?;
    for seed in args.episodes.0.clone() {
        if let Some(result) = kept.remove(&seed) {
            print_row(&result);
            results.push(result);
            continue;
        }
        let setup = EpisodeSetup::from_seed(seed).under(args.condition);
        let mut no_observer = NoObserver;
        let observer: &mut dyn EpisodeObserver = match foxglove.as_mut() {
            Some(foxglove) => foxglove,
            None => &mut no_observer,
        };
        let result = match policy_path {
            None => {
                let expert = Expert::teaching(
                    args.expert,
                    ExpertConfig::default(),
                    FieldGeometry::SPL,
                    config.cameras,
                );
                run_episode_observed(
                    &setup,
                    config,
                    Driver::Expert(expert),
                    renderer.as_mut(),
                    None,
                    observer,
                )
            }
            Some(path) => {
                if session.is_none() {
                    let opened = ControllerSession::open(&args.controller, path, config.control)?;
                    engine = opened.engine(&args.controller);
                    session = Some(opened);
                }
                let link = session.as_mut().map(ControllerSession::link);
                let driver = Driver::Controller(link.context("no controller session")?);
                run_episode_observed(&setup, config, driver, renderer.as_mut(), None, observer)
            }
        }
        .with_context(|| format!("episode {seed}"))?;
        if let Some(failure) = foxglove.as_mut().and_then(|f| f.take_failure()) {
            return Err(failure.context(format!("episode {seed}: writing it for Foxglove")));
        }
        print_row(&result);
        if let Some(journal) = journal.as_mut() {
            journal.append(&result, engine.as_deref())?;
        }
        if result.failure.is_some() {
            // A new controller for the next episode (a running one we did not start is
            // looked for again).
            session = None;
        }
        latency.merge(&result.tick_times);
        results.push(result);
    }
    if let Some(session) = session.take() {
        session.finish(&args.controller);
    }
    if let (Some(foxglove), Some(dir)) = (&foxglove, &args.foxglove.mcap) {
        println!(
            "mcap: {} episode file(s) in {} (open in Foxglove with sim-harness/foxglove-layout.json)",
            foxglove.written().len(),
            dir.display()
        );
    }
    let engine = match (kept_engine, engine) {
        (Some(theirs), Some(ours)) if theirs.as_ref() != Some(&ours) => anyhow::bail!(
            "the episodes kept from the journal ran on {theirs:?}, this run on {ours}: \
             remove the journal to play them all again"
        ),
        (Some(theirs), None) => theirs,
        (_, ours) => ours,
    };
    Ok(Played {
        results,
        engine,
        latency: Some(latency),
    })
}

/// Goals with their interval, the time to goal, the latency, the plot and the file.
fn report(args: &EvalArgs, policy: bool, played: &Played) -> anyhow::Result<()> {
    let results = &played.results;
    let goals: Vec<f32> = results
        .iter()
        .filter(|r| r.outcome == Outcome::Goal)
        .map(|r| r.duration_s)
        .collect();
    let lost = results
        .iter()
        .filter(|r| r.outcome == Outcome::ControllerLost)
        .count();
    println!();
    if let Some(engine) = &played.engine {
        println!("engine: {engine}");
    }
    let (low, high) = crate::evaluation::goal_rate::wilson_interval(goals.len(), results.len());
    println!(
        "goals: {} of {} (95 % Wilson interval {low:.2}-{high:.2})",
        goals.len(),
        results.len()
    );
    if lost > 0 {
        println!("episodes failed because the controller was lost: {lost}");
    }
    if let Some(median) = median(&goals) {
        println!("median time to goal: {median:.1} s");
    }
    let what = if policy {
        args.controller.latency_label()
    } else {
        "controller tick latency (computing ticks, this machine)"
    };
    match played.latency.as_ref().and_then(TickStats::summary) {
        Some(summary) => println!("{what}: {summary}"),
        None if args.jobs > 1 && policy => {
            println!("{what}: in each job's output (not merged across --jobs)")
        }
        None => {}
    }
    plot_trajectories(results, &title(&args.driver, results), &args.plot)?;
    println!("trajectory plot: {}", args.plot.display());
    if let Some(path) = &args.trajectories {
        write_trajectories(results, played.engine.as_deref(), path)?;
        println!("trajectories: {}", path.display());
    }
    Ok(())
}

fn median(values: &[f32]) -> Option<f32> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f32::total_cmp);
    match sorted.len() {
        0 => None,
        n if n % 2 == 1 => Some(sorted[n / 2]),
        n => Some((sorted[n / 2 - 1] + sorted[n / 2]) / 2.0),
    }
}
