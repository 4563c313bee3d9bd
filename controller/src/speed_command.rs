//! Speed commands for the walk, normalised to the walk's maximum speeds.
//!
//! DESIGN.md: forward, left and turn are each in [-1, 1] of the walk's maximum (by default
//! 0.25 m/s, 0.15 m/s and 1.0 rad/s). Errors between commands are measured in these units.

use core::fmt;

use crate::units::{MetresPerSecond, RadiansPerSecond};

/// A walk request in normalised units: each component in [-1, 1], always finite.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpeedCommand {
    forward: f32,
    left: f32,
    turn: f32,
}

/// A command had a NaN or infinite component; it must not reach the walk.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("speed command has a non-finite component")]
pub struct NonFiniteCommand;

impl SpeedCommand {
    /// Standing still.
    pub const STOP: Self = Self {
        forward: 0.0,
        left: 0.0,
        turn: 0.0,
    };

    /// A command from normalised components, each clamped to [-1, 1]. Refuses NaN and
    /// infinities rather than guessing what they meant.
    pub fn new(forward: f32, left: f32, turn: f32) -> Result<Self, NonFiniteCommand> {
        if !(forward.is_finite() && left.is_finite() && turn.is_finite()) {
            return Err(NonFiniteCommand);
        }
        Ok(Self {
            forward: forward.clamp(-1.0, 1.0),
            left: left.clamp(-1.0, 1.0),
            turn: turn.clamp(-1.0, 1.0),
        })
    }

    /// Positive walks forward.
    pub const fn forward(&self) -> f32 {
        self.forward
    }

    /// Positive walks to the robot's left.
    pub const fn left(&self) -> f32 {
        self.left
    }

    /// Positive turns counter-clockwise (to the left) seen from above.
    pub const fn turn(&self) -> f32 {
        self.turn
    }

    pub const fn as_array(&self) -> [f32; 3] {
        [self.forward, self.left, self.turn]
    }

    pub fn is_stop(&self) -> bool {
        *self == Self::STOP
    }

    /// Euclidean distance to `other` in normalised units: the paper's error measure.
    pub fn distance(&self, other: &Self) -> f32 {
        let d = [
            self.forward - other.forward,
            self.left - other.left,
            self.turn - other.turn,
        ];
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    }

    /// The physical walk velocity this command asks for under `limits`.
    pub fn to_velocity(&self, limits: &WalkLimits) -> WalkVelocity {
        WalkVelocity {
            forward: MetresPerSecond(self.forward * limits.max_forward.0),
            left: MetresPerSecond(self.left * limits.max_left.0),
            turn: RadiansPerSecond(self.turn * limits.max_turn.0),
        }
    }
}

impl fmt::Display for SpeedCommand {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "forward {:+.3} left {:+.3} turn {:+.3}",
            self.forward, self.left, self.turn
        )
    }
}

/// The walk's maximum speeds: what a normalised 1.0 means. Stated in every model manifest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkLimits {
    pub max_forward: MetresPerSecond,
    pub max_left: MetresPerSecond,
    pub max_turn: RadiansPerSecond,
}

impl Default for WalkLimits {
    fn default() -> Self {
        Self {
            max_forward: MetresPerSecond(0.25),
            max_left: MetresPerSecond(0.15),
            max_turn: RadiansPerSecond(1.0),
        }
    }
}

/// A walk velocity in the robot frame, in physical units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WalkVelocity {
    pub forward: MetresPerSecond,
    pub left: MetresPerSecond,
    pub turn: RadiansPerSecond,
}

impl WalkVelocity {
    /// The normalised command for this velocity under `limits`, saturating at the limits.
    pub fn to_command(&self, limits: &WalkLimits) -> Result<SpeedCommand, NonFiniteCommand> {
        SpeedCommand::new(
            self.forward.0 / limits.max_forward.0,
            self.left.0 / limits.max_left.0,
            self.turn.0 / limits.max_turn.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn clamps_each_component_to_the_unit_range() {
        let command = SpeedCommand::new(1.5, -3.0, 0.25).expect("finite");
        assert_eq!(command.as_array(), [1.0, -1.0, 0.25]);
    }

    #[test]
    fn refuses_nan_and_infinity() {
        assert_eq!(SpeedCommand::new(f32::NAN, 0.0, 0.0), Err(NonFiniteCommand));
        assert_eq!(
            SpeedCommand::new(0.0, f32::INFINITY, 0.0),
            Err(NonFiniteCommand)
        );
        assert_eq!(
            SpeedCommand::new(0.0, 0.0, f32::NEG_INFINITY),
            Err(NonFiniteCommand)
        );
    }

    #[test]
    fn converts_to_physical_units_with_the_default_walk() {
        let velocity = SpeedCommand::new(1.0, -0.5, 0.5)
            .expect("finite")
            .to_velocity(&WalkLimits::default());
        assert_eq!(velocity.forward, MetresPerSecond(0.25));
        assert_eq!(velocity.left, MetresPerSecond(-0.075));
        assert_eq!(velocity.turn, RadiansPerSecond(0.5));
    }

    #[test]
    fn a_velocity_beyond_the_limits_saturates() {
        let limits = WalkLimits::default();
        let velocity = WalkVelocity {
            forward: MetresPerSecond(1.0),
            left: MetresPerSecond(0.0),
            turn: RadiansPerSecond(-2.0),
        };
        let command = velocity.to_command(&limits).expect("finite");
        assert_eq!(command.as_array(), [1.0, 0.0, -1.0]);
    }

    #[test]
    fn distance_is_euclidean_in_normalised_units() {
        let a = SpeedCommand::new(0.3, 0.0, 0.0).expect("finite");
        let b = SpeedCommand::new(0.0, 0.4, 0.0).expect("finite");
        assert!((a.distance(&b) - 0.5).abs() < 1e-6);
    }

    proptest! {
        #[test]
        fn velocity_round_trips_through_the_command(
            forward in -1.0f32..=1.0, left in -1.0f32..=1.0, turn in -1.0f32..=1.0,
            max_forward in 0.05f32..1.0, max_left in 0.05f32..1.0, max_turn in 0.1f32..3.0,
        ) {
            let limits = WalkLimits {
                max_forward: MetresPerSecond(max_forward),
                max_left: MetresPerSecond(max_left),
                max_turn: RadiansPerSecond(max_turn),
            };
            let command = SpeedCommand::new(forward, left, turn).expect("finite");
            let back = command.to_velocity(&limits).to_command(&limits).expect("finite");
            prop_assert!(command.distance(&back) < 1e-5);
        }

        #[test]
        fn every_finite_input_gives_a_command_in_range(
            forward in any::<f32>(), left in any::<f32>(), turn in any::<f32>()
        ) {
            match SpeedCommand::new(forward, left, turn) {
                Ok(command) => prop_assert!(command.as_array().iter().all(|c| (-1.0..=1.0).contains(c))),
                Err(NonFiniteCommand) => prop_assert!(
                    !(forward.is_finite() && left.is_finite() && turn.is_finite())
                ),
            }
        }
    }
}
