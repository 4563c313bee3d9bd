//! The simulator's side of the controller, in lock-step: it publishes the frames as the
//! cameras take them and a tick every motion cycle, then waits for the command answering
//! the tick. The controller runs in another process over iceoryx2 ([`Iceoryx2Link`]) or
//! in a thread over channels ([`ThreadLink`]); either way it is the same controller code,
//! [`ControllerNode::run_lock_step`].

use std::process::Child;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use dribble_controller::policy::PolicyLoadError;
use dribble_controller::transport::channel::{ChannelSimulatorPorts, channel_transport};
use dribble_controller::transport::ipc::{
    CONTROLLER_NODE, Domain, Iceoryx2SimulatorPorts, NodeInfo, SIMULATOR_NODE,
};
use dribble_controller::transport::{ControllerNode, LockStepTick, SimulatorPorts, TransportError};
use dribble_controller::{
    BottomFrame, ControlLoop, LoopConfig, ManualClock, MotionCommand, Policy, TopFrame,
};

/// The link to the controller failed; the episode cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("the controller died: {0}")]
    ControllerDied(String),
    #[error("the controller did not answer tick {index} (t = {time_s:.3} s) within {timeout:?}")]
    NoAnswer {
        index: u64,
        time_s: f64,
        timeout: Duration,
    },
    #[error("the controller could not start: {0}")]
    Start(String),
    #[error(transparent)]
    Transport(#[from] TransportError),
}

/// How long to wait for the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkTimeouts {
    /// For the answer to one tick, while the controller is alive.
    pub answer: Duration,
    /// Between two checks that the controller is alive while waiting: a killed
    /// controller is noticed within about this long.
    pub liveness: Duration,
    /// For a controller process to start and open its ports.
    pub start: Duration,
}

impl Default for LinkTimeouts {
    fn default() -> Self {
        Self {
            answer: Duration::from_secs(2),
            liveness: Duration::from_millis(10),
            start: Duration::from_secs(20),
        }
    }
}

/// A controller the simulator drives in lock-step.
pub trait ControllerLink {
    /// The simulator's side of the transport the frames and ticks cross.
    fn ports(&mut self) -> &mut dyn SimulatorPorts;

    fn publish_top(&mut self, frame: &TopFrame) -> Result<(), LinkError> {
        Ok(self.ports().publish_top(frame)?)
    }

    fn publish_bottom(&mut self, frame: &BottomFrame) -> Result<(), LinkError> {
        Ok(self.ports().publish_bottom(frame)?)
    }

    /// Publishes `tick` and returns the command that answers it.
    fn exchange(&mut self, tick: &LockStepTick) -> Result<MotionCommand, LinkError>;
}

/// The controller in a thread of this process, over crossbeam channels.
#[derive(Debug)]
pub struct ThreadLink {
    ports: ChannelSimulatorPorts,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), TransportError>>>,
    timeouts: LinkTimeouts,
}

impl ThreadLink {
    /// Starts the controller thread; `load` makes its policy there (tract plans need not
    /// cross threads), and its error comes back here.
    pub fn spawn<L>(config: LoopConfig, load: L, timeouts: LinkTimeouts) -> Result<Self, LinkError>
    where
        L: FnOnce() -> Result<Box<dyn Policy>, PolicyLoadError> + Send + 'static,
    {
        let (controller_ports, ports) = channel_transport();
        let stop = Arc::new(AtomicBool::new(false));
        let (loaded_tx, loaded_rx) = crossbeam_channel::bounded(1);
        let thread_stop = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("dribble-controller".into())
            .spawn(move || {
                let policy = match load() {
                    Ok(policy) => {
                        let _ = loaded_tx.send(Ok(()));
                        policy
                    }
                    Err(error) => {
                        let _ = loaded_tx.send(Err(error.to_string()));
                        return Ok(());
                    }
                };
                let control = ControlLoop::new(config, policy, ManualClock::default());
                ControllerNode::new(control, controller_ports).run_lock_step(&thread_stop, |_| {})
            })
            .map_err(|e| LinkError::Start(e.to_string()))?;
        match loaded_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(message)) => return Err(LinkError::Start(message)),
            Err(_) => return Err(LinkError::Start("the controller thread panicked".into())),
        }
        Ok(Self {
            ports,
            stop,
            thread: Some(thread),
            timeouts,
        })
    }
}

impl ControllerLink for ThreadLink {
    fn ports(&mut self) -> &mut dyn SimulatorPorts {
        &mut self.ports
    }

    fn exchange(&mut self, tick: &LockStepTick) -> Result<MotionCommand, LinkError> {
        let thread = self.thread.as_ref();
        exchange_over(&mut self.ports, tick, &self.timeouts, || {
            if thread.is_none_or(JoinHandle::is_finished) {
                Err(LinkError::ControllerDied(
                    "the controller thread ended".into(),
                ))
            } else {
                Ok(())
            }
        })
    }
}

impl Drop for ThreadLink {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// One lock-step exchange over `ports`: the tick out, then its answer, waited for in
/// slices of the liveness interval; between slices `alive` says whether the controller
/// still runs (an error if not).
fn exchange_over(
    ports: &mut impl SimulatorPorts,
    tick: &LockStepTick,
    timeouts: &LinkTimeouts,
    mut alive: impl FnMut() -> Result<(), LinkError>,
) -> Result<MotionCommand, LinkError> {
    ports.discard_commands()?;
    ports.publish_tick(tick)?;
    let deadline = Instant::now() + timeouts.answer;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match ports.answer(tick, left.min(timeouts.liveness)) {
            Ok(Some(command)) => return Ok(command),
            Ok(None) => {}
            Err(TransportError::Disconnected(_)) => alive()?,
            Err(other) => return Err(other.into()),
        }
        alive()?;
        if left.is_zero() {
            return Err(LinkError::NoAnswer {
                index: tick.index,
                time_s: tick.time_ns as f64 / 1e9,
                timeout: timeouts.answer,
            });
        }
    }
}

