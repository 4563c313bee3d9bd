//! `dribble soak`: the controller process at the robot's real rates for a long time, watched
//! from outside as a robot's camera driver and motion module would see it.
//!
//! This process stands in for both: it publishes YUYV frames of both cameras over iceoryx2 at
//! 30 Hz on CLOCK_MONOTONIC (the bottom camera half a period after the top one, as on the
//! Nao) and reads every command the controller publishes on its 100 Hz loop. Once a second
//! it samples the controller's resident memory and open files (`/proc/PID`), and the
//! latency of that second's commands (from the tick's start, stamped in the command on the
//! shared clock, to its arrival here). It writes one CSV row per second and a JSON summary,
//! and fails if the controller's memory grows after the warm-up, if more than the allowed
//! share of ticks miss their deadline, if any command is lost (a gap in the sequence), or if
//! the controller stops or dies.

use std::fs;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, bail, ensure};
use clap::Args;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_controller::realtime::{self, RealtimeRequest};
use dribble_controller::test_pattern::{PatternCameras, TestPattern};
use dribble_controller::transport::SimulatorPorts;
use dribble_controller::transport::ipc::{Domain, Iceoryx2SimulatorPorts};
use dribble_controller::{Clock, LoopConfig, MonotonicClock, MotionCommand, SyncConfig, Timestamp};
use indicatif::{ProgressBar, ProgressStyle};

use crate::soak_faults::{Action, FaultPlan, FaultReport};
use crate::soak_motion_side::MotionSide;
use serde_json::json;

#[derive(Debug, Args)]
pub struct SoakArgs {
    /// The learned policy the controller runs (`policy.toml`).
    #[arg(long)]
    pub policy: PathBuf,
    /// How long to run, in minutes.
    #[arg(long, default_value_t = 1.0)]
    pub minutes: f64,
    /// Where the CSV (one row a second), the summary and the controller's log go.
    #[arg(long, default_value = "soak")]
    pub out: PathBuf,
    /// Seconds at the start whose memory growth is allowed (loading, first touches of the
    /// shared-memory pools); growth after that fails the soak.
    #[arg(long, default_value_t = 10.0)]
    pub warm_up_s: f64,
    /// Memory growth after the warm-up that fails the soak, KiB.
    #[arg(long, default_value_t = 256)]
    pub max_rss_growth_kib: u64,
    /// Share of ticks that may miss their deadline (a command arriving more than the 2 ms
    /// tick budget after its tick began, or a tick beginning more than half a period late).
    #[arg(long, default_value_t = 0.001)]
    pub max_missed_share: f64,
    /// The controller's SCHED_FIFO priority (passed as --fifo-priority); this process runs
    /// one below it, as a camera driver would. 0: neither asks for one.
    #[arg(long, default_value_t = 40)]
    pub priority: u8,
    /// The controller binary. Default: `dribble-controller` beside this program.
    #[arg(long)]
    pub controller: Option<PathBuf>,
    /// The iceoryx2 domain. Default: one of its own, `soak-PID`.
    #[arg(long)]
    pub domain: Option<String>,
    /// Inject four faults after the warm-up and check the controller's answer to each: a
    /// 1 s camera pause, a publisher restart, a second controller in the domain, the policy
    /// file replaced on disk (the controller runs a copy of the policy in --out).
    #[arg(long)]
    pub faults: bool,
}

/// One second of the soak, as written to the CSV.
#[derive(Clone, Copy, Debug, Default)]
struct Second {
    elapsed_s: f64,
    rss_kib: u64,
    open_files: u64,
    commands: u64,
    new_commands: u64,
    stops: u64,
    lost: u64,
    over_budget: u64,
    late_ticks: u64,
    /// Commands over budget or begun late (a command may be both; counted once).
    missed: u64,
    latency_p50_us: f64,
    latency_p99_us: f64,
    latency_max_us: f64,
}

impl Second {
    const HEADER: &str = "elapsed_s,rss_kib,open_files,commands,new_commands,stops,lost,\
                          over_budget,late_ticks,missed,latency_p50_us,latency_p99_us,latency_max_us";

