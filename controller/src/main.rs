//! `dribble-controller`: the robot process.

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};
use dribble_controller::log_output::{self, LogFormat};
use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::engine::peak::{
    int8_multiply_adds_per_second, multiply_adds_per_second,
};
use dribble_controller::policy::file_watch::PolicyFileWatch;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_controller::policy::{BrightnessPolicy, OnnxPolicy};
use dribble_controller::policy::{Engine, EngineOptions};
use dribble_controller::realtime::{self, RealtimeRequest};
use dribble_controller::run_statistics::RunStatistics;
use dribble_controller::test_pattern::{PatternCameras, TestPattern};
use dribble_controller::thumbnail::downscale;
use dribble_controller::tick_stats::TickStats;
use dribble_controller::transport::ipc::{Domain, Iceoryx2ControllerPorts};
use dribble_controller::transport::{ControllerNode, NodeCounters, NodeEvent};
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraInput, Clock, ControlLoop, LoopConfig, ManualClock,
    MonotonicClock, Policy, PolicyInput, SyncConfig, Timestamp, TopFrame, TopThumbnail, shutdown,
};

/// The dribble controller: turns the Nao's two camera images into walk speed commands with a
/// learned policy, at a fixed rate, allocation-free after start-up.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    /// Control loop rate in ticks per second.
    #[arg(long, default_value_t = 100.0, global = true)]
    rate_hz: f64,
    /// Which engine runs a learned policy: `tract`, or `compiled` (the controller's own
    /// allocation-free engine; a network it cannot lower runs under tract, and the log
    /// says why).
    #[arg(long, default_value = "compiled", global = true)]
    engine: Engine,
    /// The compiled engine's instruction set (portable, sse2, ssse3, sse4.2, avx2+fma, avx512).
    /// Default: the widest this CPU runs.
    #[arg(long, global = true)]
    isa: Option<Isa>,
    /// How events are logged on standard error: `logfmt` (key=value pairs) or `json` (one
    /// object a line). `RUST_LOG` filters them (default `info`; e.g. `RUST_LOG=warn`).
    #[arg(long, default_value = "logfmt", global = true)]
    log_format: LogFormat,
    #[command(subcommand)]
    command: Command,
}

/// Real-time settings for the control thread, applied once start-up is done (policy loaded,
/// ports open). A refused setting logs a warning and the controller runs on, unless
/// `--require-realtime` is given.
#[derive(Clone, Copy, Debug, clap::Args)]
struct RealtimeArgs {
    /// Do not lock the process's memory (by default `mlockall(MCL_CURRENT | MCL_FUTURE)`,
    /// so no page fault lands in a tick; needs root, CAP_IPC_LOCK or `ulimit -l`).
    #[arg(long)]
    no_lock_memory: bool,
    /// Run the control thread under SCHED_FIFO at this priority (1-99; needs root,
    /// CAP_SYS_NICE or an RLIMIT_RTPRIO allowance). The robot package uses 40: above
    /// ordinary processes, below the motion module.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=99))]
    fifo_priority: Option<u8>,
    /// Pin the control thread to this CPU (0-based).
    #[arg(long)]
    cpu: Option<usize>,
    /// Refuse to start unless every real-time setting asked for took effect.
    #[arg(long)]
    require_realtime: bool,
}

impl RealtimeArgs {
    /// Applies the settings to the calling thread and logs what is in force.
    fn apply(&self) -> anyhow::Result<()> {
        let report = realtime::apply(RealtimeRequest {
            lock_memory: !self.no_lock_memory,
            fifo_priority: self.fifo_priority,
            cpu: self.cpu,
        });
        for refusal in &report.refused {
            if self.require_realtime {
                tracing::error!(
                    event = "realtime_refused",
                    setting = %refusal.setting,
                    reason = %refusal.reason,
                    action = "refusing to start (--require-realtime)",
                );
            } else {
                tracing::warn!(
                    event = "realtime_refused",
                    setting = %refusal.setting,
                    reason = %refusal.reason,
                    action = "running on without it",
                );
            }
        }
        if self.require_realtime && !report.refused.is_empty() {
            let refused: Vec<String> = report.refused.iter().map(ToString::to_string).collect();
            bail!("--require-realtime: {}", refused.join("; "));
        }
        tracing::info!(event = "realtime", in_force = %report.in_force_text());
        Ok(())
    }
}

