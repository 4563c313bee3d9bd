//! The command message the controller publishes every tick (DESIGN.md, "Shared memory").

use crate::speed_command::{NonFiniteCommand, SpeedCommand};
use crate::units::Timestamp;

/// Frame sequence recorded when no frame was used (before the first computed command).
pub const NO_FRAME: u64 = u64::MAX;

/// What kind of command a [`MotionCommand`] carries. Bits, combined:
/// `NEW` computed this tick from new frames of both cameras; `REPEATED` the last command
/// again, as no new pair arrived; `STOP` a stop for a fault (no frames yet, a silent camera,
/// a failed or non-finite inference). A repeated stop carries `REPEATED | STOP`.
#[repr(transparent)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct CommandFlags(pub u32);

impl CommandFlags {
    pub const NEW: Self = Self(1);
    pub const REPEATED: Self = Self(1 << 1);
    pub const STOP: Self = Self(1 << 2);
    /// A stop published while no lock-step tick came (the simulator silent, or not started):
    /// it answers no tick, even one stamped with the same time (the first tick of a run and a
    /// stop before it are both at time zero).
    pub const WATCHDOG: Self = Self(1 << 3);

    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
}

/// One command to the motion module.
///
/// Layout, little-endian, 48 bytes on both i686 and x86_64: `sequence: u64` at 0,
/// `timestamp_ns: u64` at 8, `top_sequence: u64` at 16, `bottom_sequence: u64` at 24,
/// `forward: f32` at 32, `left: f32` at 36, `turn: f32` at 40, `flags: u32` at 44.
/// Speeds are normalised to [-1, 1] of the walk's maximum (see [`SpeedCommand`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionCommand {
    /// Counts up by one per published command.
    pub sequence: u64,
    /// When the tick that produced it started, on the shared monotonic clock.
    pub timestamp_ns: u64,
    /// Sequences of the frames the command was computed from, [`NO_FRAME`] if none.
    pub top_sequence: u64,
    pub bottom_sequence: u64,
    pub speed: SpeedCommand,
    pub flags: CommandFlags,
}

impl MotionCommand {
    /// The stop published before anything has been computed.
    pub const fn initial_stop() -> Self {
        Self {
            sequence: 0,
            timestamp_ns: 0,
            top_sequence: NO_FRAME,
            bottom_sequence: NO_FRAME,
            speed: SpeedCommand::STOP,
            flags: CommandFlags::STOP,
        }
    }

    pub const fn timestamp(&self) -> Timestamp {
        Timestamp::from_nanos(self.timestamp_ns)
    }

    pub const fn is_new(&self) -> bool {
        self.flags.contains(CommandFlags::NEW)
    }

    pub const fn is_repeated(&self) -> bool {
        self.flags.contains(CommandFlags::REPEATED)
    }

    pub const fn is_stop(&self) -> bool {
        self.flags.contains(CommandFlags::STOP)
    }

    pub const fn is_watchdog(&self) -> bool {
        self.flags.contains(CommandFlags::WATCHDOG)
    }

    /// The command with its speed checked as [`SpeedCommand::new`] checks it: read from
    /// shared memory, the bytes may come from any process, so a NaN or infinite speed is
    /// refused and a component outside [-1, 1] clamped before it can reach a walk.
    pub fn checked(mut self) -> Result<Self, NonFiniteCommand> {
        let [forward, left, turn] = self.speed.as_array();
        self.speed = SpeedCommand::new(forward, left, turn)?;
        Ok(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::offset_of;

    #[test]
    fn layout_is_the_documented_one() {
        assert_eq!(size_of::<MotionCommand>(), 48);
        assert_eq!(offset_of!(MotionCommand, timestamp_ns), 8);
        assert_eq!(offset_of!(MotionCommand, top_sequence), 16);
        assert_eq!(offset_of!(MotionCommand, bottom_sequence), 24);
        assert_eq!(offset_of!(MotionCommand, speed), 32);
        assert_eq!(offset_of!(MotionCommand, flags), 44);
    }

    #[test]
    fn flags_combine() {
        let repeated_stop = CommandFlags::REPEATED.union(CommandFlags::STOP);
        assert!(repeated_stop.contains(CommandFlags::STOP));
        assert!(repeated_stop.contains(CommandFlags::REPEATED));
        assert!(!repeated_stop.contains(CommandFlags::NEW));
    }
}
