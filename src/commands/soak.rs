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
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, ensure};
use clap::Args;
use dribble_controller::policy::engine::Isa;
use dribble_controller::test_pattern::{PatternCameras, TestPattern};
use dribble_controller::transport::ipc::{Domain, Iceoryx2SimulatorPorts};
use dribble_controller::{Clock, LoopConfig, MonotonicClock, SyncConfig, Timestamp};

use crate::soak::cameras::CameraSide;
use crate::soak::command_watch::CommandWatch;
use crate::soak::controller_process::{
    ControllerProcess, apply_realtime, copy_policy, start_controller, wait_for_connection,
};
use crate::soak::faults::FaultPlan;
use crate::soak::motion_side::MotionSide;
use crate::soak::second_log::SecondLog;
use crate::soak::verdict::summarise;

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
    /// The compiled engine's instruction set the controller runs (passed as --isa: portable,
    /// sse2, ssse3, sse4.2, avx2+fma, avx512; the Nao V5's is ssse3, the V6's sse4.2).
    /// Default: the widest this CPU runs. Recorded in soak.json with the engine the
    /// controller reports.
    #[arg(long)]
    pub isa: Option<Isa>,
    /// The iceoryx2 domain. Default: one of its own, `soak-PID`.
    #[arg(long)]
    pub domain: Option<String>,
    /// Inject four faults after the warm-up and check the controller's answer to each: a
    /// 1 s camera pause, a publisher restart, a second controller in the domain, the policy
    /// file replaced on disk (the controller runs a copy of the policy in --out).
    #[arg(long)]
    pub faults: bool,
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
    if let Some(isa) = args.isa {
        ensure!(
            isa.is_available(),
            "this CPU does not run {isa} (it runs {})",
            Isa::available()
                .map(Isa::name)
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
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
            &crate::controller_session::controller_binary(args.controller.as_deref())?,
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
