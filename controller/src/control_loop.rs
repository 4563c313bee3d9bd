//! The controller tick: frames → sync → thumbnails → policy → command, at a fixed rate.
//!
//! Everything the tick touches is allocated in [`ControlLoop::new`]; a tick itself allocates
//! nothing. Each accepted frame is downscaled as it arrives, so the loop never holds on to a
//! camera buffer (a shared-memory sample can go back to the driver at once) and the policy
//! runs on the thumbnails of the newest frame of each camera.

use core::time::Duration;
use std::time::Instant;

use crate::camera_sync::{CameraSync, StopReason, SyncConfig, SyncCounters, SyncDecision};
use crate::clock::Clock;
use crate::frame::{BottomFrame, CameraFrame, CameraPosition, TopFrame};
use crate::motion_command::{CommandFlags, MotionCommand};
use crate::policy::{Policy, PolicyError, PolicyInput};
use crate::speed_command::SpeedCommand;
use crate::thumbnail::{BottomThumbnail, Thumbnail, TopThumbnail, downscale};
use crate::tick_stats::TickStats;
use crate::units::Timestamp;

/// Rates and limits of the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopConfig {
    /// Time between two ticks: 10 ms, the 100 Hz of a Nao motion cycle, so a new pair of
    /// camera frames is picked up within a tick of its arrival.
    pub tick_period: Duration,
    /// Time one tick may take on the robot.
    pub budget: Duration,
    pub sync: SyncConfig,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            tick_period: Duration::from_millis(10),
            budget: Duration::from_millis(2),
            sync: SyncConfig::default(),
        }
    }
}

/// The frames that arrived since the last tick, newest per camera, borrowed for the tick.
#[derive(Clone, Copy, Debug, Default)]
pub struct CameraInput<'a> {
    pub top: Option<&'a TopFrame>,
    pub bottom: Option<&'a BottomFrame>,
}

/// What the loop did, counted since start-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LoopCounters {
    pub ticks: u64,
    /// Commands computed by the policy from a new pair of frames.
    pub new_commands: u64,
    pub repeated_commands: u64,
    /// Stop commands of every cause, repeated ones included.
    pub stops: u64,
    /// Stops because a camera had not delivered yet or fell silent.
    pub camera_stops: u64,
    pub policy_failures: u64,
    /// Policy outputs with a NaN or infinity, replaced by a stop.
    pub non_finite_outputs: u64,
    /// Frames whose header did not describe a YUYV frame of their camera's size.
    pub invalid_frames: u64,
    /// Frames stamped after the tick's time: left from before an episode restart (a
    /// simulator's last frames, queued but never consumed), or a clock fault. Refused, so a
    /// command is never computed from another episode's image.
    pub future_frames: u64,
    /// Ticks that started after their deadline had already passed.
    pub deadline_misses: u64,
}

/// The robot's control loop around a policy `P`, timed by a clock `C`.
#[derive(Debug)]
pub struct ControlLoop<P, C> {
    config: LoopConfig,
    policy: P,
    clock: C,
    sync: CameraSync,
    top: Box<TopThumbnail>,
    bottom: Box<BottomThumbnail>,
    last_command: MotionCommand,
    next_sequence: u64,
    next_deadline: Option<Timestamp>,
    counters: LoopCounters,
    stats: Box<TickStats>,
    last_stop: Option<StopReason>,
    last_policy_error: Option<PolicyError>,
}

impl<P: Policy, C: Clock> ControlLoop<P, C> {
    pub fn new(config: LoopConfig, policy: P, clock: C) -> Self {
        Self {
            config,
            policy,
            clock,
            sync: CameraSync::new(config.sync),
            top: Box::new(Thumbnail::black()),
            bottom: Box::new(Thumbnail::black()),
            last_command: MotionCommand::initial_stop(),
            next_sequence: 0,
            next_deadline: None,
            counters: LoopCounters::default(),
            stats: Box::new(TickStats::new(config.budget)),
            last_stop: None,
            last_policy_error: None,
        }
    }