/// Where the controller's time comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum ClockArg {
    /// The robot: a tick every period on CLOCK_MONOTONIC.
    Monotonic,
    /// Lock-step simulation: a tick whenever the simulator publishes one, at its time.
    Simulation,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Runs the controller: subscribes to the cameras (iceoryx2 services
    /// dribble/camera/top and dribble/camera/bottom), computes a command every tick and
    /// publishes it on dribble/motion/command. Logs events (logfmt) on standard error; on
    /// SIGINT or SIGTERM it stops cleanly and prints its statistics.
    Run {
        /// A learned policy's manifest (`policy.toml`); without it, the brightness test
        /// policy drives.
        #[arg(long)]
        policy: Option<PathBuf>,
        /// Where time comes from: `monotonic` on the robot, `simulation` to run in
        /// lock-step with `dribble eval`.
        #[arg(long, value_enum, default_value_t = ClockArg::Monotonic)]
        clock: ClockArg,
        /// The iceoryx2 domain: keeps several robots (or tests) on one machine apart.
        /// Default: $DRIBBLE_DOMAIN, else iceoryx2's default configuration.
        #[arg(long)]
        domain: Option<String>,
        #[command(flatten)]
        realtime: RealtimeArgs,
    },
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
        #[command(flatten)]
        realtime: RealtimeArgs,
    },
    /// Runs a policy's forward pass `--steps` times on the test pattern's thumbnails, prints
    /// the time per pass (min, median, p99, max, against the tick of `--rate-hz`) and, on the
    /// compiled engine, how near the fastest pass came to this core's measured arithmetic
    /// peak, and exits:
    /// a quick speed check on the robot itself, where no benchmark harness runs, and the
    /// workload for instruction counts (`cross/count` runs it under callgrind with 1 and
    /// with 11 steps; the difference is ten forward passes).
    Forward {
        /// A learned policy's manifest (`policy.toml`).
        #[arg(long)]
        policy: PathBuf,
        #[arg(long, default_value_t = 1)]
        steps: u32,
        /// Do not measure this core's arithmetic peak. The probe runs for a fixed time, not a
        /// fixed number of instructions, so instruction counts (`cross/count`, callgrind)
        /// must leave it out.
        #[arg(long)]
        no_peak: bool,
        /// Each step is a whole computing tick of the control loop instead of a forward pass:
        /// both cameras deliver a new frame, the loop accepts them, makes both thumbnails, runs
        /// the policy and publishes the command (what DESIGN.md's 2 ms budget covers).
        #[arg(long, conflicts_with_all = ["layer", "layers"])]
        whole_tick: bool,
        /// Each step runs only layer K of a CNN's compiled plan (on the values a first whole
        /// pass left in its buffers): one layer's workload, for `cross/cycles` and per-layer
        /// timing. `--layers` lists the plan's steps.
        #[arg(long, value_name = "K", conflicts_with = "layers")]
        layer: Option<usize>,
        /// Lists the compiled plan's steps (a CNN's), each with its multiply-adds, the bytes
        /// it reads and writes, and its time per run over `--steps` runs (min and median),
        /// then one line `layers ` + JSON for tools.
        #[arg(long)]
        layers: bool,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let reports_only = !matches!(cli.command, Command::Run { .. });
    match run_command(cli) {
        // Rust ignores SIGPIPE, so a reader that has gone (`forward ... | head -1`) is an
        // error of the write, not a signal; for the commands that only report, it ends the
        // program quietly, as it would a C tool. The controller itself (`run`) still fails.
        Err(error) if reports_only && reader_gone(&error) => Ok(()),
        result => result,
    }
}

