//! `dribble eval`: a driver plays episodes in closed loop; a table, the goal count, the
//! controller's latency and a trajectory plot come out.
//!
//! A learned policy runs in the controller, in lock-step with the simulator: by default
//! the `dribble-controller` process over iceoryx2 shared memory (started here unless one
//! already runs in the domain), or with `--transport in-process` the same controller code
//! in a thread over channels. The scripted expert reads ground truth, so it always runs
//! inside the simulator.

use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use dribble_controller::Policy;
use dribble_controller::policy::OnnxPolicy;
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_controller::tick_stats::TickStats;
use dribble_controller::transport::ipc::Domain;
use dribble_sim::controller_link::{ControllerLink, Iceoryx2Link, LinkTimeouts, ThreadLink};
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, EpisodeResult, run_episode};
use serde_json::json;

use crate::episodes::Episodes;
use crate::trajectory_plot::plot_trajectories;

/// How frames and commands travel between the simulator and a policy's controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Transport {
    /// The `dribble-controller` process, over iceoryx2 shared memory, as on the robot.
    Iceoryx2,
    /// The same controller code in a thread of this process, over channels.
    InProcess,
}

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
    /// Also write every episode's outcome and robot and ball paths (10 Hz) as JSON.
    #[arg(long)]
    trajectories: Option<PathBuf>,
    /// Render the cameras even for the expert (slower; it does not look at them).
    #[arg(long)]
    render: bool,
    /// Time limit per episode, simulated seconds.
    #[arg(long, default_value_t = 90.0)]
    time_limit: f32,
    /// How a policy's controller is reached (the expert always runs in the simulator).
    #[arg(long, value_enum, default_value_t = Transport::Iceoryx2)]
    transport: Transport,
    /// The controller binary to start when none runs. Default: `dribble-controller`
    /// beside this program.
    #[arg(long)]
    controller: Option<PathBuf>,
    /// Where a controller started here writes its log and statistics.
    #[arg(long, default_value = "controller.log")]
    controller_log: PathBuf,
    /// iceoryx2 domain. Default: $DRIBBLE_DOMAIN, else iceoryx2's default configuration.
    #[arg(long)]
    domain: Option<String>,
    /// How long to wait for the command answering a tick before the episode fails, ms.
    /// A controller that dies is noticed within about 10 ms whatever this is.
    #[arg(long, default_value_t = 2000)]
    answer_timeout_ms: u64,
}

/// A policy's controller, reached over a transport.
enum Session {
    Thread(ThreadLink),
    Process(Box<Iceoryx2Link>),
}

impl Session {
    fn link(&mut self) -> &mut dyn ControllerLink {
        match self {
            Self::Thread(link) => link,
            Self::Process(link) => link.as_mut(),
        }
    }
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        ..EpisodeConfig::default()
    };
    let policy_path = (args.driver != "expert").then(|| PathBuf::from(&args.driver));
    match &policy_path {
        None => {
            println!("driver: the scripted expert (ground truth)")
        }
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
                match args.transport {
                    Transport::Iceoryx2 => "iceoryx2 (controller process)",
                    Transport::InProcess => "in-process (controller thread)",
                }
            );
        }
    }
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
    let timeouts = LinkTimeouts {
        answer: Duration::from_millis(args.answer_timeout_ms),
        ..LinkTimeouts::default()
    };

    println!();
    println!(
        "{:>6}  {:<15}  {:>9}  {:>9}  {:>8}",
        "seed", "outcome", "time (s)", "walked (m)", "commands"
    );
    let mut results: Vec<EpisodeResult> = Vec::new();
    let mut latency = TickStats::new(config.control.budget);
    let mut session: Option<Session> = None;
    if policy_path.is_some() && args.transport == Transport::Iceoryx2 {
        // This run's controllers log here, one after another.
        File::create(&args.controller_log).with_context(|| {
            format!(
                "cannot write the controller log {}",
                args.controller_log.display()
            )
        })?;
    }
    for seed in args.episodes.0.clone() {
        let setup = EpisodeSetup::from_seed(seed);
        let result = match &policy_path {
            None => {
                let expert = Expert::new(ExpertConfig::default(), FieldGeometry::SPL);
                run_episode(
                    &setup,
                    &config,
                    Driver::Expert(expert),
                    renderer.as_mut(),
                    None,
                )
            }
            Some(path) => {
                if session.is_none() {
                    session = Some(open_session(args, path, &config, timeouts)?);
                }
                let link = session.as_mut().map(Session::link);
                let driver = Driver::Controller(link.context("no controller session")?);
                run_episode(&setup, &config, driver, renderer.as_mut(), None)
            }
        }
        .with_context(|| format!("episode {seed}"))?;
        println!(
            "{:>6}  {:<15}  {:>9.1}  {:>9.2}  {:>8}",
            seed,
            result.outcome.name(),
            result.duration_s,
            result.distance_walked_m,
            result.computed_commands
        );
        if let Some(failure) = &result.failure {
            println!("        {failure}");
            // A new controller for the next episode (a running one we did not start is
            // looked for again).
            session = None;
        }
        latency.merge(&result.tick_times);
        results.push(result);
    }
    if let Some(Session::Process(mut link)) = session.take()
        && link.owns_controller()
    {
        link.stop_controller();
        print_controller_statistics(&args.controller_log);
    }
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
    println!("goals: {} of {}", goals.len(), results.len());
    if lost > 0 {
        println!("episodes failed because the controller was lost: {lost}");
    }
    if let Some(median) = median(&goals) {
        println!("median time to goal: {median:.1} s");
    }
    if let Some(summary) = latency.summary() {
        let what = match (&policy_path, args.transport) {
            (None, _) => "controller tick latency (computing ticks, this machine)",
            (Some(_), Transport::Iceoryx2) => {
                "lock-step round trip (tick out, command back; computing ticks, this machine)"
            }
            (Some(_), Transport::InProcess) => {
                "lock-step round trip over channels (computing ticks, this machine)"
            }
        };
        println!("{what}: {summary}");
    }
    let driver_name = if policy_path.is_some() {
        "POLICY"
    } else {
        "EXPERT"
    };
    let title = format!("{driver_name}: {} OF {} GOALS", goals.len(), results.len());
    plot_trajectories(&results, &title, &args.plot)?;
    println!("trajectory plot: {}", args.plot.display());
    if let Some(path) = &args.trajectories {
        write_trajectories(&results, path)?;
        println!("trajectories: {}", path.display());
    }
    Ok(())
}

