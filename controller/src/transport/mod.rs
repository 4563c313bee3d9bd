//! How frames come in and commands go out.
//!
//! On the robot a camera driver publishes frames and a motion module consumes commands; in
//! simulation the harness plays both roles and, in lock-step, also hands out the time. The
//! controller sees the same [`ControllerPorts`] either way:
//!
//! - [`ipc`]: iceoryx2 zero-copy shared memory between processes, the robot's transport;
//! - [`channel`]: crossbeam channels to a controller in a thread of the simulator.
//!
//! [`ControllerNode`] is the controller's main loop over any of them.

pub mod channel;
pub mod ipc;
mod lock_step;
mod node;

use core::ops::Deref;
use core::time::Duration;

pub use lock_step::LockStepTick;
pub use node::{ControllerNode, NodeCounters, NodeEvent};

use crate::frame::{BottomFrame, TopFrame};
use crate::motion_command::MotionCommand;

/// A transport failed. Carries the transport's own words: these are rare, and a RoboCup
/// team debugging a robot wants the whole story.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TransportError {
    #[error("{what}: {detail}")]
    Ipc { what: &'static str, detail: String },
    /// The other side of an in-process transport is gone.
    #[error("the {0} side of the in-process transport is gone")]
    Disconnected(&'static str),
    /// A service that takes one publisher already has it: another `role` (simulator or
    /// controller) runs in the same iceoryx2 domain.
    #[error(
        "{service} already has its publisher in this iceoryx2 domain: another {role} runs in \
         it; give each run its own domain (--domain NAME or DRIBBLE_DOMAIN)"
    )]
    DomainBusy {
        service: &'static str,
        role: &'static str,
    },
    /// A command read from shared memory holds a speed no walk may receive (NaN or
    /// infinite): a foreign or broken controller published it.
    #[error("command {sequence} from the controller has a non-finite speed {speed}: refused")]
    MalformedCommand { sequence: u64, speed: String },
}

impl TransportError {
    pub(crate) fn ipc(what: &'static str, detail: impl core::fmt::Debug) -> Self {
        Self::Ipc {
            what,
            detail: format!("{detail:?}"),
        }
    }
}

/// The controller's side of a transport.
///
/// A frame is held as the transport's own sample (`Top`, `Bottom`): in shared memory, the
/// controller reads it where the driver wrote it, and it goes back when dropped.
pub trait ControllerPorts {
    type Top: Deref<Target = TopFrame>;
    type Bottom: Deref<Target = BottomFrame>;

    /// The newest top frame published since the last call, if any; older ones are released.
    fn newest_top(&mut self) -> Result<Option<Self::Top>, TransportError>;

    /// The newest bottom frame published since the last call, if any.
    fn newest_bottom(&mut self) -> Result<Option<Self::Bottom>, TransportError>;

    /// Publishes a command to the motion module (and wakes whoever waits for it).
    fn publish(&mut self, command: &MotionCommand) -> Result<(), TransportError>;

    /// Lock-step simulation only: the simulator's next tick, waiting at most `timeout`.
    fn next_tick(&mut self, timeout: Duration) -> Result<Option<LockStepTick>, TransportError>;
}

/// The other side of a transport: what a camera driver and a motion module do on the robot,
/// and what the simulator does in lock-step (publishes frames and ticks, waits for commands).
pub trait SimulatorPorts {
    fn publish_top(&mut self, frame: &TopFrame) -> Result<(), TransportError>;

    fn publish_bottom(&mut self, frame: &BottomFrame) -> Result<(), TransportError>;

    /// Throws away the commands waiting unread: they answer nothing the simulator waits for
    /// (stops published while no simulator ticked).
    fn discard_commands(&mut self) -> Result<(), TransportError>;

    /// Publishes a lock-step tick and wakes the controller.
    fn publish_tick(&mut self, tick: &LockStepTick) -> Result<(), TransportError>;

    /// The next command in order, whatever it answers, waiting at most `timeout` for it.
    fn next_command(&mut self, timeout: Duration) -> Result<Option<MotionCommand>, TransportError>;

    /// The command answering `tick`, waiting at most `timeout` for it. The answer is the
    /// command stamped with the tick's time; any other, and a stop from a silent spell
    /// ([`CommandFlags::WATCHDOG`](crate::CommandFlags): one published before a run's first
    /// tick is stamped zero, as that tick is), answers nothing and is passed over.
    fn answer(
        &mut self,
        tick: &LockStepTick,
        timeout: Duration,
    ) -> Result<Option<MotionCommand>, TransportError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.next_command(left)? {
                Some(command) if command.timestamp_ns == tick.time_ns && !command.is_watchdog() => {
                    return Ok(Some(command));
                }
                Some(_) => {}
                None => return Ok(None),
            }
        }
    }
}