/// Whether `error` is a write to a pipe whose reader has closed it.
fn reader_gone(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        cause
            .downcast_ref::<io::Error>()
            .is_some_and(|io| io.kind() == io::ErrorKind::BrokenPipe)
    })
}

fn run_command(cli: Cli) -> anyhow::Result<()> {
    log_output::install(cli.log_format)?;
    let options = EngineOptions {
        engine: cli.engine,
        isa: cli.isa,
    };
    // Below 1 Hz the camera-silence limit (100 ms) would stop every tick; the bound also keeps
    // the period far inside what a `Duration` holds.
    if !(1.0..=10_000.0).contains(&cli.rate_hz) {
        bail!(
            "--rate-hz must be in [1, 10000] ticks per second, got {}",
            cli.rate_hz
        );
    }
    let config = LoopConfig {
        tick_period: Duration::from_secs_f64(1.0 / cli.rate_hz),
        ..LoopConfig::default()
    };
    match cli.command {
        Command::Run {
            policy,
            clock,
            domain,
            realtime,
        } => {
            let domain = match domain {
                Some(name) => Domain::new(Some(&name))?,
                None => Domain::from_env()?,
            };
            let loaded = load_policy(policy.as_deref(), options)?;
            let files = policy.as_deref().map(policy_files).unwrap_or_default();
            let result = run(config, loaded, files, clock, &domain, realtime);
            if let Err(error) = &result {
                tracing::error!(event = "failed", error = %format!("{error:#}"));
            }
            result
        }
        Command::Forward {
            policy,
            steps,
            whole_tick: true,
            ..
        } => whole_ticks(&policy, steps, options, config),
        Command::Forward {
            policy,
            steps,
            layer,
            layers,
            ..
        } if layer.is_some() || layers => layer_passes(&policy, steps, layer, options),
        Command::Forward {
            policy,
            steps,
            no_peak,
            ..
        } => forward(&policy, steps, !no_peak, options, config.tick_period),
        Command::DryRun {
            policy,
            seconds,
            drop_bottom_every,
            realtime,
        } => dry_run(
            config,
            load_policy(policy.as_deref(), options)?,
            seconds,
            drop_bottom_every,
            realtime,
        ),
    }
}

fn load_policy(manifest: Option<&Path>, options: EngineOptions) -> anyhow::Result<Box<dyn Policy>> {
    let Some(manifest) = manifest else {
        writeln!(io::stdout(), "policy: brightness test policy")?;
        return Ok(Box::new(BrightnessPolicy::default()));
    };
    Ok(Box::new(load_learned_policy(manifest, options)?))
}

fn load_learned_policy(manifest: &Path, options: EngineOptions) -> anyhow::Result<OnnxPolicy> {
    let (policy, manifest) = OnnxPolicy::load_with(manifest, options)?;
    let commitment = manifest.hypotheses.as_ref().map_or(String::new(), |h| {
        format!(
            ", holding one of {} hypotheses by a switch margin of {}",
            h.count, h.switch_margin
        )
    });
    writeln!(
        io::stdout(),
        "policy: {} from {} ({} network file(s), {}, trained on {:?}{commitment}), engine {}",
        manifest.kind,
        manifest.directory.display(),
        manifest.networks.len(),
        manifest.precision,
        manifest.training.dataset,
        policy.engine()
    )?;
    Ok(policy)
}

/// The files a loaded policy came from: its manifest and its network files.
fn policy_files(manifest: &Path) -> Vec<PathBuf> {
    let mut files = vec![manifest.to_owned()];
    if let Ok(parsed) = PolicyManifest::load(manifest) {
        files.extend(parsed.network_paths());
    }
    files
}