    /// One tick: takes the newest frames, and publishes a new, repeated or stop command.
    pub fn tick(&mut self, input: CameraInput<'_>) -> MotionCommand {
        // Tick time is wall time whatever the clock: a simulated clock stands still during a tick.
        let stopwatch = Instant::now();
        let started = self.clock.now();
        if let Some(frame) = input.top
            && self.accept(CameraPosition::Top, frame, started)
        {
            downscale(frame, &mut self.top);
        }
        if let Some(frame) = input.bottom
            && self.accept(CameraPosition::Bottom, frame, started)
        {
            downscale(frame, &mut self.bottom);
        }
        let command = match self.sync.decide(started) {
            SyncDecision::Compute {
                top_sequence,
                bottom_sequence,
            } => self.compute(started, top_sequence, bottom_sequence),
            SyncDecision::Repeat => self.repeat(started),
            SyncDecision::Stop(reason) => {
                self.counters.camera_stops += 1;
                self.last_stop = Some(reason);
                self.stop(
                    started,
                    self.last_command.top_sequence,
                    self.last_command.bottom_sequence,
                )
            }
        };
        self.counters.ticks += 1;
        if command.is_stop() {
            self.counters.stops += 1;
        }
        self.last_command = command;
        self.stats.record(stopwatch.elapsed());
        command
    }

    /// A stop published when no tick could run: the source of time and frames (a lock-step
    /// simulator) fell silent. It is counted, but changes nothing the next tick decides on,
    /// so a simulator that was only slow carries on exactly where it was.
    pub fn watchdog_stop(&mut self) -> MotionCommand {
        let now = self.clock.now();
        let last = self.last_command;
        self.counters.stops += 1;
        self.counters.camera_stops += 1;
        self.command(
            now,
            last.top_sequence,
            last.bottom_sequence,
            SpeedCommand::STOP,
            CommandFlags::STOP.union(CommandFlags::WATCHDOG),
        )
    }

    /// Waits for the next tick's deadline. Deadlines are a fixed grid from the first call;
    /// when a tick ran past one or more of them they are skipped and counted as misses.
    pub fn wait_for_next_tick(&mut self) {
        let now = self.clock.now();
        let period = self.config.tick_period;
        let mut deadline = self.next_deadline.map_or(now + period, |d| d + period);
        if now >= deadline {
            self.counters.deadline_misses += 1;
            let late = now.saturating_since(deadline);
            let skipped = late.as_nanos() / period.as_nanos().max(1) + 1;
            deadline = deadline + period * u32::try_from(skipped).unwrap_or(u32::MAX);
        }
        self.next_deadline = Some(deadline);
        self.clock.sleep_until(deadline);
    }

    /// Starts a new episode, as if the robot were switched on afresh: the policy forgets its
    /// state, the cameras are waited for again and the robot stands until both deliver.
    /// Command sequence numbers, counters and statistics go on.
    pub fn reset_episode(&mut self) {
        self.policy.reset();
        self.sync.reset();
        let sequence = self.last_command.sequence;
        self.last_command = MotionCommand {
            sequence,
            ..MotionCommand::initial_stop()
        };
        self.next_deadline = None;
    }

    /// Whether `frame` is valid and newer than this camera's newest frame.
    fn accept<const W: usize, const H: usize>(
        &mut self,
        camera: CameraPosition,
        frame: &CameraFrame<W, H>,
        now: Timestamp,
    ) -> bool {
        if CameraFrame::<W, H>::check_header(frame.header()).is_err() {
            self.counters.invalid_frames += 1;
            return false;
        }
        if frame.header().timestamp_ns > now.as_nanos() {
            self.counters.future_frames += 1;
            return false;
        }
        self.sync
            .offer(camera, frame.header().sequence, now)
            .is_accepted()
    }

