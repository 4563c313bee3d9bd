//! Reaching a learned policy's controller from the simulator, as `dribble eval` and
//! `dribble record --driver` both do: the `dribble-controller` process over iceoryx2 shared
//! memory (started here unless one already runs in the domain), or the same controller code
//! in a thread of this process over channels.

use dribble_controller::run_statistics::RunStatistics;
use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use dribble_controller::Policy;
use dribble_controller::control_loop::LoopConfig;
use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy};
use dribble_controller::transport::ipc::Domain;
use dribble_sim::controller_link::{ControllerLink, Iceoryx2Link, LinkTimeouts, ThreadLink};

/// How frames and commands travel between the simulator and a policy's controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Transport {
    /// The `dribble-controller` process, over iceoryx2 shared memory, as on the robot.
    Iceoryx2,
    /// The same controller code in a thread of this process, over channels.
    InProcess,
}

/// Where and how a policy's controller runs (shared by the commands that drive with one).
#[derive(Debug, Args)]
pub struct ControllerOptions {
    /// How a policy's controller is reached (the expert always runs in the simulator).
    #[arg(long, value_enum, default_value_t = Transport::Iceoryx2)]
    pub transport: Transport,
    /// The controller binary to start when none runs. Default: `dribble-controller`
    /// beside this program.
    #[arg(long)]
    pub controller: Option<PathBuf>,
    /// Where a controller started here writes its log and statistics.
    #[arg(long, default_value = "controller.log")]
    pub controller_log: PathBuf,
    /// iceoryx2 domain. Default: $DRIBBLE_DOMAIN, else iceoryx2's default configuration.
    #[arg(long)]
    pub domain: Option<String>,
    /// How long to wait for the command answering a tick before the episode fails, ms.
    /// A controller that dies is noticed within about 10 ms whatever this is.
    #[arg(long, default_value_t = 2000)]
    pub answer_timeout_ms: u64,
    /// Which engine the controller runs the policy with: `compiled` (its own allocation-free
    /// engine, the default) or `tract`.
    #[arg(long, default_value = "compiled")]
    pub engine: Engine,
    /// The compiled engine's instruction set (portable, sse2, ssse3, sse4.2, avx2+fma,
    /// avx512). Default: the widest this CPU runs. Pin it to compare closed-loop results
    /// across machines: each instruction set adds up in its own order, and a closed loop
    /// turns differences in the last bits into different episodes.
    #[arg(long)]
    pub isa: Option<Isa>,
}

impl ControllerOptions {
    pub fn describe(&self) -> &'static str {
        match self.transport {
            Transport::Iceoryx2 => "iceoryx2 (controller process)",
            Transport::InProcess => "in-process (controller thread)",
        }
    }

    /// What a lock-step round trip measures over this transport.
    pub fn latency_label(&self) -> &'static str {
        match self.transport {
            Transport::Iceoryx2 => {
                "lock-step round trip (tick out, command back; computing ticks, this machine)"
            }
            Transport::InProcess => {
                "lock-step round trip over channels (computing ticks, this machine)"
            }
        }
    }

    /// Empties the controller log for this run (its controllers then log there, one after
    /// another).
    pub fn start_log(&self) -> anyhow::Result<()> {
        if self.transport == Transport::Iceoryx2 {
            File::create(&self.controller_log).with_context(|| {
                format!(
                    "cannot write the controller log {}",
                    self.controller_log.display()
                )
            })?;
        }
        Ok(())
    }

    pub(crate) fn engine_options(&self) -> EngineOptions {
        EngineOptions {
            engine: self.engine,
            isa: self.isa,
        }
    }

    fn timeouts(&self) -> LinkTimeouts {
        LinkTimeouts {
            answer: Duration::from_millis(self.answer_timeout_ms),
            ..LinkTimeouts::default()
        }
    }
}

/// A policy's controller, reached over a transport.
pub enum ControllerSession {
    Thread {
        link: ThreadLink,
        /// What runs the policy's networks, as the loaded policy reports it.
        engine: Option<String>,
    },
    Process(Box<Iceoryx2Link>),
}

impl ControllerSession {
    /// Starts (or, over iceoryx2, finds) a controller running `policy`.
    pub fn open(
        options: &ControllerOptions,
        policy: &Path,
        control: LoopConfig,
    ) -> anyhow::Result<Self> {
        match options.transport {
            Transport::InProcess => {
                let policy = policy.to_owned();
                let engine_options = options.engine_options();
                let (report_tx, report_rx) = std::sync::mpsc::channel();
                let load = move || {
                    OnnxPolicy::load_with(&policy, engine_options).map(|(policy, _)| {
                        let _ = report_tx.send(policy.engine().to_string());
                        Box::new(policy) as Box<dyn Policy>
                    })
                };
                let link = ThreadLink::spawn(control, load, options.timeouts())?;
                // The load has finished when `spawn` returns (it waits for it).
                let engine = report_rx.try_recv().ok();
                Ok(Self::Thread { link, engine })
            }
            Transport::Iceoryx2 => open_process(options, policy, control),
        }
    }

    pub fn link(&mut self) -> &mut dyn ControllerLink {
        match self {
            Self::Thread { link, .. } => link,
            Self::Process(link) => link.as_mut(),
        }
    }

