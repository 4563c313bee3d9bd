//! The paper's synchronisation rule for the two head cameras.
//!
//! A command is computed only when both cameras delivered a new frame since the last
//! computed command; otherwise the last command repeats. Each camera is tracked on its own,
//! so one camera dropping frames only delays the next pair until its next frame arrives,
//! and the pair then uses the newest frame of each.
//!
//! Sequence numbers must increase per camera: a repeated number is a duplicate and a smaller
//! one is out of order; both are rejected and counted, so a command is never computed from
//! a frame older than one already used. A camera silent for more than `silence_periods`
//! camera periods stops the robot. A camera heard again after such a silence is taken as
//! restarted (a new driver or simulator), and its sequence numbers start afresh.

use core::time::Duration;

use crate::frame::CameraPosition;
use crate::units::Timestamp;

/// Timing of the cameras, as DESIGN.md states it: 30 Hz each, silent after 3 periods.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SyncConfig {
    /// Time between two frames of one camera.
    pub camera_period: Duration,
    /// A camera not heard from for more than this many periods is silent.
    pub silence_periods: u32,
}

impl Default for SyncConfig {
    fn default() -> Self {
        Self {
            camera_period: Duration::from_nanos(1_000_000_000 / 30),
            silence_periods: 3,
        }
    }
}

impl SyncConfig {
    /// How long a camera may be quiet before the robot stops.
    pub fn silence_limit(&self) -> Duration {
        self.camera_period * self.silence_periods
    }
}

/// What happened to a frame offered to the synchroniser.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameVerdict {
    /// Newer than every frame seen before: it is this camera's newest frame now.
    Accepted,
    /// The first frame after a silence, accepted whatever its sequence number.
    AcceptedAfterRestart,
    /// Same sequence number as the newest frame.
    Duplicate,
    /// Older than the newest frame.
    OutOfOrder,
}

impl FrameVerdict {
    pub const fn is_accepted(self) -> bool {
        matches!(self, Self::Accepted | Self::AcceptedAfterRestart)
    }
}

/// Why the robot must stop instead of acting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// This camera has not delivered a frame yet.
    NoFrameYet(CameraPosition),
    /// This camera has been silent for longer than the silence limit.
    Silent(CameraPosition),
}

/// What the tick should do now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SyncDecision {
    /// Both cameras have a new frame: compute a command from these two.
    Compute {
        top_sequence: u64,
        bottom_sequence: u64,
    },
    /// No new pair: repeat the last command.
    Repeat,
    /// Publish a stop.
    Stop(StopReason),
}

/// Counts of what the synchroniser saw, per camera where it applies (index: top 0, bottom 1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SyncCounters {
    pub accepted: [u64; 2],
    pub duplicates: [u64; 2],
    pub out_of_order: [u64; 2],
    pub restarts: [u64; 2],
    pub computed: u64,
    pub repeated: u64,
    pub stopped: u64,
}

#[derive(Clone, Copy, Debug, Default)]
struct CameraTrack {
    /// Sequence and arrival time of the newest accepted frame.
    newest: Option<(u64, Timestamp)>,
    /// Sequence of the frame the last computed command used, since the last restart.
    used: Option<u64>,
}

impl CameraTrack {
    fn is_silent(&self, now: Timestamp, limit: Duration) -> bool {
        self.newest
            .is_some_and(|(_, arrived)| now.saturating_since(arrived) > limit)
    }

    fn has_unused_frame(&self) -> bool {
        self.newest
            .is_some_and(|(sequence, _)| Some(sequence) != self.used)
    }
}

/// Decides, tick by tick, whether to compute a command, repeat the last one, or stop.
#[derive(Clone, Debug, Default)]
pub struct CameraSync {
    config: SyncConfig,
    tracks: [CameraTrack; 2],
    counters: SyncCounters,
}

impl CameraSync {
    pub fn new(config: SyncConfig) -> Self {
        Self {
            config,
            tracks: Default::default(),
            counters: SyncCounters::default(),
        }
    }

