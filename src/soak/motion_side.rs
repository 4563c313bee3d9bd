//! The motion module's side of `dribble soak`: a thread of its own that reads every command
//! the controller sends, with the moment it arrived.
//!
//! On the robot the motion module is a process of its own; it reads on whatever the camera
//! driver does. Here the camera side closes and reopens its ports when a fault asks, and
//! opening iceoryx2 ports takes tens of milliseconds on a loaded machine: a reader on the
//! soak's main thread stopped reading for that long, the command subscription (4 samples
//! deep, 40 ms of commands) overflowed, and the soak counted a command lost that the
//! controller had sent. The thread reads through a [`CommandMonitor`] opened once, so no
//! fault of the camera side pauses it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use dribble_controller::transport::TransportError;
use dribble_controller::transport::ipc::{CommandMonitor, Domain};
use dribble_controller::{Clock, MonotonicClock, MotionCommand, Timestamp};

/// A command and when the motion side received it.
pub type Arrival = (MotionCommand, Timestamp);

/// The reading thread, and the channel its commands come through.
pub struct MotionSide {
    arrivals: mpsc::Receiver<Arrival>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), TransportError>>>,
}

/// How long the thread waits for a command before it looks at its stop flag.
const STOP_CHECK: Duration = Duration::from_millis(5);

impl MotionSide {
    /// Starts the thread and returns once its subscription is open in `domain`.
    pub fn start(domain: &Domain) -> anyhow::Result<Self> {
        let (arrivals_in, arrivals) = mpsc::channel();
        let (opened_in, opened) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let thread = std::thread::Builder::new()
            .name("soak-motion".into())
            .spawn({
                let domain = domain.clone();
                let stop = Arc::clone(&stop);
                move || {
                    let mut monitor = match CommandMonitor::open(&domain, "soak-motion") {
                        Ok(monitor) => {
                            let _ = opened_in.send(None);
                            monitor
                        }
                        Err(error) => {
                            let _ = opened_in.send(Some(error.to_string()));
                            return Ok(());
                        }
                    };
                    read(&mut monitor, &arrivals_in, &stop)
                }
            })
            .context("cannot start the motion side's thread")?;
        match opened.recv() {
            Ok(None) => {}
            Ok(Some(error)) => anyhow::bail!("cannot open the motion side: {error}"),
            Err(_) => anyhow::bail!("the motion side's thread ended before it opened"),
        }
        Ok(Self {
            arrivals,
            stop,
            thread: Some(thread),
        })
    }

    /// The next command to arrive before `until`, if one does.
    pub fn next_before(&mut self, until: Timestamp) -> anyhow::Result<Option<Arrival>> {
        let left = until.saturating_since(MonotonicClock.now());
        match self.arrivals.recv_timeout(left) {
            Ok(arrival) => Ok(Some(arrival)),
            Err(mpsc::RecvTimeoutError::Timeout) => Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(self.ended()),
        }
    }

    /// Why the thread ended before it was asked to.
    fn ended(&mut self) -> anyhow::Error {
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(Err(error))) => {
                anyhow::Error::new(error).context("the motion side stopped reading commands")
            }
            Some(Err(_)) => anyhow::anyhow!("the motion side's thread panicked"),
            Some(Ok(Ok(()))) | None => anyhow::anyhow!("the motion side stopped reading commands"),
        }
    }
}

impl Drop for MotionSide {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Reads commands until `stop` is set or the receiving end is gone.
fn read(
    monitor: &mut CommandMonitor,
    arrivals: &mpsc::Sender<Arrival>,
    stop: &AtomicBool,
) -> Result<(), TransportError> {
    while !stop.load(Ordering::Relaxed) {
        if let Some(command) = monitor.next(STOP_CHECK)?
            && arrivals.send((command, MonotonicClock.now())).is_err()
        {
            return Ok(());
        }
    }
    Ok(())
}