    /// What runs the policy's networks, e.g. `compiled (avx2+fma)` or `tract`: as the
    /// loaded policy reports it in this process, or as the controller process wrote it to
    /// its log when it loaded the policy (`None` for a controller this session joined, which
    /// logs elsewhere).
    pub fn engine(&self, options: &ControllerOptions) -> Option<String> {
        match self {
            Self::Thread { engine, .. } => engine.clone(),
            Self::Process(link) if link.owns_controller() => {
                let log = std::fs::read_to_string(&options.controller_log).ok()?;
                engine_in_log(&log).map(str::to_owned)
            }
            Self::Process(_) => None,
        }
    }

    /// Stops a controller process this session started, and prints its statistics.
    pub fn finish(self, options: &ControllerOptions) {
        if let Self::Process(mut link) = self
            && link.owns_controller()
        {
            link.stop_controller();
            print_controller_statistics(&options.controller_log);
        }
    }
}

fn open_process(
    options: &ControllerOptions,
    policy: &Path,
    control: LoopConfig,
) -> anyhow::Result<ControllerSession> {
    let domain = match &options.domain {
        Some(name) => Domain::new(Some(name))?,
        None => Domain::from_env()?,
    };
    let binary = controller_binary(options.controller.as_deref())?;
    // Appended to: a controller started after one was lost keeps the first one's log.
    let log = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&options.controller_log)
        .with_context(|| {
            format!(
                "cannot write the controller log {}",
                options.controller_log.display()
            )
        })?;
    let mut command = Command::new(&binary);
    command
        .arg("--rate-hz")
        .arg((1.0 / control.tick_period.as_secs_f64()).to_string())
        .args(["--engine", options.engine.name()]);
    if let Some(isa) = options.isa {
        command.args(["--isa", isa.name()]);
    }
    command
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
    ends_with_this_process(&mut command);
    let link = Iceoryx2Link::connect(&domain, Some(&mut command), options.timeouts())
        .with_context(|| {
            format!(
                "linking to a controller ({}) in iceoryx2 domain {}",
                binary.display(),
                domain.label()
            )
        })?;
    if link.owns_controller() {
        tracing::info!(
            event = "controller_started",
            binary = %binary.display(),
            pid = link.controller_pid().unwrap_or(-1),
            domain = %domain.label(),
            log = %options.controller_log.display(),
        );
    } else {
        tracing::info!(
            event = "controller_joined",
            domain = %domain.label(),
            pid = link.controller_pid().unwrap_or(-1),
            note = "the controller already running in the domain drives with its own policy",
        );
    }
    if link.cleaned_dead_nodes() > 0 {
        tracing::info!(
            event = "iceoryx2_cleaned",
            dead_processes = link.cleaned_dead_nodes(),
            domain = %domain.label(),
        );
    }
    Ok(ControllerSession::Process(Box::new(link)))
}

/// A controller this process starts is sent SIGTERM (which it answers by stopping cleanly)
/// when this process ends: killed by a signal, this process runs no destructor, and its
/// controller would otherwise wait for the next lock-step tick for ever. The signal follows
/// the thread that starts the controller, which is the main thread in every command.
fn ends_with_this_process(command: &mut Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id();
    // SAFETY: between fork and exec the closure calls only prctl(2) and getppid(2), both
    // async-signal-safe, and allocates nothing.
    #[allow(unsafe_code)]
    unsafe {
        command.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have ended before the request was made.
            if u32::try_from(libc::getppid()).ok() != Some(parent) {
                libc::raise(libc::SIGTERM);
            }
            Ok(())
        });
    }
}

/// The controller program every command starts: `--controller`, else `dribble-controller`
/// beside this executable, else on the PATH.
pub(crate) fn controller_binary(given: Option<&Path>) -> anyhow::Result<PathBuf> {
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

/// The engine the last policy loaded in a controller log runs on: the end of the controller's
/// `policy: ... engine compiled (avx2+fma)` line.
fn engine_in_log(log: &str) -> Option<&str> {
    log.lines()
        .rev()
        .filter(|line| line.starts_with("policy: "))
        .find_map(|line| {
            line.rsplit_once(", engine ")
                .map(|(_, engine)| engine.trim())
        })
}

/// The statistics a stopped controller printed, read from its machine line.
fn print_controller_statistics(log: &Path) {
    let Ok(text) = std::fs::read_to_string(log) else {
        return;
    };
    println!();
    match RunStatistics::from_log(&text) {
        Ok(statistics) => {
            println!("controller statistics ({}):", log.display());
            for line in statistics.to_string().lines() {
                println!("  {line}");
            }
        }
        Err(why) => println!("controller statistics ({}): {why}", log.display()),
    }
}

#[cfg(test)]
mod tests {
    use super::engine_in_log;

    #[test]
    fn the_engine_is_read_from_the_last_policy_line_of_a_controller_log() {
        let log = "policy: cnn from a (1 network file(s), trained on \"x\"), engine tract\n\
                   ts=2026-11-23T10:00:00Z level=info event=ready\n\
                   policy: cnn from b (1 network file(s), trained on \"y, engine z\"), engine compiled (avx2+fma)\n\
                   ticks: 100\n";
        assert_eq!(engine_in_log(log), Some("compiled (avx2+fma)"));
        assert_eq!(engine_in_log("ts=... event=ready\n"), None);
    }
}
