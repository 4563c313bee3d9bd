//! Physical quantities that cross module boundaries carry their unit in their type.

use core::fmt;
use core::ops::{Add, Sub};
use core::time::Duration;

/// A point in time: nanoseconds of one monotonic clock (`CLOCK_MONOTONIC` on the robot,
/// simulation time in the simulator), as every time stamp in DESIGN.md.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Timestamp(u64);

impl Timestamp {
    pub const ZERO: Self = Self(0);

    pub const fn from_nanos(nanos: u64) -> Self {
        Self(nanos)
    }

    pub const fn as_nanos(self) -> u64 {
        self.0
    }

    /// Time from `earlier` to `self`; zero if `earlier` is later.
    pub fn saturating_since(self, earlier: Self) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl Add<Duration> for Timestamp {
    type Output = Self;

    fn add(self, rhs: Duration) -> Self {
        Self(self.0.saturating_add(duration_nanos(rhs)))
    }
}

impl Sub<Duration> for Timestamp {
    type Output = Self;

    fn sub(self, rhs: Duration) -> Self {
        Self(self.0.saturating_sub(duration_nanos(rhs)))
    }
}

impl fmt::Display for Timestamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}.{:09} s",
            self.0 / 1_000_000_000,
            self.0 % 1_000_000_000
        )
    }
}

/// Nanoseconds of a duration, saturating at `u64::MAX` (585 years).
pub fn duration_nanos(duration: Duration) -> u64 {
    u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX)
}

/// A linear speed in metres per second.
#[derive(Clone, Copy, Debug, Default, PartialEq, PartialOrd)]
pub struct MetresPerSecond(pub f32);

/// An angular speed in radians per second.
#[derive(Clone, Copy, Debug, Default, PartialEq, PartialOrd)]
pub struct RadiansPerSecond(pub f32);

impl fmt::Display for MetresPerSecond {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} m/s", self.0)
    }
}

impl fmt::Display for RadiansPerSecond {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} rad/s", self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamp_arithmetic_saturates_instead_of_wrapping() {
        let t = Timestamp::from_nanos(10);
        assert_eq!(t - Duration::from_nanos(20), Timestamp::ZERO);
        assert_eq!(
            Timestamp::from_nanos(u64::MAX - 1) + Duration::from_secs(1),
            Timestamp::from_nanos(u64::MAX)
        );
        assert_eq!(
            t.saturating_since(Timestamp::from_nanos(25)),
            Duration::ZERO
        );
        assert_eq!(
            Timestamp::from_nanos(25).saturating_since(t),
            Duration::from_nanos(15)
        );
    }

    #[test]
    fn timestamp_displays_seconds_with_nanosecond_digits() {
        assert_eq!(
            Timestamp::from_nanos(1_500_000_002).to_string(),
            "1.500000002 s"
        );
    }
}
