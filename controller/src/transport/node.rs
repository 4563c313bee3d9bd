//! The controller process's main loop over any transport, on either source of time: the
//! robot's `CLOCK_MONOTONIC` ([`ControllerNode::run_fixed_rate`]) or a lock-step
//! simulator's ticks ([`ControllerNode::run_lock_step`]).

use core::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::{ControllerPorts, TransportError};
use crate::clock::{Clock, ManualClock, MonotonicClock};
use crate::control_loop::{CameraInput, ControlLoop};
use crate::motion_command::MotionCommand;
use crate::policy::Policy;
use crate::policy::file_watch::PolicyFileWatch;

/// What happened to the node, for the log. Rare by design: nothing here is per tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeEvent {
    /// A lock-step simulator started an episode; the controller reset itself.
    EpisodeStarted { episode: u64 },
    /// No tick for longer than the camera silence limit: stops are published from now on.
    SimulatorSilent,
    /// Ticks came back after a silence.
    SimulatorBack,
    /// The cameras fell silent (or never delivered): the loop publishes stops.
    CamerasSilent,
    /// Both cameras deliver again: commands are computed again.
    CamerasBack,
    /// A camera's frames are accepted again after a silence, whatever their sequence
    /// numbers: after a pause, or a restarted driver (or publisher) numbering afresh.
    CameraResynced,
    /// The policy file watched at this index was replaced or changed on disk; the loaded
    /// policy runs on until the controller restarts.
    PolicyFileChanged { file: usize },
}

/// Ticks between two looks at the policy files (1 s at 100 Hz).
const POLICY_FILE_POLL_TICKS: u64 = 100;

/// What the node did beyond the control loop's own counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NodeCounters {
    pub episodes: u64,
    pub lock_step_ticks: u64,
    /// Stops published because the lock-step simulator fell silent.
    pub watchdog_stops: u64,
}

/// A control loop wired to a transport: frames in, commands out.
#[derive(Debug)]
pub struct ControllerNode<P, C, T> {
    control: ControlLoop<P, C>,
    ports: T,
    counters: NodeCounters,
}

impl<P: Policy, C: Clock, T: ControllerPorts> ControllerNode<P, C, T> {
    pub fn new(control: ControlLoop<P, C>, ports: T) -> Self {
        Self {
            control,
            ports,
            counters: NodeCounters::default(),
        }
    }

    /// One tick: the newest frame of each camera (read in place, released before the
    /// command goes out), the control loop's decision, and the command published.
    pub fn serve_tick(&mut self) -> Result<MotionCommand, TransportError> {
        let command = {
            let top = self.ports.newest_top()?;
            let bottom = self.ports.newest_bottom()?;
            self.control.tick(CameraInput {
                top: top.as_deref(),
                bottom: bottom.as_deref(),
            })
        };
        self.ports.publish(&command)?;
        Ok(command)
    }

    pub fn control(&self) -> &ControlLoop<P, C> {
        &self.control
    }

    pub fn control_mut(&mut self) -> &mut ControlLoop<P, C> {
        &mut self.control
    }

    pub fn ports_mut(&mut self) -> &mut T {
        &mut self.ports
    }

    pub fn counters(&self) -> &NodeCounters {
        &self.counters
    }
}

impl<P: Policy, T: ControllerPorts> ControllerNode<P, MonotonicClock, T> {
    /// The robot's loop: a tick every period until `stop` is set. A camera that falls
    /// silent makes the control loop publish stops; it picks up again when frames return.
    /// `on_event` hears of silences, returns and restarts as they happen (from counters the
    /// loop keeps anyway: nothing is built per tick).
    /// `policy_files` are looked at once a second ([`PolicyFileWatch`]).
    pub fn run_fixed_rate(
        &mut self,
        stop: &AtomicBool,
        policy_files: &mut [PolicyFileWatch],
        mut on_event: impl FnMut(NodeEvent),
    ) -> Result<(), TransportError> {
        let mut silent = false;
        let mut restarts = self.restarts();
        let mut ticks = 0u64;
        while !stop.load(Ordering::Acquire) {
            ticks += 1;
            if ticks.is_multiple_of(POLICY_FILE_POLL_TICKS) {
                for (file, watch) in policy_files.iter_mut().enumerate() {
                    if watch.changed() {
                        on_event(NodeEvent::PolicyFileChanged { file });
                    }
                }
            }
            let command = self.serve_tick()?;
            if command.is_stop() && !silent && self.control.counters().camera_stops > 0 {
                silent = true;
                on_event(NodeEvent::CamerasSilent);
            } else if silent && command.is_new() && !command.is_stop() {
                silent = false;
                on_event(NodeEvent::CamerasBack);
            }
            let now_restarts = self.restarts();
            if now_restarts != restarts {
                restarts = now_restarts;
                on_event(NodeEvent::CameraResynced);
            }
            self.control.wait_for_next_tick();
        }
        Ok(())
    }

    fn restarts(&self) -> u64 {
        self.control.sync_counters().restarts.iter().sum()
    }
}

impl<P: Policy, T: ControllerPorts> ControllerNode<P, ManualClock, T> {
    /// The lock-step loop: each tick of the simulator runs one controller tick at the
    /// simulator's time, and the command answers it. When no tick comes for longer than the
    /// camera silence limit (the simulator died, or has not started), a stop is published
    /// every tick period of wall time until ticks return. Runs until `stop` is set.
    pub fn run_lock_step(
        &mut self,
        stop: &AtomicBool,
        mut on_event: impl FnMut(NodeEvent),
    ) -> Result<(), TransportError> {
        let period = self.control.config().tick_period;
        let silence = self.control.config().sync.silence_limit();
        let clock = self.control.clock().clone();
        let mut episode = None;
        let mut last_heard = Instant::now();
        let mut silent = false;
        while !stop.load(Ordering::Acquire) {
            match self.ports.next_tick(period)? {
                Some(tick) => {
                    if silent {
                        silent = false;
                        on_event(NodeEvent::SimulatorBack);
                    }
                    if tick.starts_episode(episode) {
                        self.control.reset_episode();
                        clock.restart_at(tick.time());
                        episode = Some(tick.episode);
                        self.counters.episodes += 1;
                        on_event(NodeEvent::EpisodeStarted {
                            episode: tick.episode,
                        });
                    }
                    clock.set(tick.time());
                    self.serve_tick()?;
                    self.counters.lock_step_ticks += 1;
                    last_heard = Instant::now();
                }
                None if last_heard.elapsed() > silence => {
                    if !silent {
                        silent = true;
                        on_event(NodeEvent::SimulatorSilent);
                    }
                    let command = self.control.watchdog_stop();
                    self.ports.publish(&command)?;
                    self.counters.watchdog_stops += 1;
                }
                None => {}
            }
        }
        Ok(())
    }
}
