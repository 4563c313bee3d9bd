//! `dribble eval`: a driver plays episodes in closed loop; a table, the goal count, the
//! controller's latency and a trajectory plot come out.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use dribble_controller::policy::OnnxPolicy;
use dribble_controller::tick_stats::TickStats;
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, EpisodeResult, run_episode};

use crate::episodes::Episodes;
use crate::trajectory_plot::plot_trajectories;

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// `expert` for the scripted expert (ground truth), or the path of a policy's
    /// `policy.toml` (it sees the rendered cameras).
    #[arg(long, default_value = "expert")]
    driver: String,
    /// `test` (seeds 10000..10019), `train` (0..99) or a seed range such as `10000..10005`.
    #[arg(long, default_value = "test")]
    episodes: Episodes,
    /// Where to write the trajectory plot.
    #[arg(long, default_value = "eval_trajectories.png")]
    plot: PathBuf,
    /// Render the cameras even for the expert (slower; it does not look at them).
    #[arg(long)]
    render: bool,
    /// Time limit per episode, simulated seconds.
    #[arg(long, default_value_t = 90.0)]
    time_limit: f32,
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        ..EpisodeConfig::default()
    };
    let mut policy = if args.driver == "expert" {
        println!("driver: the scripted expert (ground truth; no trained policy is shipped yet)");
        None
    } else {
        let (policy, manifest) = OnnxPolicy::load(Path::new(&args.driver))?;
        println!(
            "driver: {} policy {} (trained on {:?}, test error {})",
            manifest.kind,
            args.driver,
            manifest.training.dataset,
            manifest
                .training
                .test_error
                .map_or("not recorded".into(), |e| format!("{e:.3}"))
        );
        Some(policy)
    };
    let mut renderer = if policy.is_some() || args.render {
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
    println!(
        "{:>6}  {:<10}  {:>9}  {:>9}  {:>8}",
        "seed", "outcome", "time (s)", "walked (m)", "commands"
    );
    let mut results: Vec<EpisodeResult> = Vec::new();
    let mut latency = TickStats::new(config.control.budget);
    for seed in args.episodes.0.clone() {
        let setup = EpisodeSetup::from_seed(seed);
        let driver = match policy.as_mut() {
            Some(policy) => Driver::Policy(policy),
            None => Driver::Expert(Expert::new(ExpertConfig::default(), FieldGeometry::SPL)),
        };
        let result = run_episode(&setup, &config, driver, renderer.as_mut(), None)
            .with_context(|| format!("episode {seed}"))?;
        println!(
            "{:>6}  {:<10}  {:>9.1}  {:>9.2}  {:>8}",
            seed,
            result.outcome.name(),
            result.duration_s,
            result.distance_walked_m,
            result.computed_commands
        );
        latency.merge(&result.tick_times);
        results.push(result);
    }
    let goals: Vec<f32> = results
        .iter()
        .filter(|r| r.outcome == Outcome::Goal)
        .map(|r| r.duration_s)
        .collect();
    println!();
    println!("goals: {} of {}", goals.len(), results.len());
    if let Some(median) = median(&goals) {
        println!("median time to goal: {median:.1} s");
    }
    if let Some(summary) = latency.summary() {
        println!("controller tick latency (computing ticks, this machine): {summary}");
    }
    let driver_name = if policy.is_some() { "POLICY" } else { "EXPERT" };
    let title = format!("{driver_name}: {} OF {} GOALS", goals.len(), results.len());
    plot_trajectories(&results, &title, &args.plot)?;
    println!("trajectory plot: {}", args.plot.display());
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