    fn compute(
        &mut self,
        now: Timestamp,
        top_sequence: u64,
        bottom_sequence: u64,
    ) -> MotionCommand {
        // The last command a tick published (a stop after a failed step or silent cameras,
        // and from an episode's start until the first computed one). A watchdog stop is not
        // a tick's: it changes nothing the next tick decides on.
        let input = PolicyInput {
            top: &self.top,
            bottom: &self.bottom,
            previous: self.last_command.speed,
        };
        let output = match self.policy.step(input) {
            Ok(output) => output,
            Err(error) => {
                self.counters.policy_failures += 1;
                self.last_policy_error = Some(error);
                return self
                    .stop(now, top_sequence, bottom_sequence)
                    .with_flag(CommandFlags::NEW);
            }
        };
        match SpeedCommand::new(output.forward, output.left, output.turn) {
            Ok(speed) => {
                self.counters.new_commands += 1;
                self.command(now, top_sequence, bottom_sequence, speed, CommandFlags::NEW)
            }
            Err(_) => {
                self.counters.non_finite_outputs += 1;
                self.stop(now, top_sequence, bottom_sequence)
                    .with_flag(CommandFlags::NEW)
            }
        }
    }

    fn repeat(&mut self, now: Timestamp) -> MotionCommand {
        self.counters.repeated_commands += 1;
        let last = self.last_command;
        let flags = if last.is_stop() {
            CommandFlags::REPEATED.union(CommandFlags::STOP)
        } else {
            CommandFlags::REPEATED
        };
        self.command(
            now,
            last.top_sequence,
            last.bottom_sequence,
            last.speed,
            flags,
        )
    }

    fn stop(&mut self, now: Timestamp, top_sequence: u64, bottom_sequence: u64) -> MotionCommand {
        self.command(
            now,
            top_sequence,
            bottom_sequence,
            SpeedCommand::STOP,
            CommandFlags::STOP,
        )
    }

    fn command(
        &mut self,
        now: Timestamp,
        top_sequence: u64,
        bottom_sequence: u64,
        speed: SpeedCommand,
        flags: CommandFlags,
    ) -> MotionCommand {
        let sequence = self.next_sequence;
        self.next_sequence += 1;
        MotionCommand {
            sequence,
            timestamp_ns: now.as_nanos(),
            top_sequence,
            bottom_sequence,
            speed,
            flags,
        }
    }

    pub fn config(&self) -> &LoopConfig {
        &self.config
    }

    pub fn counters(&self) -> &LoopCounters {
        &self.counters
    }

    pub fn sync_counters(&self) -> &SyncCounters {
        self.sync.counters()
    }

    pub fn tick_stats(&self) -> &TickStats {
        &self.stats
    }

    pub fn last_command(&self) -> &MotionCommand {
        &self.last_command
    }

    /// Why the last camera stop happened, if one did.
    pub fn last_stop_reason(&self) -> Option<StopReason> {
        self.last_stop
    }

    /// The error of the last failed policy step, if one failed.
    pub fn last_policy_error(&self) -> Option<&PolicyError> {
        self.last_policy_error.as_ref()
    }

    /// The thumbnails of the newest accepted frames, as the policy saw or will see them.
    pub fn thumbnails(&self) -> (&TopThumbnail, &BottomThumbnail) {
        (&self.top, &self.bottom)
    }

    pub fn policy(&self) -> &P {
        &self.policy
    }

    pub fn clock(&self) -> &C {
        &self.clock
    }
}

impl MotionCommand {
    fn with_flag(mut self, flag: CommandFlags) -> Self {
        self.flags = self.flags.union(flag);
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::motion_command::NO_FRAME;
    use crate::policy::{BrightnessPolicy, PolicyOutput};
    use crate::test_pattern::TestPattern;

    /// Returns the outputs it is given, in turn, and counts resets.
    #[derive(Debug, Default)]
    struct ScriptedPolicy {
        outputs: Vec<Result<PolicyOutput, &'static str>>,
        steps: usize,
        resets: usize,
        /// The last command each step was given.
        previous: Vec<SpeedCommand>,
    }

    impl Policy for ScriptedPolicy {
        fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
            self.previous.push(input.previous);
            let output = self.outputs[self.steps % self.outputs.len()];
            self.steps += 1;
            output.map_err(|message| PolicyError::Inference(message.to_owned()))
        }

        fn reset(&mut self) {
            self.resets += 1;
        }
    }