    pub fn config(&self) -> &SyncConfig {
        &self.config
    }

    pub fn counters(&self) -> &SyncCounters {
        &self.counters
    }

    /// Forgets both cameras, as after a restart of the driver (a new episode in simulation):
    /// the next frames are accepted whatever their sequence. Counters go on.
    pub fn reset(&mut self) {
        self.tracks = Default::default();
    }

    /// Offers a frame of `camera` with `sequence` that arrived at `now`.
    pub fn offer(&mut self, camera: CameraPosition, sequence: u64, now: Timestamp) -> FrameVerdict {
        let limit = self.config.silence_limit();
        let i = camera.index();
        let track = &mut self.tracks[i];
        let verdict = match track.newest {
            None => FrameVerdict::Accepted,
            Some(_) if track.is_silent(now, limit) => FrameVerdict::AcceptedAfterRestart,
            Some((newest, _)) if sequence > newest => FrameVerdict::Accepted,
            Some((newest, _)) if sequence == newest => FrameVerdict::Duplicate,
            Some(_) => FrameVerdict::OutOfOrder,
        };
        match verdict {
            FrameVerdict::Accepted => self.counters.accepted[i] += 1,
            FrameVerdict::AcceptedAfterRestart => {
                self.counters.accepted[i] += 1;
                self.counters.restarts[i] += 1;
                track.used = None;
            }
            FrameVerdict::Duplicate => self.counters.duplicates[i] += 1,
            FrameVerdict::OutOfOrder => self.counters.out_of_order[i] += 1,
        }
        if verdict.is_accepted() {
            track.newest = Some((sequence, now));
        }
        verdict
    }

    /// The decision for a tick at `now`. A `Compute` marks both newest frames as used.
    pub fn decide(&mut self, now: Timestamp) -> SyncDecision {
        let decision = self.decision_at(now);
        match decision {
            SyncDecision::Compute {
                top_sequence,
                bottom_sequence,
            } => {
                self.tracks[CameraPosition::Top.index()].used = Some(top_sequence);
                self.tracks[CameraPosition::Bottom.index()].used = Some(bottom_sequence);
                self.counters.computed += 1;
            }
            SyncDecision::Repeat => self.counters.repeated += 1,
            SyncDecision::Stop(_) => self.counters.stopped += 1,
        }
        decision
    }