fn open_session(
    args: &EvalArgs,
    policy: &Path,
    config: &EpisodeConfig,
    timeouts: LinkTimeouts,
) -> anyhow::Result<Session> {
    match args.transport {
        Transport::InProcess => {
            let policy = policy.to_owned();
            let load = move || {
                OnnxPolicy::load(&policy).map(|(policy, _)| Box::new(policy) as Box<dyn Policy>)
            };
            Ok(Session::Thread(ThreadLink::spawn(
                config.control,
                load,
                timeouts,
            )?))
        }
        Transport::Iceoryx2 => {
            let domain = match &args.domain {
                Some(name) => Domain::new(Some(name))?,
                None => Domain::from_env()?,
            };
            let binary = controller_binary(args.controller.as_deref())?;
            // Appended to: a controller started after one was lost keeps the first one's log.
            let log = OpenOptions::new()
                .create(true)
                .append(true)
                .open(&args.controller_log)
                .with_context(|| {
                    format!(
                        "cannot write the controller log {}",
                        args.controller_log.display()
                    )
                })?;
            let mut command = Command::new(&binary);
            command
                .arg("--rate-hz")
                .arg((1.0 / config.control.tick_period.as_secs_f64()).to_string())
                .args(["run", "--clock", "simulation"])
                .arg("--policy")
                .arg(policy)
                .stdin(Stdio::null())
                .stdout(log.try_clone()?)
                .stderr(log);
            // The child joins exactly this domain: named, or iceoryx2's default one.
            match domain.name() {
                Some(name) => command.args(["--domain", name]),
                None => command.env_remove(Domain::ENV),
            };
            let link = Iceoryx2Link::connect(&domain, Some(&mut command), timeouts).with_context(
                || {
                    format!(
                        "linking to a controller ({}) in iceoryx2 domain {}",
                        binary.display(),
                        domain.label()
                    )
                },
            )?;
            if link.owns_controller() {
                println!(
                    "controller: started {} (pid {}, domain {}, log {})",
                    binary.display(),
                    link.controller_pid().unwrap_or(-1),
                    domain.label(),
                    args.controller_log.display()
                );
            } else {
                println!(
                    "controller: using the one already running in domain {} (pid {}); its policy is its own",
                    domain.label(),
                    link.controller_pid().unwrap_or(-1)
                );
            }
            if link.cleaned_dead_nodes() > 0 {
                println!(
                    "iceoryx2: cleaned up after {} dead process(es) in domain {}",
                    link.cleaned_dead_nodes(),
                    domain.label()
                );
            }
            Ok(Session::Process(Box::new(link)))
        }
    }
}

/// `--controller`, else `dribble-controller` beside this executable, else on the PATH.
fn controller_binary(given: Option<&Path>) -> anyhow::Result<PathBuf> {
    if let Some(path) = given {
        if !path.is_file() {
            bail!("--controller {}: no such file", path.display());
        }
        return Ok(path.to_owned());
    }
    let beside = std::env::current_exe()?.with_file_name("dribble-controller");
    if beside.is_file() {
        return Ok(beside);
    }
    Ok(PathBuf::from("dribble-controller"))
}

/// The statistics a stopped controller printed (its log's lines that are not log events).
fn print_controller_statistics(log: &Path) {
    let Ok(text) = std::fs::read_to_string(log) else {
        return;
    };
    println!();
    println!("controller statistics ({}):", log.display());
    for line in text.lines().filter(|l| !l.starts_with("ts=")) {
        println!("  {line}");
    }
}

fn write_trajectories(results: &[EpisodeResult], path: &Path) -> anyhow::Result<()> {
    let points = |path: &[glam::Vec2]| path.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>();
    let episodes: Vec<_> = results
        .iter()
        .map(|r| {
            json!({
                "seed": r.setup.seed,
                "outcome": r.outcome,
                "duration_s": r.duration_s,
                "computed_commands": r.computed_commands,
                "failure": r.failure,
                "robot": points(&r.robot_path),
                "ball": points(&r.ball_path),
            })
        })
        .collect();
    let text = serde_json::to_string(&json!({ "episodes": episodes }))?;
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
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