fn run(
    config: LoopConfig,
    policy: Box<dyn Policy>,
    policy_files: Vec<PathBuf>,
    clock: ClockArg,
    domain: &Domain,
    realtime: RealtimeArgs,
) -> anyhow::Result<()> {
    let stop = shutdown::on_termination().context("cannot handle SIGINT and SIGTERM")?;
    let ports = Iceoryx2ControllerPorts::open(domain).with_context(|| {
        format!(
            "cannot open the iceoryx2 services of domain {}",
            domain.label()
        )
    })?;
    tracing::info!(
        event = "ready",
        domain = %domain.label(),
        clock = %format!("{clock:?}").to_lowercase(),
        rate_hz = 1.0 / config.tick_period.as_secs_f64(),
        pid = std::process::id(),
        cleaned_dead_nodes = ports.cleaned_dead_nodes(),
    );
    realtime.apply()?;
    let on_event = |event: NodeEvent| match event {
        NodeEvent::EpisodeStarted { episode } => {
            tracing::info!(event = "episode", episode);
        }
        NodeEvent::SimulatorSilent => tracing::warn!(
            event = "simulator_silent",
            action = "publishing stops until ticks return",
        ),
        NodeEvent::SimulatorBack => tracing::info!(event = "simulator_back"),
        NodeEvent::CamerasSilent => tracing::warn!(
            event = "cameras_silent",
            action = "publishing stops until both cameras deliver",
        ),
        NodeEvent::CamerasBack => tracing::info!(event = "cameras_back"),
        // Logged with the file's path where the files are watched (the fixed-rate loop).
        NodeEvent::PolicyFileChanged { .. } => {}
        NodeEvent::CameraResynced => tracing::info!(
            event = "camera_resynced",
            action = "frames accepted again after a silence, whatever their sequence numbers",
        ),
    };
    match clock {
        ClockArg::Monotonic => {
            let mut node =
                ControllerNode::new(ControlLoop::new(config, policy, MonotonicClock), ports);
            let mut watches: Vec<PolicyFileWatch> = policy_files
                .iter()
                .filter_map(|path| PolicyFileWatch::new(path))
                .collect();
            let result = node.run_fixed_rate(stop, &mut watches, |event| match event {
                NodeEvent::PolicyFileChanged { file } => tracing::warn!(
                    event = "policy_file_changed",
                    path = %watches_path(&policy_files, file),
                    action = "the loaded policy runs on; restart the controller to load the new one",
                ),
                other => on_event(other),
            });
            finish(node.control(), node.counters(), result)
        }
        ClockArg::Simulation => {
            let control = ControlLoop::new(config, policy, ManualClock::default());
            let mut node = ControllerNode::new(control, ports);
            let result = node.run_lock_step(stop, on_event);
            finish(node.control(), node.counters(), result)
        }
    }
}

fn watches_path(files: &[PathBuf], index: usize) -> String {
    files
        .get(index)
        .map_or_else(String::new, |path| path.display().to_string())
}

fn finish<P: Policy, C: Clock, E: std::error::Error + Send + Sync + 'static>(
    control: &ControlLoop<P, C>,
    node: &NodeCounters,
    result: Result<(), E>,
) -> anyhow::Result<()> {
    let counters = control.counters();
    tracing::info!(
        event = "stopped",
        ticks = counters.ticks,
        episodes = node.episodes,
        watchdog_stops = node.watchdog_stops,
    );
    let printed = print_statistics(control);
    result.context("the transport failed")?;
    Ok(printed?)
}

/// The two thumbnails of the test pattern's first frames: the input of `forward`.
fn test_pattern_thumbnails() -> (Box<TopThumbnail>, Box<BottomThumbnail>) {
    let pattern = TestPattern::default();
    let (mut top_frame, mut bottom_frame) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    let (mut top, mut bottom) = (
        Box::new(TopThumbnail::black()),
        Box::new(BottomThumbnail::black()),
    );
    pattern.paint(&mut top_frame, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom_frame, 0, Timestamp::ZERO);
    downscale(&top_frame, &mut top);
    downscale(&bottom_frame, &mut bottom);
    (top, bottom)
}