    fn csv(&self) -> String {
        format!(
            "{:.3},{},{},{},{},{},{},{},{},{},{:.1},{:.1},{:.1}",
            self.elapsed_s,
            self.rss_kib,
            self.open_files,
            self.commands,
            self.new_commands,
            self.stops,
            self.lost,
            self.over_budget,
            self.late_ticks,
            self.missed,
            self.latency_p50_us,
            self.latency_p99_us,
            self.latency_max_us
        )
    }
}

/// The commands' sequence, timing and kinds, over a second and over the whole run.
#[derive(Debug)]
struct CommandWatch {
    budget: Duration,
    late_after: Duration,
    last: Option<MotionCommand>,
    second: Second,
    /// This second's latencies, µs.
    latencies: Vec<f64>,
    /// Every latency of the run, µs (an hour at 100 Hz is 360,000 values).
    all_latencies: Vec<f64>,
    totals: Second,
}

impl CommandWatch {
    fn new(config: &LoopConfig) -> Self {
        Self {
            budget: config.budget,
            late_after: config.tick_period + config.tick_period / 2,
            last: None,
            second: Second::default(),
            latencies: Vec::with_capacity(200),
            all_latencies: Vec::new(),
            totals: Second::default(),
        }
    }

    /// Counts `command`, which arrived at `arrived`; returns false (and counts nothing) for a
    /// command already seen: across a publisher restart two subscribers overlap and both
    /// deliver the commands of that moment.
    fn take(&mut self, command: MotionCommand, arrived: Timestamp) -> bool {
        if self
            .last
            .is_some_and(|last| command.sequence <= last.sequence)
        {
            return false;
        }
        let second = &mut self.second;
        second.commands += 1;
        second.new_commands += u64::from(command.is_new());
        second.stops += u64::from(command.is_stop());
        let mut late = false;
        if let Some(last) = self.last {
            second.lost += command.sequence.saturating_sub(last.sequence + 1);
            let interval = command.timestamp().saturating_since(last.timestamp());
            late = interval > self.late_after;
        }
        let latency = arrived.saturating_since(command.timestamp());
        let over_budget = latency > self.budget;
        second.late_ticks += u64::from(late);
        second.over_budget += u64::from(over_budget);
        second.missed += u64::from(late || over_budget);
        self.latencies.push(latency.as_secs_f64() * 1e6);
        self.last = Some(command);
        true
    }

    /// Closes the second: its latency quantiles, added to the totals.
    fn close_second(&mut self, elapsed_s: f64, rss_kib: u64, open_files: u64) -> Second {
        self.latencies.sort_by(f64::total_cmp);
        let quantile = |q: f64| quantile(&self.latencies, q);
        let mut second = Second {
            elapsed_s,
            rss_kib,
            open_files,
            latency_p50_us: quantile(0.5),
            latency_p99_us: quantile(0.99),
            latency_max_us: quantile(1.0),
            ..self.second
        };
        if self.latencies.is_empty() {
            second.latency_max_us = 0.0;
        }
        let totals = &mut self.totals;
        totals.commands += second.commands;
        totals.new_commands += second.new_commands;
        totals.stops += second.stops;
        totals.lost += second.lost;
        totals.over_budget += second.over_budget;
        totals.late_ticks += second.late_ticks;
        totals.missed += second.missed;
        self.all_latencies.extend_from_slice(&self.latencies);
        self.latencies.clear();
        self.second = Second::default();
        second
    }
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Resident memory and open files of process `pid`, from /proc.
fn sample_process(pid: u32) -> anyhow::Result<(u64, u64)> {
    let status = fs::read_to_string(format!("/proc/{pid}/status"))
        .with_context(|| format!("the controller (pid {pid}) is gone"))?;
    let rss_kib = status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|value| value.split_whitespace().next())
        .and_then(|kib| kib.parse().ok())
        .context("no VmRSS in /proc/PID/status")?;
    let open_files = fs::read_dir(format!("/proc/{pid}/fd"))
        .context("cannot list the controller's open files")?
        .count() as u64;
    Ok((rss_kib, open_files))
}

/// The controller process, stopped (SIGTERM, then SIGKILL) when dropped.
struct ControllerProcess(Child);