/// The controller process, over iceoryx2 shared memory.
#[derive(Debug)]
pub struct Iceoryx2Link {
    domain: Domain,
    ports: Iceoryx2SimulatorPorts,
    controller: NodeInfo,
    child: Option<Child>,
    timeouts: LinkTimeouts,
}

impl Iceoryx2Link {
    /// Connects to the controller running in `domain`, or, when none runs, starts
    /// `spawn` (a `dribble-controller run --clock simulation ...` command) and waits
    /// until its ports are open.
    pub fn connect(
        domain: &Domain,
        spawn: Option<&mut std::process::Command>,
        timeouts: LinkTimeouts,
    ) -> Result<Self, LinkError> {
        let ports = Iceoryx2SimulatorPorts::open(domain, SIMULATOR_NODE)?;
        let mut child = None;
        if running_controller(domain)?.is_none() {
            let Some(command) = spawn else {
                return Err(LinkError::Start(format!(
                    "no controller runs in domain {}",
                    domain.label()
                )));
            };
            child = Some(
                command
                    .spawn()
                    .map_err(|e| LinkError::Start(format!("{command:?}: {e}")))?,
            );
        }
        let started = Instant::now();
        loop {
            if let Some(child) = child.as_mut()
                && let Ok(Some(status)) = child.try_wait()
            {
                return Err(LinkError::Start(format!("it exited with {status}")));
            }
            if let Some(controller) = running_controller(domain)?
                && ports.controller_connected()
            {
                return Ok(Self {
                    domain: domain.clone(),
                    ports,
                    controller,
                    child,
                    timeouts,
                });
            }
            if started.elapsed() > timeouts.start {
                if let Some(mut child) = child {
                    let _ = child.kill();
                    let _ = child.wait();
                }
                return Err(LinkError::Start(format!(
                    "its ports did not open within {:?}",
                    timeouts.start
                )));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// How many dead nodes (killed processes) opening this link cleaned up after.
    pub fn cleaned_dead_nodes(&self) -> u64 {
        self.ports.cleaned_dead_nodes()
    }

    /// The controller's process id.
    pub fn controller_pid(&self) -> Option<i32> {
        self.controller.pid
    }

    /// Whether this link started the controller (and stops it when dropped).
    pub fn owns_controller(&self) -> bool {
        self.child.is_some()
    }

    /// Stops a controller this link started (SIGTERM, so it prints its statistics) and
    /// waits for it; a controller that does not stop within 5 s is killed.
    pub fn stop_controller(&mut self) -> Option<std::process::ExitStatus> {
        let mut child = self.child.take()?;
        if let Ok(pid) = libc_pid(child.id()) {
            terminate(pid);
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            match child.try_wait() {
                Ok(Some(status)) => return Some(status),
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(5));
                }
                _ => {
                    let _ = child.kill();
                    return child.wait().ok();
                }
            }
        }
    }
}

impl ControllerLink for Iceoryx2Link {
    fn ports(&mut self) -> &mut dyn SimulatorPorts {
        &mut self.ports
    }

    fn exchange(&mut self, tick: &LockStepTick) -> Result<MotionCommand, LinkError> {
        let (domain, controller, child) = (&self.domain, self.controller, &mut self.child);
        exchange_over(&mut self.ports, tick, &self.timeouts, || {
            if controller_alive(domain, controller, child.as_mut())? {
                Ok(())
            } else {
                Err(LinkError::ControllerDied(format!(
                    "process {} is gone",
                    controller.pid.unwrap_or(-1)
                )))
            }
        })
    }
}

impl Drop for Iceoryx2Link {
    fn drop(&mut self) {
        self.stop_controller();
    }
}

/// Whether `controller` still runs: our child has not exited, and its iceoryx2 node (whose
/// lock the kernel drops with the process) is alive.
fn controller_alive(
    domain: &Domain,
    controller: NodeInfo,
    child: Option<&mut Child>,
) -> Result<bool, LinkError> {
    if let Some(child) = child
        && !matches!(child.try_wait(), Ok(None))
    {
        return Ok(false);
    }
    Ok(domain.is_alive(controller.id)?)
}

/// The one live controller of `domain`, if any.
fn running_controller(domain: &Domain) -> Result<Option<NodeInfo>, LinkError> {
    let alive: Vec<NodeInfo> = domain
        .nodes_named(CONTROLLER_NODE)?
        .into_iter()
        .filter(|node| node.alive)
        .collect();
    match alive.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(*one)),
        many => Err(LinkError::Start(format!(
            "{} controllers run in domain {} (pids {:?}); stop all but one",
            many.len(),
            domain.label(),
            many.iter().map(|n| n.pid).collect::<Vec<_>>()
        ))),
    }
}

fn libc_pid(id: u32) -> Result<libc::pid_t, std::num::TryFromIntError> {
    libc::pid_t::try_from(id)
}

/// Sends SIGTERM (std's `Child::kill` only sends SIGKILL).
fn terminate(pid: libc::pid_t) {
    // SAFETY: kill(2) with a pid of our own child and a valid signal number.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(pid, libc::SIGTERM);
    }
}
