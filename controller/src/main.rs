//! `dribble-controller`: the robot process.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, bail};
use clap::{Parser, Subcommand};
use dribble_controller::Policy;
use dribble_controller::policy::{BrightnessPolicy, OnnxPolicy};
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::{
    BottomFrame, CameraInput, Clock, ControlLoop, LoopConfig, MonotonicClock, SyncConfig, TopFrame,
};

/// The dribble controller: turns the Nao's two camera images into walk speed commands with a
/// learned policy, at a fixed rate, allocation-free after start-up.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    /// Control loop rate in ticks per second.
    #[arg(long, default_value_t = 100.0, global = true)]
    rate_hz: f64,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Runs the loop in real time on a built-in moving test pattern instead of the cameras,
    /// with a hand-written brightness policy, then prints its statistics. Use it on a robot
    /// to check that the loop keeps its rate and the 2 ms tick budget there.
    DryRun {
        /// A learned policy's manifest (`policy.toml`); without it, the brightness test
        /// policy drives.
        #[arg(long)]
        policy: Option<PathBuf>,
        /// How long to run, in seconds.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Drop every Nth bottom frame (0: drop none), to watch the synchroniser cope.
        #[arg(long, default_value_t = 0)]
        drop_bottom_every: u64,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    if !(cli.rate_hz.is_finite() && cli.rate_hz > 0.0 && cli.rate_hz <= 10_000.0) {
        bail!("--rate-hz must be in (0, 10000], got {}", cli.rate_hz);
    }
    let config = LoopConfig {
        tick_period: Duration::from_secs_f64(1.0 / cli.rate_hz),
        ..LoopConfig::default()
    };
    match cli.command {
        Command::DryRun {
            policy,
            seconds,
            drop_bottom_every,
        } => dry_run(
            config,
            load_policy(policy.as_deref())?,
            seconds,
            drop_bottom_every,
        ),
    }
}

fn load_policy(manifest: Option<&Path>) -> anyhow::Result<Box<dyn Policy>> {
    let Some(manifest) = manifest else {
        println!("policy: brightness test policy");
        return Ok(Box::new(BrightnessPolicy::default()));
    };
    let (policy, manifest) = OnnxPolicy::load(manifest)?;
    println!(
        "policy: {} from {} ({} network file(s), trained on {:?})",
        manifest.kind,
        manifest.directory.display(),
        manifest.networks.len(),
        manifest.training.dataset
    );
    Ok(Box::new(policy))
}

fn dry_run(
    config: LoopConfig,
    policy: Box<dyn Policy>,
    seconds: f64,
    drop_bottom_every: u64,
) -> anyhow::Result<()> {
    let duration = Duration::try_from_secs_f64(seconds)
        .with_context(|| format!("--seconds must be a non-negative duration, got {seconds}"))?;
    let camera_period = SyncConfig::default().camera_period;
    let pattern = TestPattern::default();
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    let mut control = ControlLoop::new(config, policy, MonotonicClock);
    let start = control.clock().now();
    let end = start + duration;
    // The bottom camera fires half a period after the top one.
    let mut next_top = (0u64, start);
    let mut next_bottom = (0u64, start + camera_period / 2);
    while control.clock().now() < end {
        let now = control.clock().now();
        let mut input = CameraInput::default();
        if now >= next_top.1 {
            pattern.paint(&mut top, next_top.0, next_top.1);
            input.top = Some(&top);
            next_top = (next_top.0 + 1, next_top.1 + camera_period);
        }
        if now >= next_bottom.1 {
            let (sequence, time) = next_bottom;
            next_bottom = (sequence + 1, time + camera_period);
            if drop_bottom_every == 0 || (sequence + 1) % drop_bottom_every != 0 {
                pattern.paint(&mut bottom, sequence, time);
                input.bottom = Some(&bottom);
            }
        }
        control.tick(input);
        control.wait_for_next_tick();
    }
    print_statistics(&control);
    Ok(())
}

fn print_statistics<P: Policy, C: Clock>(control: &ControlLoop<P, C>) {
    let counters = control.counters();
    let sync = control.sync_counters();
    println!(
        "ticks {}: {} new, {} repeated, {} stops ({} for cameras), {} policy failures, {} non-finite outputs",
        counters.ticks,
        counters.new_commands,
        counters.repeated_commands,
        counters.stops,
        counters.camera_stops,
        counters.policy_failures,
        counters.non_finite_outputs
    );
    println!(
        "frames accepted top {} bottom {}; duplicates {:?}, out of order {:?}, invalid {}; deadline misses {}",
        sync.accepted[0],
        sync.accepted[1],
        sync.duplicates,
        sync.out_of_order,
        counters.invalid_frames,
        counters.deadline_misses
    );
    match control.tick_stats().summary() {
        Some(summary) => println!("tick time: {summary}"),
        None => println!("tick time: no ticks ran"),
    }
}