impl Drop for ControllerProcess {
    fn drop(&mut self) {
        if let Ok(pid) = i32::try_from(self.0.id()) {
            // SAFETY: kill takes a pid and a signal number only.
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(pid, libc::SIGTERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn controller_binary(args: &SoakArgs) -> anyhow::Result<PathBuf> {
    Ok(match &args.controller {
        Some(path) => path.clone(),
        None => std::env::current_exe()?.with_file_name("dribble-controller"),
    })
}

/// Copies the policy's directory to `to`; returns the copy's manifest and first network.
fn copy_policy(manifest: &Path, to: &Path) -> anyhow::Result<(PathBuf, PathBuf)> {
    let from = manifest.parent().context("the policy has no directory")?;
    fs::create_dir_all(to)?;
    for entry in fs::read_dir(from)? {
        let path = entry?.path();
        if path.is_file() {
            fs::copy(&path, to.join(path.file_name().context("a file name")?))?;
        }
    }
    let copy = to.join(manifest.file_name().context("a manifest name")?);
    let parsed = PolicyManifest::load(&copy)?;
    let network = parsed
        .network_paths()
        .next()
        .context("the policy names no network")?;
    Ok((copy, network))
}

fn start_controller(
    args: &SoakArgs,
    policy: &Path,
    domain: &str,
    log: &Path,
) -> anyhow::Result<Child> {
    let binary = controller_binary(args)?;
    ensure!(
        binary.is_file(),
        "no controller binary at {}",
        binary.display()
    );
    let log_file = fs::File::create(log)
        .with_context(|| format!("cannot write the controller log {}", log.display()))?;
    let mut command = Command::new(&binary);
    command
        .args(["run", "--clock", "monotonic", "--domain", domain])
        .arg("--policy")
        .arg(policy)
        .stdin(Stdio::null())
        .stdout(log_file.try_clone()?)
        .stderr(log_file);
    if args.priority > 0 {
        command.args(["--fifo-priority", &args.priority.to_string()]);
    }
    command
        .spawn()
        .with_context(|| format!("cannot start {}", binary.display()))
}

fn check_arguments(args: &SoakArgs) -> anyhow::Result<()> {
    ensure!(
        args.minutes.is_finite() && args.minutes > 0.0 && args.minutes <= 24.0 * 60.0,
        "--minutes must be in (0, 1440], got {}",
        args.minutes
    );
    ensure!(
        args.warm_up_s >= 0.0 && args.warm_up_s < args.minutes * 60.0,
        "--warm-up-s must be shorter than the run"
    );
    ensure!(
        args.policy.is_file(),
        "no policy at {}",
        args.policy.display()
    );
    Ok(())
}

/// Waits (30 s at most) until the controller has opened its ports.
fn wait_for_connection(
    ports: &Iceoryx2SimulatorPorts,
    controller: &mut ControllerProcess,
    log: &Path,
) -> anyhow::Result<()> {
    let connect_deadline = Instant::now() + Duration::from_secs(30);
    while !ports.controller_connected() {
        if let Some(status) = controller.0.try_wait()? {
            bail!(
                "the controller exited ({status}) before connecting; its log: {}",
                log.display()
            );
        }
        ensure!(
            Instant::now() < connect_deadline,
            "the controller did not connect in 30 s; its log: {}",
            log.display()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}

/// This process (cameras and motion side) one priority below the controller, memory locked;
/// a refusal is a warning.
fn apply_realtime(controller_priority: u8) {
    let report = realtime::apply(RealtimeRequest {
        lock_memory: true,
        fifo_priority: (controller_priority > 1).then(|| controller_priority - 1),
        cpu: None,
    });
    println!(
        "soak: this process (cameras and motion side): {}",
        report.in_force_text()
    );
    for refusal in &report.refused {
        tracing::warn!(event = "realtime_refused", setting = %refusal, action = "the soak runs on without it");
    }
}

/// The camera driver's side of the soak: the camera publisher (which a fault closes and
/// reopens) and the cameras' schedule. The motion module reads the commands on a thread of
/// its own ([`MotionSide`]).
struct CameraSide {
    ports: Option<Iceoryx2SimulatorPorts>,
    cameras: PatternCameras,
}

impl CameraSide {
    /// Does what a fault asks of the publisher.
    fn act(&mut self, action: Action, domain: &Domain) -> anyhow::Result<()> {
        match action {
            Action::None => {}
            Action::ClosePublisher => self.ports = None,
            Action::ReopenPublisher => {
                self.ports = Some(
                    Iceoryx2SimulatorPorts::open(domain, "soak-cameras")
                        .context("cannot reopen the cameras")?,
                );
                // A new publisher numbers its frames from 0.
                self.cameras.restart_numbering();
            }
        }
        Ok(())
    }

    /// Empties the camera ports' own command subscription, which the soak does not count
    /// (the motion side does), so that its events do not pile up.
    fn discard_commands(&mut self) -> anyhow::Result<()> {
        if let Some(ports) = self.ports.as_mut() {
            ports
                .discard_commands()
                .context("cannot read the controller's commands")?;
        }
        Ok(())
    }

    fn publish_due(&mut self, now: Timestamp, publish: bool) -> anyhow::Result<()> {
        let due = self.cameras.poll(now);
        if let Some(ports) = self.ports.as_mut().filter(|_| publish) {
            if due.top {
                ports
                    .publish_top(self.cameras.top())
                    .context("cannot publish a top frame")?;
            }
            if due.bottom {
                ports
                    .publish_bottom(self.cameras.bottom())
                    .context("cannot publish a bottom frame")?;
            }
        }
        Ok(())
    }
}

pub fn run(args: &SoakArgs) -> anyhow::Result<()> {
    check_arguments(args)?;
    fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let domain_name = args
        .domain
        .clone()
        .unwrap_or_else(|| format!("soak-{}", std::process::id()));
    let domain = Domain::new(Some(&domain_name))?;
    let ports = Iceoryx2SimulatorPorts::open(&domain, "soak-cameras")
        .with_context(|| format!("cannot open iceoryx2 domain {domain_name}"))?;
    // With faults, the controller runs a copy of the policy, which the last fault replaces.
    let (policy, network) = if args.faults {
        copy_policy(&args.policy, &args.out.join("policy"))?
    } else {
        (args.policy.clone(), PathBuf::new())
    };
    let log = args.out.join("controller.log");
    let mut controller = ControllerProcess(start_controller(args, &policy, &domain_name, &log)?);
    let pid = controller.0.id();
    wait_for_connection(&ports, &mut controller, &log)?;
    println!(
        "soak: controller pid {pid} in domain {domain_name}, policy {}, {} min; log {}",
        args.policy.display(),
        args.minutes,
        log.display()
    );
    apply_realtime(args.priority);
    // Started after the real-time settings, so that its thread inherits them.
    let mut motion = MotionSide::start(&domain)?;

    let config = LoopConfig::default();
    let clock = MonotonicClock;
    let mut watch = CommandWatch::new(&config);
    let duration = Duration::from_secs_f64(args.minutes * 60.0);
    let start = clock.now();
    let end = start + duration;
    let mut seconds = SecondLog::create(&args.out.join("soak.csv"), start, duration)?;
    let mut plan = if args.faults {
        Some(FaultPlan::new(
            start + Duration::from_secs_f64(args.warm_up_s),
            end,
            &controller_binary(args)?,
            &domain_name,
            &policy,
            &network,
        ))
    } else {
        None
    };
    let mut side = CameraSide {
        ports: Some(ports),
        cameras: PatternCameras::new(
            TestPattern::default(),
            SyncConfig::default().camera_period,
            start,
        ),
    };
    let outcome: anyhow::Result<()> = loop {
        let now = clock.now();
        if now >= end {
            break Ok(());
        }
        let mut publish = true;
        if let Some(plan) = plan.as_mut() {
            let action = match plan.poll(now) {
                Ok(action) => action,
                Err(error) => break Err(error).context("a fault could not be injected"),
            };
            if let Err(error) = side.act(action, &domain) {
                break Err(error);
            }
            publish = plan.cameras_publish(now);
        }
        if let Err(error) = side.publish_due(now, publish) {
            break Err(error);
        }
        if now >= seconds.next
            && let Err(error) = seconds.close(now, pid, &mut watch)
        {
            break Err(error);
        }
        if let Some(status) = controller.0.try_wait()? {
            break Err(anyhow::anyhow!(
                "the controller exited ({status}) during the soak"
            ));
        }
        if let Err(error) = side.discard_commands() {
            break Err(error);
        }
        // Commands until the next event.
        let next_event = side.cameras.next_due().min(seconds.next);
        if let Err(error) = read_until(&mut motion, &mut watch, plan.as_mut(), next_event) {
            break Err(error);
        }
    };
    seconds.progress.finish_and_clear();
    drop(motion);
    drop(controller);
    outcome?;
    let faults = plan.map(|mut plan| {
        let text = fs::read_to_string(&log).unwrap_or_default();
        plan.reports(&text)
    });
    summarise(args, &seconds.seconds, &mut watch, faults.as_deref())
}

/// The soak's seconds: each closed one is a row of `soak.csv`, kept for the summary, and
/// moves the progress bar.
struct SecondLog {
    csv: fs::File,
    start: Timestamp,
    /// When the next second closes.
    next: Timestamp,
    seconds: Vec<Second>,
    progress: ProgressBar,
}

impl SecondLog {
    fn create(path: &Path, start: Timestamp, duration: Duration) -> anyhow::Result<Self> {
        let mut csv =
            fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
        writeln!(csv, "{}", Second::HEADER)?;
        let progress = ProgressBar::new(duration.as_secs());
        progress.set_style(
            ProgressStyle::with_template("{bar:30} {pos}/{len} s  {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        Ok(Self {
            csv,
            start,
            next: start + Duration::from_secs(1),
            seconds: Vec::new(),
            progress,
        })
    }

    /// Closes the second that ended at `now`, with the controller's memory and open files.
    fn close(&mut self, now: Timestamp, pid: u32, watch: &mut CommandWatch) -> anyhow::Result<()> {
        let elapsed_s = now.saturating_since(self.start).as_secs_f64();
        let (rss_kib, open_files) = sample_process(pid)?;
        let second = watch.close_second(elapsed_s, rss_kib, open_files);
        writeln!(self.csv, "{}", second.csv())?;
        self.progress.set_position(elapsed_s as u64);
        self.progress.set_message(format!(
            "RSS {} KiB, {} files, latency p99 {:.0} µs, lost {}",
            rss_kib, open_files, second.latency_p99_us, watch.totals.lost
        ));
        self.seconds.push(second);
        self.next = self.next + Duration::from_secs(1);
        Ok(())
    }
}

/// Takes every command the motion side receives until `until`.
fn read_until(
    motion: &mut MotionSide,
    watch: &mut CommandWatch,
    mut plan: Option<&mut FaultPlan>,
    until: Timestamp,
) -> anyhow::Result<()> {
    while let Some((command, arrived)) = motion.next_before(until)? {
        if watch.take(command, arrived)
            && let Some(plan) = plan.as_deref_mut()
        {
            plan.on_command(&command, arrived);
        }
    }
    Ok(())
}

/// The lines a controller prints about itself as it stops: ticks, frames, its tick time.
fn controller_statistics(log: &str) -> Vec<&str> {
    log.lines()
        .filter(|line| {
            ["ticks ", "frames accepted ", "tick time: "]
                .iter()
                .any(|start| line.starts_with(start))
        })
        .collect()
}

/// Every criterion the soak missed, in words (empty: it passed).
fn failures(
    args: &SoakArgs,
    totals: &Second,
    missed_share: f64,
    growth: u64,
    files: (u64, u64),
    faults: Option<&[FaultReport]>,
) -> Vec<String> {
    let mut failures = Vec::new();
    if totals.commands == 0 {
        failures.push("no command arrived".to_owned());
    }
    if totals.lost > 0 {
        failures.push(format!("{} commands lost", totals.lost));
    }
    if missed_share > args.max_missed_share {
        failures.push(format!(
            "{:.4} % of ticks missed their deadline (allowed {:.4} %)",
            100.0 * missed_share,
            100.0 * args.max_missed_share
        ));
    }
    if growth > args.max_rss_growth_kib {
        failures.push(format!(
            "the controller's memory grew {growth} KiB after the warm-up (allowed {} KiB)",
            args.max_rss_growth_kib
        ));
    }
    if files.1 > files.0 {
        failures.push(format!("open files grew from {} to {}", files.0, files.1));
    }
    for report in faults.unwrap_or_default().iter().filter(|r| !r.passed) {
        failures.push(format!("fault {}: {}", report.kind.name(), report.detail));
    }
    failures
}

/// Prints and writes the summary; fails if a criterion is not met.
/// The controller's memory and open files over the soak.
#[derive(Clone, Copy, Debug)]
struct MemoryAccount {
    /// Resident set at the end of the warm-up (or at the first second after it), KiB.
    rss_start: u64,
    rss_end: u64,
    /// The most after the warm-up, KiB, and its growth over `rss_start`.
    rss_max: u64,
    growth: u64,
    /// Open files in the first and the last second.
    files: (u64, u64),
}

impl MemoryAccount {
    fn of(seconds: &[Second], warm_up_s: f64) -> Self {
        let (warm_up, settled): (Vec<&Second>, Vec<&Second>) =
            seconds.iter().partition(|s| s.elapsed_s <= warm_up_s);
        let rss_start = warm_up
            .last()
            .or(settled.first())
            .map_or(0, |second| second.rss_kib);
        let rss_max = settled.iter().map(|s| s.rss_kib).max().unwrap_or(rss_start);
        Self {
            rss_start,
            rss_end: seconds.last().map_or(0, |second| second.rss_kib),
            rss_max,
            growth: rss_max.saturating_sub(rss_start),
            files: (
                seconds.first().map_or(0, |s| s.open_files),
                seconds.last().map_or(0, |s| s.open_files),
            ),
        }
    }
}

/// Prints each fault's verdict; the same as JSON for soak.json.
fn fault_reports(faults: &[FaultReport]) -> Vec<serde_json::Value> {
    for report in faults {
        let verdict = if report.passed {
            "as documented"
        } else {
            "NOT as documented"
        };
        let (kind, detail) = (report.kind.name(), &report.detail);
        println!("soak: fault {kind}: {verdict} ({detail})");
    }
    faults
        .iter()
        .map(|r| json!({"fault": r.kind.name(), "passed": r.passed, "detail": r.detail}))
        .collect()
}

fn summarise(
    args: &SoakArgs,
    seconds: &[Second],
    watch: &mut CommandWatch,
    faults: Option<&[FaultReport]>,
) -> anyhow::Result<()> {
    let totals = watch.totals;
    let MemoryAccount {
        rss_start,
        rss_end,
        rss_max,
        growth,
        files,
    } = MemoryAccount::of(seconds, args.warm_up_s);
    watch.all_latencies.sort_by(f64::total_cmp);
    let latency = |q: f64| quantile(&watch.all_latencies, q);
    let missed = totals.missed;
    let missed_share = missed as f64 / totals.commands.max(1) as f64;
    println!(
        "soak: {:.1} min, {} commands ({} computed, {} stops), {} lost",
        seconds.last().map_or(0.0, |s| s.elapsed_s) / 60.0,
        totals.commands,
        totals.new_commands,
        totals.stops,
        totals.lost
    );
    println!(
        "soak: latency from tick start to arrival p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs; \
         missed deadlines {missed} ({:.4} %: {} over the {:?} budget, {} ticks begun late)",
        latency(0.5),
        latency(0.99),
        latency(1.0),
        100.0 * missed_share,
        totals.over_budget,
        watch.budget,
        totals.late_ticks
    );
    println!(
        "soak: controller RSS {rss_start} KiB after the {:.0} s warm-up, {rss_end} KiB at the \
         end (max {rss_max}, growth {growth} KiB); open files {} -> {}",
        args.warm_up_s, files.0, files.1
    );
    let fault_json = fault_reports(faults.unwrap_or_default());
    // The controller's own account, printed as it stops (SIGTERM): ticks, frames and its tick
    // time from inside the loop.
    let controller_log = fs::read_to_string(args.out.join("controller.log")).unwrap_or_default();
    let controller_statistics = controller_statistics(&controller_log);
    for line in &controller_statistics {
        println!("soak: the controller says: {line}");
    }
    let summary = json!({
        "faults": fault_json,
        "controller_statistics": controller_statistics,
        "policy": args.policy,
        "minutes": args.minutes,
        "commands": totals.commands,
        "computed": totals.new_commands,
        "stops": totals.stops,
        "lost": totals.lost,
        "missed": missed,
        "missed_share": missed_share,
        "over_budget": totals.over_budget,
        "late_ticks": totals.late_ticks,
        "latency_us": {"p50": latency(0.5), "p99": latency(0.99), "max": latency(1.0)},
        "rss_kib": {"after_warm_up": rss_start, "end": rss_end, "max": rss_max, "growth": growth},
        "open_files": {"start": files.0, "end": files.1},
        "limits": {
            "max_rss_growth_kib": args.max_rss_growth_kib,
            "max_missed_share": args.max_missed_share,
        },
    });
    let summary_path = args.out.join("soak.json");
    fs::write(&summary_path, format!("{summary:#}\n"))
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    println!(
        "soak: wrote {} and {}",
        args.out.join("soak.csv").display(),
        summary_path.display()
    );
    let failures = failures(args, &totals, missed_share, growth, files, faults);
    if !failures.is_empty() {
        bail!("soak failed: {}", failures.join("; "));
    }
    println!("soak: passed");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use dribble_controller::{CommandFlags, SpeedCommand};

    fn command(sequence: u64, tick_ms: u64) -> MotionCommand {
        MotionCommand {
            sequence,
            timestamp_ns: tick_ms * 1_000_000,
            top_sequence: 0,
            bottom_sequence: 0,
            speed: SpeedCommand::STOP,
            flags: CommandFlags::NEW,
        }
    }

    fn at_us(us: u64) -> Timestamp {
        Timestamp::from_nanos(us * 1000)
    }

    #[test]
    fn gaps_late_ticks_and_slow_commands_are_counted_once_each() {
        let mut watch = CommandWatch::new(&LoopConfig::default());
        watch.take(command(1, 10), at_us(10_100)); // 100 µs
        watch.take(command(2, 20), at_us(20_200));
        watch.take(command(5, 30), at_us(30_300)); // 3 and 4 lost
        watch.take(command(6, 50), at_us(50_100)); // begun 20 ms after the last: late
        watch.take(command(7, 60), at_us(63_000)); // 3 ms after its start: over budget
        watch.take(command(8, 80), at_us(83_000)); // both: missed once
        let second = watch.close_second(1.0, 100, 5);
        assert_eq!(second.commands, 6);
        assert_eq!(second.lost, 2);
        assert_eq!(second.late_ticks, 2);
        assert_eq!(second.over_budget, 2);
        assert_eq!(second.missed, 3);
        assert_eq!(second.latency_max_us, 3000.0);
        assert_eq!(second.latency_p50_us, 300.0); // of 100, 100, 200, 300, 3000, 3000 µs
        assert_eq!(watch.totals.lost, 2);
        // The next second starts from zero, the totals go on.
        watch.take(command(9, 90), at_us(90_050));
        let next = watch.close_second(2.0, 100, 5);
        assert_eq!((next.commands, next.lost, next.missed), (1, 0, 0));
        assert_eq!(watch.totals.commands, 7);
        assert_eq!(watch.all_latencies.len(), 7);
    }

    #[test]
    fn a_command_seen_twice_counts_once_and_a_gap_across_a_restart_is_lost() {
        let mut watch = CommandWatch::new(&LoopConfig::default());
        assert!(watch.take(command(1, 10), at_us(10_100)));
        // The second subscriber of a restart delivers 1 again, then 2 and 4.
        assert!(!watch.take(command(1, 10), at_us(10_300)));
        assert!(watch.take(command(2, 20), at_us(20_100)));
        assert!(watch.take(command(4, 40), at_us(40_100)));
        let second = watch.close_second(1.0, 100, 5);
        assert_eq!((second.commands, second.lost), (3, 1));
    }

    #[test]
    fn a_csv_row_has_a_value_for_every_column() {
        let columns = Second::HEADER.split(',').count();
        assert_eq!(Second::default().csv().split(',').count(), columns);
    }
}
