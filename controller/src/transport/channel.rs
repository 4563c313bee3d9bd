//! The in-process transport: crossbeam channels to a controller running in a thread.
//!
//! The same [`ControllerPorts`] as shared memory, for a simulator that wants no second
//! process. Frames travel as boxes that come back to the sender when the controller drops
//! them, so after the first few frames nothing is allocated.

use core::ops::Deref;
use core::time::Duration;

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TryRecvError, bounded};

use super::{ControllerPorts, LockStepTick, SimulatorPorts, TransportError};
use crate::frame::{BottomFrame, CameraFrame, TopFrame};
use crate::motion_command::MotionCommand;

/// Frames in flight per camera, and spare buffers kept for reuse.
const FRAMES_IN_FLIGHT: usize = 4;
/// Commands the simulator has not read yet (an answer and a few stops at most).
const COMMANDS_IN_FLIGHT: usize = 16;

/// A frame received over a channel; it goes back to the sender for reuse when dropped.
#[derive(Debug)]
pub struct ChannelFrame<T> {
    frame: Option<Box<T>>,
    back: Sender<Box<T>>,
}

impl<T> Deref for ChannelFrame<T> {
    type Target = T;

    fn deref(&self) -> &T {
        // Only `drop` takes the box out.
        self.frame.as_deref().unwrap_or_else(|| unreachable!())
    }
}

impl<T> Drop for ChannelFrame<T> {
    fn drop(&mut self) {
        if let Some(frame) = self.frame.take() {
            // A full or closed return channel only means the buffer is freed instead.
            let _ = self.back.try_send(frame);
        }
    }
}

#[derive(Debug)]
struct FrameLane<T> {
    frames: Sender<Box<T>>,
    spare: Receiver<Box<T>>,
}

#[derive(Debug)]
struct FrameInbox<T> {
    frames: Receiver<Box<T>>,
    back: Sender<Box<T>>,
}

fn frame_lane<T>() -> (FrameLane<T>, FrameInbox<T>) {
    let (frames_tx, frames_rx) = bounded(FRAMES_IN_FLIGHT);
    let (back_tx, back_rx) = bounded(FRAMES_IN_FLIGHT);
    (
        FrameLane {
            frames: frames_tx,
            spare: back_rx,
        },
        FrameInbox {
            frames: frames_rx,
            back: back_tx,
        },
    )
}

impl<T> FrameInbox<T> {
    fn newest(&self) -> Result<Option<ChannelFrame<T>>, TransportError> {
        let mut newest = None;
        loop {
            match self.frames.try_recv() {
                Ok(frame) => {
                    newest = Some(ChannelFrame {
                        frame: Some(frame),
                        back: self.back.clone(),
                    })
                }
                Err(TryRecvError::Empty) => return Ok(newest),
                // Frames already sent still count; a closed lane just has no more.
                Err(TryRecvError::Disconnected) => return Ok(newest),
            }
        }
    }
}

impl<const W: usize, const H: usize> FrameLane<CameraFrame<W, H>> {
    /// Copies `frame` into a spare buffer (or a new one) and sends it.
    fn send(&self, frame: &CameraFrame<W, H>) -> Result<(), TransportError> {
        let mut buffer = self
            .spare
            .try_recv()
            .unwrap_or_else(|_| CameraFrame::new_boxed());
        buffer.copy_from(frame);
        self.frames
            .send(buffer)
            .map_err(|_| TransportError::Disconnected("controller"))
    }
}

/// The controller's side of the in-process transport.
#[derive(Debug)]
pub struct ChannelControllerPorts {
    top: FrameInbox<TopFrame>,
    bottom: FrameInbox<BottomFrame>,
    ticks: Receiver<LockStepTick>,
    commands: Sender<MotionCommand>,
}

/// The simulator's side of the in-process transport.
#[derive(Debug)]
pub struct ChannelSimulatorPorts {
    top: FrameLane<TopFrame>,
    bottom: FrameLane<BottomFrame>,
    ticks: Sender<LockStepTick>,
    commands: Receiver<MotionCommand>,
}

/// A connected pair of ports.
pub fn channel_transport() -> (ChannelControllerPorts, ChannelSimulatorPorts) {
    let (top_lane, top_inbox) = frame_lane();
    let (bottom_lane, bottom_inbox) = frame_lane();
    let (ticks_tx, ticks_rx) = bounded(2);
    let (commands_tx, commands_rx) = bounded(COMMANDS_IN_FLIGHT);
    (
        ChannelControllerPorts {
            top: top_inbox,
            bottom: bottom_inbox,
            ticks: ticks_rx,
            commands: commands_tx,
        },
        ChannelSimulatorPorts {
            top: top_lane,
            bottom: bottom_lane,
            ticks: ticks_tx,
            commands: commands_rx,
        },
    )
}

impl ControllerPorts for ChannelControllerPorts {
    type Top = ChannelFrame<TopFrame>;
    type Bottom = ChannelFrame<BottomFrame>;

    fn newest_top(&mut self) -> Result<Option<Self::Top>, TransportError> {
        self.top.newest()
    }

    fn newest_bottom(&mut self) -> Result<Option<Self::Bottom>, TransportError> {
        self.bottom.newest()
    }

    fn publish(&mut self, command: &MotionCommand) -> Result<(), TransportError> {
        match self.commands.try_send(*command) {
            // Unread stops pile up only while the simulator is not waiting for an answer.
            Ok(()) | Err(crossbeam_channel::TrySendError::Full(_)) => Ok(()),
            Err(crossbeam_channel::TrySendError::Disconnected(_)) => {
                Err(TransportError::Disconnected("simulator"))
            }
        }
    }

    fn next_tick(&mut self, timeout: Duration) -> Result<Option<LockStepTick>, TransportError> {
        match self.ticks.recv_timeout(timeout) {
            Ok(tick) => Ok(Some(tick)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(TransportError::Disconnected("simulator")),
        }
    }
}

impl SimulatorPorts for ChannelSimulatorPorts {
    fn publish_top(&mut self, frame: &TopFrame) -> Result<(), TransportError> {
        self.top.send(frame)
    }

    fn publish_bottom(&mut self, frame: &BottomFrame) -> Result<(), TransportError> {
        self.bottom.send(frame)
    }

    fn discard_commands(&mut self) -> Result<(), TransportError> {
        while self.commands.try_recv().is_ok() {}
        Ok(())
    }

    fn publish_tick(&mut self, tick: &LockStepTick) -> Result<(), TransportError> {
        self.ticks
            .send(*tick)
            .map_err(|_| TransportError::Disconnected("controller"))
    }

    fn next_command(&mut self, timeout: Duration) -> Result<Option<MotionCommand>, TransportError> {
        match self.commands.recv_timeout(timeout) {
            Ok(command) => Ok(Some(command)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(TransportError::Disconnected("controller")),
        }
    }
}
