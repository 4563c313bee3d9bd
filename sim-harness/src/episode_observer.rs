//! What an episode shows as it plays, handed to a viewer (an MCAP file, a live Foxglove
//! connection) on the simulated clock. The runner calls an [`EpisodeObserver`] at each event;
//! each method defaults to doing nothing, so an observer takes only what it shows.

use dribble_controller::{BottomFrame, CameraPosition, MotionCommand, Timestamp, TopFrame};
use glam::Vec2;

use crate::dataset::Outcome;
use crate::episode::EpisodeSetup;
use crate::pose::FieldPose;

/// Receives an episode's events in time order.
pub trait EpisodeObserver {
    /// The episode starts (simulated time zero).
    fn start(&mut self, _setup: &EpisodeSetup) {}

    /// `camera` took a frame at `time`; `top` and `bottom` are the newest frames of each
    /// camera (rendered when the episode renders, else only stamped).
    fn frame(
        &mut self,
        _time: Timestamp,
        _camera: CameraPosition,
        _top: &TopFrame,
        _bottom: &BottomFrame,
    ) {
    }

    /// The motion module received `command` at `time` (every motion cycle: a new command,
    /// a repeat, or a stop).
    fn command(&mut self, _time: Timestamp, _command: &MotionCommand) {}

    /// Where the robot and the ball are at `time` (every motion cycle).
    fn state(&mut self, _time: Timestamp, _robot: FieldPose, _ball: Vec2) {}

    /// The controller is about to tick at `time` with the robot and the ball here (every
    /// motion cycle, before the tick's command exists): the state a teacher beside the
    /// policy would label that command in.
    fn before_tick(&mut self, _time: Timestamp, _robot: FieldPose, _ball: Vec2) {}

    /// Whether the episode should stop now, unfinished (asked every motion cycle, after the
    /// tick): a Gymnasium `reset` in the middle of an episode. It then ends as
    /// [`Outcome::Abandoned`].
    fn abandon(&mut self) -> bool {
        false
    }

    /// The episode ended at `time` with `outcome`.
    fn end(&mut self, _time: Timestamp, _outcome: Outcome) {}
}

/// Shows nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoObserver;

impl EpisodeObserver for NoObserver {}