    fn decision_at(&self, now: Timestamp) -> SyncDecision {
        let limit = self.config.silence_limit();
        for camera in CameraPosition::ALL {
            let track = &self.tracks[camera.index()];
            if track.newest.is_none() {
                return SyncDecision::Stop(StopReason::NoFrameYet(camera));
            }
            if track.is_silent(now, limit) {
                return SyncDecision::Stop(StopReason::Silent(camera));
            }
        }
        let [top, bottom] = &self.tracks;
        match (top.newest, bottom.newest) {
            (Some((top_sequence, _)), Some((bottom_sequence, _)))
                if top.has_unused_frame() && bottom.has_unused_frame() =>
            {
                SyncDecision::Compute {
                    top_sequence,
                    bottom_sequence,
                }
            }
            _ => SyncDecision::Repeat,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use CameraPosition::{Bottom, Top};
    use proptest::prelude::*;

    const MS: u64 = 1_000_000;

    fn at(ms: u64) -> Timestamp {
        Timestamp::from_nanos(ms * MS)
    }

    #[test]
    fn stops_until_both_cameras_have_delivered() {
        let mut sync = CameraSync::new(SyncConfig::default());
        assert_eq!(
            sync.decide(at(0)),
            SyncDecision::Stop(StopReason::NoFrameYet(Top))
        );
        sync.offer(Top, 0, at(1));
        assert_eq!(
            sync.decide(at(2)),
            SyncDecision::Stop(StopReason::NoFrameYet(Bottom))
        );
        sync.offer(Bottom, 0, at(17));
        assert_eq!(
            sync.decide(at(18)),
            SyncDecision::Compute {
                top_sequence: 0,
                bottom_sequence: 0
            }
        );
    }

    #[test]
    fn repeats_last_command_until_both_cameras_are_new() {
        let mut sync = CameraSync::new(SyncConfig::default());
        sync.offer(Top, 0, at(0));
        sync.offer(Bottom, 0, at(16));
        assert!(matches!(sync.decide(at(17)), SyncDecision::Compute { .. }));
        assert_eq!(sync.decide(at(20)), SyncDecision::Repeat);
        sync.offer(Top, 1, at(33));
        assert_eq!(sync.decide(at(34)), SyncDecision::Repeat, "only top is new");
        sync.offer(Bottom, 1, at(50));
        assert_eq!(
            sync.decide(at(51)),
            SyncDecision::Compute {
                top_sequence: 1,
                bottom_sequence: 1
            }
        );
        assert_eq!(sync.counters().computed, 2);
        assert_eq!(sync.counters().repeated, 2);
    }

    #[test]
    fn a_camera_dropping_frames_does_not_freeze_the_other() {
        let mut sync = CameraSync::new(SyncConfig::default());
        sync.offer(Top, 0, at(0));
        sync.offer(Bottom, 0, at(16));
        sync.decide(at(17));
        // The bottom camera drops frames 1 and 2; the top keeps going.
        sync.offer(Top, 1, at(33));
        sync.offer(Top, 2, at(66));
        assert_eq!(sync.decide(at(67)), SyncDecision::Repeat);
        sync.offer(Bottom, 3, at(83));
        assert_eq!(
            sync.decide(at(84)),
            SyncDecision::Compute {
                top_sequence: 2,
                bottom_sequence: 3
            },
            "the newest top frame pairs with the bottom camera's next frame"
        );
    }

    #[test]
    fn rejects_and_counts_duplicates_and_out_of_order_frames() {
        let mut sync = CameraSync::new(SyncConfig::default());
        assert_eq!(sync.offer(Top, 5, at(0)), FrameVerdict::Accepted);
        assert_eq!(sync.offer(Top, 5, at(1)), FrameVerdict::Duplicate);
        assert_eq!(sync.offer(Top, 4, at(2)), FrameVerdict::OutOfOrder);
        assert_eq!(sync.offer(Bottom, 9, at(3)), FrameVerdict::Accepted);
        assert_eq!(
            sync.decide(at(4)),
            SyncDecision::Compute {
                top_sequence: 5,
                bottom_sequence: 9
            }
        );
        // A late copy of an older frame must not count as new.
        assert_eq!(sync.offer(Bottom, 8, at(5)), FrameVerdict::OutOfOrder);
        sync.offer(Top, 6, at(6));
        assert_eq!(sync.decide(at(7)), SyncDecision::Repeat);
        let counters = sync.counters();
        assert_eq!(counters.duplicates, [1, 0]);
        assert_eq!(counters.out_of_order, [1, 1]);
        assert_eq!(counters.accepted, [2, 1]);
    }

    #[test]
    fn stops_after_three_silent_periods() {
        let config = SyncConfig::default();
        let limit_ms = config.silence_limit().as_millis() as u64;
        assert_eq!(limit_ms, 99, "3 periods of 33.3 ms");
        let mut sync = CameraSync::new(config);
        sync.offer(Top, 0, at(0));
        sync.offer(Bottom, 0, at(0));
        sync.decide(at(1));
        // The top keeps delivering; the bottom goes silent.
        for (sequence, ms) in (1..).zip((33..=99).step_by(33)) {
            sync.offer(Top, sequence, at(ms));
        }
        assert_eq!(
            sync.decide(at(99)),
            SyncDecision::Repeat,
            "still within the limit"
        );
        assert_eq!(
            sync.decide(at(101)),
            SyncDecision::Stop(StopReason::Silent(Bottom))
        );
        assert_eq!(sync.counters().stopped, 1);
    }

    #[test]
    fn a_restarted_camera_is_followed_from_its_new_sequence_numbers() {
        let mut sync = CameraSync::new(SyncConfig::default());
        sync.offer(Top, 500, at(0));
        sync.offer(Bottom, 500, at(0));
        sync.decide(at(1));
        // Both publishers die and come back, counting from zero again.
        assert_eq!(
            sync.offer(Top, 0, at(1000)),
            FrameVerdict::AcceptedAfterRestart
        );
        assert_eq!(
            sync.offer(Bottom, 0, at(1010)),
            FrameVerdict::AcceptedAfterRestart
        );
        assert_eq!(
            sync.decide(at(1011)),
            SyncDecision::Compute {
                top_sequence: 0,
                bottom_sequence: 0
            }
        );
        assert_eq!(sync.counters().restarts, [1, 1]);
    }

    #[derive(Clone, Debug)]
    enum Event {
        Frame {
            camera: CameraPosition,
            sequence: u64,
        },
        Tick,
    }

    fn event() -> impl Strategy<Value = (Event, u64)> {
        let frame = (any::<bool>(), 0u64..40).prop_map(|(top, sequence)| Event::Frame {
            camera: if top { Top } else { Bottom },
            sequence,
        });
        (prop_oneof![frame, Just(Event::Tick)], 0u64..60)
    }

    proptest! {
        /// Checked against a model written from DESIGN.md, not from the code: a camera's
        /// frame is taken if it is its first, or newer than its newest, or comes after more
        /// than 3 camera periods (of 1/30 s) without one (a restart: its numbers begin afresh).
        /// A command is computed from the newest frames, and never from a frame older than
        /// one already used since the camera's last restart.
        #[test]
        fn never_computes_from_a_frame_older_than_one_already_used(
            events in proptest::collection::vec(event(), 1..200)
        ) {
            let limit = Duration::from_secs(1) / 30 * 3;
            let mut sync = CameraSync::new(SyncConfig::default());
            let mut now = Timestamp::ZERO;
            // Per camera, the model: the newest taken frame and when it came; the sequence
            // the last computed command used since the camera's last restart.
            let mut newest: [Option<(u64, Timestamp)>; 2] = [None, None];
            let mut last_used: [Option<u64>; 2] = [None, None];
            for (event, advance_ms) in events {
                now = now + Duration::from_millis(advance_ms);
                match event {
                    Event::Frame { camera, sequence } => {
                        let i = camera.index();
                        let (taken, restart) = match newest[i] {
                            None => (true, false),
                            Some((_, came)) if now.saturating_since(came) > limit => (true, true),
                            Some((newest_sequence, _)) => (sequence > newest_sequence, false),
                        };
                        let verdict = sync.offer(camera, sequence, now);
                        prop_assert_eq!(verdict.is_accepted(), taken, "{:?} {} at {:?}", camera, sequence, now);
                        prop_assert_eq!(verdict == FrameVerdict::AcceptedAfterRestart, restart);
                        if restart {
                            last_used[i] = None;
                        }
                        if taken {
                            newest[i] = Some((sequence, now));
                        }
                    }
                    Event::Tick => match sync.decide(now) {
                        SyncDecision::Compute { top_sequence, bottom_sequence } => {
                            let sequences = [top_sequence, bottom_sequence];
                            for (i, sequence) in sequences.into_iter().enumerate() {
                                prop_assert_eq!(Some(sequence), newest[i].map(|(s, _)| s), "the newest frame");
                                if let Some(previous) = last_used[i] {
                                    prop_assert!(sequence > previous, "{} after {}", sequence, previous);
                                }
                                last_used[i] = Some(sequence);
                            }
                        }
                        SyncDecision::Repeat | SyncDecision::Stop(_) => {}
                    },
                }
            }
        }

        #[test]
        fn a_silent_camera_always_stops_the_robot(
            quiet_ms in 100u64..10_000, sequence in 0u64..1000
        ) {
            let mut sync = CameraSync::new(SyncConfig::default());
            sync.offer(Top, sequence, at(0));
            sync.offer(Bottom, sequence, at(0));
            let now = at(quiet_ms);
            prop_assert!(matches!(sync.decide(now), SyncDecision::Stop(StopReason::Silent(_))));
        }
    }
}
