//! Episodes played in this process, one after another: each driven by the expert or through
//! the controller process (started once, again after a failure), printed as it ends, added
//! to the journal; episodes a journal kept are taken as they are. Then the report: goals
//! with their interval, times, the controller's latency.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use dribble_controller::tick_stats::TickStats;
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::episode_observer::{EpisodeObserver, NoObserver};
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, EpisodeResult, run_episode_observed};

use crate::commands::eval::EvalArgs;
use crate::controller_session::ControllerSession;
use crate::evaluation::journal::{EvalJournal, KeptEpisode};
use crate::trajectories::file::{PlayedWith, write_trajectories};
use crate::trajectories::plot::{plot_trajectories, title};

/// What a run played: every episode, the engine that ran the policy, the controller's latency.
pub(crate) struct Played {
    pub(crate) results: Vec<EpisodeResult>,
    pub(crate) engine: Option<String>,
    /// Not known for a run in jobs (each child prints its own); of the played episodes only
    /// in a resumed run.
    pub(crate) latency: Option<TickStats>,
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
pub(crate) fn play_here(
    args: &EvalArgs,
    config: &EpisodeConfig,
    policy_path: Option<&Path>,
    journal: Option<(&mut EvalJournal, Vec<KeptEpisode>)>,
) -> anyhow::Result<Played> {
    let (mut journal, kept) = match journal {
        Some((journal, kept)) => (Some(journal), kept),
        None => (None, Vec::new()),
    };
    let KeptRun {
        by_seed: mut kept,
        engine: kept_engine,
    } = kept_by_seed(kept)?;
    let mut renderer = renderer_for(args, config, policy_path.is_some())?;
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
        let driver = match policy_path {
            None => Driver::Expert(Expert::teaching(
                args.teacher,
                ExpertConfig::default(),
                FieldGeometry::SPL,
                config.cameras,
            )),
            Some(path) => {
                if session.is_none() {
                    let opened = ControllerSession::open(&args.controller, path, config.control)?;
                    engine = opened.engine(&args.controller);
                    session = Some(opened);
                }
                let link = session.as_mut().map(ControllerSession::link);
                Driver::Controller(link.context("no controller session")?)
            }
        };
        let result =
            run_episode_observed(&setup, config, driver, renderer.as_mut(), None, observer)
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
    Ok(Played {
        results,
        engine: run_engine(kept_engine, engine)?,
        latency: Some(latency),
    })
}

/// The episodes a journal kept, by seed, and the engine they all name (`None` where the
/// journal kept none).
pub(crate) struct KeptRun {
    pub(crate) by_seed: BTreeMap<u64, EpisodeResult>,
    pub(crate) engine: Option<Option<String>>,
}

/// The journal's episodes as a [`KeptRun`]; refused where they name different engines.
pub(crate) fn kept_by_seed(kept: Vec<KeptEpisode>) -> anyhow::Result<KeptRun> {
    let mut kept_engines: Vec<Option<String>> = kept.iter().map(|(_, e)| e.clone()).collect();
    kept_engines.dedup();
    anyhow::ensure!(
        kept_engines.len() <= 1,
        "the journal's episodes name different engines: {kept_engines:?}"
    );
    let by_seed = kept
        .into_iter()
        .map(|(result, _)| (result.setup.seed, result))
        .collect();
    Ok(KeptRun {
        by_seed,
        engine: kept_engines.pop(),
    })
}

/// The renderer, where the cameras are needed: a policy sees them, or `--render` asks.
pub(crate) fn renderer_for(
    args: &EvalArgs,
    config: &EpisodeConfig,
    policy: bool,
) -> anyhow::Result<Option<Renderer>> {
    if !(policy || args.render) {
        return Ok(None);
    }
    let renderer = config.renderer()?;
    println!("adapter: {}", renderer.adapter());
    Ok(Some(renderer))
}

/// The engine the run names: the one the journal's kept episodes ran on and this run's must
/// be the same.
pub(crate) fn run_engine(
    kept_engine: Option<Option<String>>,
    engine: Option<String>,
) -> anyhow::Result<Option<String>> {
    Ok(match (kept_engine, engine) {
        (Some(theirs), Some(ours)) if theirs.as_ref() != Some(&ours) => anyhow::bail!(
            "the episodes kept from the journal ran on {theirs:?}, this run on {ours}: \
             remove the journal to play them all again"
        ),
        (Some(theirs), None) => theirs,
        (_, ours) => ours,
    })
}

/// Goals with their interval, the time to goal, the latency, the plot and the file.
pub(crate) fn report(args: &EvalArgs, policy: bool, played: &Played) -> anyhow::Result<()> {
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
        let played_with = PlayedWith {
            engine: played.engine.clone(),
            multisampling: args.camera_samples,
        };
        write_trajectories(results, &played_with, path)?;
        println!("trajectories: {}", path.display());
    }
    Ok(())
}

pub(crate) fn median(values: &[f32]) -> Option<f32> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f32::total_cmp);
    match sorted.len() {
        0 => None,
        n if n % 2 == 1 => Some(sorted[n / 2]),
        n => Some((sorted[n / 2 - 1] + sorted[n / 2]) / 2.0),
    }
}