    fn forward(speed: f32) -> Result<PolicyOutput, &'static str> {
        Ok(PolicyOutput {
            forward: speed,
            left: 0.0,
            turn: 0.0,
        })
    }

    struct Rig<P> {
        control: ControlLoop<P, ManualClock>,
        clock: ManualClock,
        top: Box<TopFrame>,
        bottom: Box<BottomFrame>,
    }

    impl<P: Policy> Rig<P> {
        fn new(policy: P) -> Self {
            let clock = ManualClock::default();
            let pattern = TestPattern::default();
            let mut top = TopFrame::new_boxed();
            let mut bottom = BottomFrame::new_boxed();
            pattern.paint(&mut top, 0, Timestamp::ZERO);
            pattern.paint(&mut bottom, 0, Timestamp::ZERO);
            Self {
                control: ControlLoop::new(LoopConfig::default(), policy, clock.clone()),
                clock,
                top,
                bottom,
            }
        }

        /// Advances 10 ms and ticks with the frames whose sequence numbers are given.
        fn tick(&mut self, top: Option<u64>, bottom: Option<u64>) -> MotionCommand {
            self.clock.advance(Duration::from_millis(10));
            let now = self.clock.now();
            if let Some(sequence) = top {
                self.top.restamp(sequence, now);
            }
            if let Some(sequence) = bottom {
                self.bottom.restamp(sequence, now);
            }
            let input = CameraInput {
                top: top.map(|_| &*self.top),
                bottom: bottom.map(|_| &*self.bottom),
            };
            self.control.tick(input)
        }
    }

    #[test]
    fn publishes_a_stop_every_tick_until_both_cameras_deliver() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![forward(0.5)],
            ..Default::default()
        });
        let first = rig.tick(None, None);
        assert!(first.is_stop() && !first.is_new());
        assert_eq!(
            (first.top_sequence, first.bottom_sequence),
            (NO_FRAME, NO_FRAME)
        );
        assert!(rig.tick(Some(0), None).is_stop());
        let computed = rig.tick(None, Some(0));
        assert!(computed.is_new() && !computed.is_stop());
        assert_eq!(computed.speed.forward(), 0.5);
        assert_eq!(rig.control.counters().camera_stops, 2);
        assert_eq!(rig.control.policy().steps, 1);
    }

    #[test]
    fn each_step_is_given_the_command_published_last_clamped_a_stop_after_a_failure() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![
                Ok(PolicyOutput {
                    forward: 2.0,
                    left: -0.5,
                    turn: 0.25,
                }),
                Err("no answer"),
                forward(0.5),
                forward(0.75),
            ],
            ..Default::default()
        });
        for sequence in 0..3 {
            rig.tick(Some(sequence), Some(sequence));
        }
        rig.control.reset_episode();
        rig.tick(Some(3), Some(3));
        let clamped = SpeedCommand::new(1.0, -0.5, 0.25).expect("finite");
        assert_eq!(
            rig.control.policy().previous,
            [
                SpeedCommand::STOP,
                clamped,
                SpeedCommand::STOP,
                SpeedCommand::STOP
            ],
            "first step, then the clamped command, a stop after the failed step, a stop \
             after the episode's reset (its last command was forward 0.5)"
        );
    }

    #[test]
    fn repeats_the_last_command_until_a_new_pair_arrives() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![forward(0.25), forward(0.75)],
            ..Default::default()
        });
        let new = rig.tick(Some(0), Some(0));
        let repeated = rig.tick(Some(1), None);
        assert!(repeated.is_repeated() && !repeated.is_new());
        assert_eq!(repeated.speed, new.speed);
        assert_eq!((repeated.top_sequence, repeated.bottom_sequence), (0, 0));
        assert_eq!(repeated.sequence, new.sequence + 1);
        let next = rig.tick(None, Some(1));
        assert!(next.is_new());
        assert_eq!(next.speed.forward(), 0.75);
        assert_eq!((next.top_sequence, next.bottom_sequence), (1, 1));
        let counters = rig.control.counters();
        assert_eq!((counters.new_commands, counters.repeated_commands), (2, 1));
    }

    #[test]
    fn a_non_finite_output_becomes_a_counted_stop() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![Ok(PolicyOutput {
                forward: 0.1,
                left: f32::NAN,
                turn: 0.0,
            })],
            ..Default::default()
        });
        let command = rig.tick(Some(0), Some(0));
        assert!(command.is_stop() && command.is_new());
        assert!(command.speed.is_stop());
        assert_eq!(rig.control.counters().non_finite_outputs, 1);
        let repeated = rig.tick(None, None);
        assert!(repeated.is_stop() && repeated.is_repeated());
        assert_eq!(rig.control.counters().stops, 2);
    }

    #[test]
    fn a_failed_inference_becomes_a_counted_stop_and_keeps_its_error() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![Err("engine on fire"), forward(1.0)],
            ..Default::default()
        });
        assert!(rig.tick(Some(0), Some(0)).is_stop());
        assert_eq!(rig.control.counters().policy_failures, 1);
        assert_eq!(
            rig.control
                .last_policy_error()
                .map(ToString::to_string)
                .as_deref(),
            Some("inference failed: engine on fire")
        );
        let recovered = rig.tick(Some(1), Some(1));
        assert!(!recovered.is_stop());
        assert_eq!(recovered.speed.forward(), 1.0);
    }

    #[test]
    fn out_of_range_outputs_are_clamped() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![forward(7.0)],
            ..Default::default()
        });
        assert_eq!(rig.tick(Some(0), Some(0)).speed.forward(), 1.0);
    }

    #[test]
    fn a_frame_from_before_an_episode_restart_is_refused() {
        let mut rig = Rig::new(BrightnessPolicy::default());
        for sequence in 0..50 {
            rig.tick(Some(sequence), Some(sequence));
        }
        // The simulator starts a new episode: the clock goes back, and the last frame of the
        // old episode, stamped at its time, is still queued for the top camera.
        let stale_time = rig.clock.now();
        rig.control.reset_episode();
        rig.clock.restart_at(Timestamp::ZERO);
        rig.top.restamp(976, stale_time);
        rig.bottom.restamp(0, Timestamp::ZERO);
        let command = rig.control.tick(CameraInput {
            top: Some(&rig.top),
            bottom: Some(&rig.bottom),
        });
        assert!(command.is_stop(), "computed from the old episode's image");
        assert_eq!(rig.control.counters().future_frames, 1);
        // The new episode's own frames are taken.
        rig.clock.advance(Duration::from_millis(10));
        rig.top.restamp(0, rig.clock.now());
        let command = rig.control.tick(CameraInput {
            top: Some(&rig.top),
            bottom: None,
        });
        assert!(command.is_new(), "{command:?}");
        assert_eq!((command.top_sequence, command.bottom_sequence), (0, 0));
    }

    #[test]
    fn a_frame_with_a_bad_header_is_ignored_and_counted() {
        let mut rig = Rig::new(BrightnessPolicy::default());
        // A producer writing in place (shared memory) can leave any header behind.
        rig.bottom.header_mut().format = u32::from_le_bytes(*b"MJPG");
        let input = CameraInput {
            top: Some(&rig.top),
            bottom: Some(&rig.bottom),
        };
        let command = rig.control.tick(input);
        assert!(command.is_stop(), "the bottom frame did not count");
        assert_eq!(rig.control.counters().invalid_frames, 1);
        assert_eq!(rig.control.sync_counters().accepted, [1, 0]);
    }

    #[test]
    fn stops_when_a_camera_falls_silent_and_resumes_when_it_returns() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![forward(0.5)],
            ..Default::default()
        });
        rig.tick(Some(0), Some(0));
        // Only the top camera for 150 ms: within 100 ms the robot must stop.
        let mut commands = Vec::new();
        for sequence in 1..=15 {
            commands.push(rig.tick(Some(sequence), None));
        }
        let first_stop = commands.iter().position(MotionCommand::is_stop);
        assert_eq!(
            first_stop,
            Some(9),
            "stops on the first tick past 100 ms of silence"
        );
        assert!(commands[9..].iter().all(MotionCommand::is_stop));
        assert_eq!(
            rig.control.last_stop_reason(),
            Some(StopReason::Silent(CameraPosition::Bottom))
        );
        let resumed = rig.tick(Some(16), Some(1));
        assert!(resumed.is_new() && !resumed.is_stop());
    }

    #[test]
    fn the_thumbnails_are_those_of_the_newest_frames() {
        let mut rig = Rig::new(BrightnessPolicy::default());
        rig.tick(Some(0), Some(0));
        rig.top.as_bytes_mut().fill(200);
        rig.tick(Some(1), None);
        let (top, bottom) = rig.control.thumbnails();
        assert!(top.as_bytes().iter().all(|&p| p == 200));
        assert!(bottom.as_bytes().iter().any(|&p| p != 200));
    }

    #[test]
    fn reset_episode_starts_afresh_like_a_new_loop() {
        let script = || ScriptedPolicy {
            outputs: vec![forward(0.5)],
            ..Default::default()
        };
        let mut used = Rig::new(script());
        used.tick(Some(7), Some(7));
        used.tick(Some(8), None);
        used.control.reset_episode();
        assert_eq!(used.control.policy().resets, 1);
        let mut fresh = Rig::new(script());
        // Sequence numbers restart with the new episode's camera, and nothing is repeated
        // from the last episode: both loops now behave the same.
        for frames in [(Some(0), None), (None, Some(0)), (Some(1), None)] {
            let (a, b) = (
                used.tick(frames.0, frames.1),
                fresh.tick(frames.0, frames.1),
            );
            assert_eq!((a.speed, a.flags), (b.speed, b.flags), "{frames:?}");
            assert_eq!(
                (a.top_sequence, a.bottom_sequence),
                (b.top_sequence, b.bottom_sequence)
            );
        }
    }

    #[test]
    fn a_watchdog_stop_leaves_the_next_decision_alone() {
        let mut rig = Rig::new(ScriptedPolicy {
            outputs: vec![forward(0.5)],
            ..Default::default()
        });
        let computed = rig.tick(Some(0), Some(0));
        let stop = rig.control.watchdog_stop();
        assert!(stop.is_stop() && stop.speed.is_stop());
        assert_eq!(stop.sequence, computed.sequence + 1);
        let repeated = rig.tick(None, None);
        assert!(repeated.is_repeated() && !repeated.is_stop());
        assert_eq!(repeated.speed, computed.speed);
        assert_eq!(rig.control.counters().camera_stops, 1);
    }

    #[test]
    fn ticks_keep_a_fixed_grid_and_count_missed_deadlines() {
        let clock = ManualClock::default();
        let mut control = ControlLoop::new(
            LoopConfig::default(),
            BrightnessPolicy::default(),
            clock.clone(),
        );
        let ms = |n: u64| Timestamp::from_nanos(n * 1_000_000);
        control.wait_for_next_tick();
        assert_eq!(clock.now(), ms(10));
        clock.advance(Duration::from_millis(3)); // a 3 ms tick
        control.wait_for_next_tick();
        assert_eq!(
            clock.now(),
            ms(20),
            "the grid does not drift with tick length"
        );
        clock.advance(Duration::from_millis(25)); // a tick that overran two deadlines
        control.wait_for_next_tick();
        assert_eq!(
            clock.now(),
            ms(50),
            "the missed deadlines at 30 and 40 ms are skipped"
        );
        assert_eq!(control.counters().deadline_misses, 1);
    }
}