fn forward(
    manifest: &Path,
    steps: u32,
    measure_peak: bool,
    options: EngineOptions,
    budget: Duration,
) -> anyhow::Result<()> {
    let mut policy = load_learned_policy(manifest, options)?;
    let (top, bottom) = test_pattern_thumbnails();
    // Measured before the passes, on an idle core (see `peak`).
    // An int8 plan against the int8 peak (its few float multiply-adds are thousandths).
    let int8 = policy.engine().int8;
    let peak = policy
        .engine()
        .compiled
        .filter(|_| measure_peak)
        .and_then(|isa| {
            if int8 {
                int8_multiply_adds_per_second(isa)
            } else {
                multiply_adds_per_second(isa)
            }
        });
    let mut last = None;
    let mut times = TickStats::new(budget);
    for _ in 0..steps {
        let start = Instant::now();
        last = Some(policy.step(PolicyInput::at_rest(&top, &bottom))?);
        times.record(start.elapsed());
    }
    writeln!(
        io::stdout(),
        "{steps} forward pass(es); last command {last:?}"
    )?;
    let Some(summary) = times.summary() else {
        return Ok(());
    };
    // The minimum is the figure to compare builds by on a shared machine: other processes
    // only ever add to a pass's time.
    writeln!(io::stdout(), "time per pass: {summary}")?;
    let report = policy.engine();
    if let (Some(isa), Some(multiply_adds), Some(peak)) =
        (report.compiled, report.multiply_adds, peak)
    {
        let bound = Duration::from_secs_f64(multiply_adds as f64 / peak);
        writeln!(
            io::stdout(),
            "{:.2} M multiply-adds a pass; this core's measured {isa}{} peak, {:.1} G a second, \
             bounds a pass at {bound:.1?}: the fastest pass ran at {:.0} % of it",
            multiply_adds as f64 / 1e6,
            if int8 { " int8" } else { "" },
            peak / 1e9,
            100.0 * bound.as_secs_f64() / summary.min.as_secs_f64(),
        )?;
    }
    Ok(())
}

/// `forward --layer K` and `forward --layers`: one whole pass on the test pattern's
/// thumbnails fills the compiled plan's buffers, then `steps` runs of layer K alone (the
/// workload `cross/cycles` counts), or of every layer in turn with its time per run.
fn layer_passes(
    manifest: &Path,
    steps: u32,
    layer: Option<usize>,
    options: EngineOptions,
) -> anyhow::Result<()> {
    let mut policy = load_learned_policy(manifest, options)?;
    let (top, bottom) = test_pattern_thumbnails();
    policy.step(PolicyInput::at_rest(&top, &bottom))?;
    let network = policy.compiled_cnn_mut().with_context(|| {
        format!(
            "{}: per-layer runs need a CNN policy that the compiled engine runs",
            manifest.display()
        )
    })?;
    let count = network.steps();
    if let Some(index) = layer {
        if index >= count {
            bail!("--layer {index}: the plan has {count} steps (0..{count}; see --layers)");
        }
        for _ in 0..steps {
            network.run_step(index);
        }
        writeln!(io::stdout(), "{steps} run(s) of layer {index} of {count}")?;
        return Ok(());
    }
    let mut rows = Vec::with_capacity(count);
    for (index, report) in network.step_reports().into_iter().enumerate() {
        let mut times = TickStats::new(Duration::from_secs(1));
        for _ in 0..steps.max(1) {
            let start = Instant::now();
            network.run_step(index);
            times.record(start.elapsed());
        }
        let summary = times.summary().context("no runs timed")?;
        writeln!(
            io::stdout(),
            "{index:>3} {:<28} {:>10} multiply-adds {:>9} weight bytes {:>9} activation bytes \
             min {:>9.1?} median {:>9.1?}",
            report.name,
            report.multiply_adds,
            report.weight_bytes,
            report.activation_bytes,
            summary.min,
            summary.median,
        )?;
        rows.push(serde_json::json!({
            "index": index,
            "name": report.name,
            "multiply_adds": report.multiply_adds,
            "weight_bytes": report.weight_bytes,
            "activation_bytes": report.activation_bytes,
            "min_ns": summary.min.as_nanos() as u64,
            "median_ns": summary.median.as_nanos() as u64,
        }));
    }
    let isa = network.isa();
    writeln!(
        io::stdout(),
        "layers {}",
        serde_json::json!({"isa": isa.to_string(), "runs": steps, "steps": rows})
    )?;
    Ok(())
}

