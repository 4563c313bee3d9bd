//! The camera driver's side of the soak: test-pattern frames of both cameras published on
//! time over iceoryx2, paused or restarted as the faults say.

use anyhow::Context;
use dribble_controller::Timestamp;
use dribble_controller::test_pattern::PatternCameras;
use dribble_controller::transport::SimulatorPorts;
use dribble_controller::transport::ipc::{Domain, Iceoryx2SimulatorPorts};

use crate::soak::faults::Action;

/// The camera driver's side of the soak: the camera publisher (which a fault closes and
/// reopens) and the cameras' schedule. The motion module reads the commands on a thread of
/// its own ([`MotionSide`]).
pub(crate) struct CameraSide {
    pub(crate) ports: Option<Iceoryx2SimulatorPorts>,
    pub(crate) cameras: PatternCameras,
}

impl CameraSide {
    /// Does what a fault asks of the publisher.
    pub(crate) fn act(&mut self, action: Action, domain: &Domain) -> anyhow::Result<()> {
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
    pub(crate) fn discard_commands(&mut self) -> anyhow::Result<()> {
        if let Some(ports) = self.ports.as_mut() {
            ports
                .discard_commands()
                .context("cannot read the controller's commands")?;
        }
        Ok(())
    }

    pub(crate) fn publish_due(&mut self, now: Timestamp, publish: bool) -> anyhow::Result<()> {
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
