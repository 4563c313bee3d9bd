//! The simulator's clock in lock-step simulation (service `dribble/sim/tick`).

use crate::units::Timestamp;

/// "Run a tick now": the simulator publishes one per motion cycle, after the frames that
/// became due, and waits for the command that answers it (the command whose `timestamp_ns`
/// is this tick's `time_ns`).
///
/// Layout, little-endian, 24 bytes on i686 and x86_64: `episode: u64` at 0, `index: u64` at
/// 8, `time_ns: u64` at 16.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LockStepTick {
    /// Identifies the episode. A tick of another episode, or a tick with index 0, starts a
    /// new episode: the controller resets as if the robot had been switched on.
    pub episode: u64,
    /// Counts this episode's ticks from 0.
    pub index: u64,
    /// Simulated time of the tick, nanoseconds from the episode's start, on the clock the
    /// episode's frames are stamped with.
    pub time_ns: u64,
}

impl LockStepTick {
    pub const fn time(&self) -> Timestamp {
        Timestamp::from_nanos(self.time_ns)
    }

    /// Whether this tick starts a new episode after `current` (the episode of the last tick).
    pub fn starts_episode(&self, current: Option<u64>) -> bool {
        self.index == 0 || current != Some(self.episode)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::offset_of;

    #[test]
    fn layout_is_the_documented_one() {
        assert_eq!(size_of::<LockStepTick>(), 24);
        assert_eq!(offset_of!(LockStepTick, index), 8);
        assert_eq!(offset_of!(LockStepTick, time_ns), 16);
    }

    #[test]
    fn a_first_tick_or_another_episode_starts_an_episode() {
        let tick = |episode, index| LockStepTick {
            episode,
            index,
            time_ns: 0,
        };
        assert!(tick(3, 0).starts_episode(Some(3)));
        assert!(tick(3, 5).starts_episode(Some(2)));
        assert!(tick(3, 5).starts_episode(None));
        assert!(!tick(3, 5).starts_episode(Some(3)));
    }
}