/// `forward --whole-tick`: `steps` computing ticks of the control loop, each on a new pair of
/// frames (the test pattern, restamped) at the cameras' rate; their times, and the share of
/// the tick budget the slowest took.
fn whole_ticks(
    manifest: &Path,
    steps: u32,
    options: EngineOptions,
    config: LoopConfig,
) -> anyhow::Result<()> {
    let policy = load_learned_policy(manifest, options)?;
    let pattern = TestPattern::default();
    let (mut top_frame, mut bottom_frame) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    pattern.paint(&mut top_frame, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom_frame, 0, Timestamp::ZERO);
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(config, policy, clock.clone());
    let period = config.sync.camera_period;
    let mut times = TickStats::new(config.budget);
    let mut last = None;
    for step in 1..=u64::from(steps) {
        let time = Timestamp::ZERO + period * u32::try_from(step).unwrap_or(u32::MAX);
        clock.set(time);
        top_frame.restamp(step, time);
        bottom_frame.restamp(step, time);
        let start = Instant::now();
        let command = control.tick(CameraInput {
            top: Some(&top_frame),
            bottom: Some(&bottom_frame),
        });
        times.record(start.elapsed());
        if !command.is_new() {
            bail!("tick {step} computed no command ({command:?})");
        }
        last = Some(command);
    }
    writeln!(
        io::stdout(),
        "{steps} computing tick(s); last command {last:?}"
    )?;
    if let Some(summary) = times.summary() {
        writeln!(io::stdout(), "time per computing tick: {summary}")?;
    }
    Ok(())
}

fn dry_run(
    config: LoopConfig,
    policy: Box<dyn Policy>,
    seconds: f64,
    drop_bottom_every: u64,
    realtime: RealtimeArgs,
) -> anyhow::Result<()> {
    let duration = Duration::try_from_secs_f64(seconds)
        .with_context(|| format!("--seconds must be a non-negative duration, got {seconds}"))?;
    realtime.apply()?;
    let mut control = ControlLoop::new(config, policy, MonotonicClock);
    let start = control.clock().now();
    let end = start + duration;
    let mut cameras = PatternCameras::new(
        TestPattern::default(),
        SyncConfig::default().camera_period,
        start,
    );
    while control.clock().now() < end {
        let due = cameras.poll(control.clock().now());
        let bottom_sequence = cameras.bottom().header().sequence;
        let dropped = drop_bottom_every != 0 && (bottom_sequence + 1) % drop_bottom_every == 0;
        let input = CameraInput {
            top: due.top.then(|| cameras.top()),
            bottom: (due.bottom && !dropped).then(|| cameras.bottom()),
        };
        control.tick(input);
        control.wait_for_next_tick();
    }
    print_statistics(&control)?;
    Ok(())
}

/// The run's statistics: three lines for people, one for programs (`RunStatistics`).
fn print_statistics<P: Policy, C: Clock>(control: &ControlLoop<P, C>) -> io::Result<()> {
    let statistics = RunStatistics::new(
        control.counters(),
        control.sync_counters(),
        control.tick_stats().summary(),
    );
    writeln!(io::stdout(), "{statistics}")?;
    writeln!(io::stdout(), "{}", statistics.machine_line())
}
