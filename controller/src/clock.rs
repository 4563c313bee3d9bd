//! Clocks that drive the control loop: the robot's monotonic clock, or a clock the
//! simulator (or a test) moves by hand.

use core::time::Duration;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::units::{Timestamp, duration_nanos};

/// A source of time and a way to wait for a deadline.
pub trait Clock {
    fn now(&self) -> Timestamp;

    /// Returns once `deadline` has passed. Deadlines are absolute, so the loop keeps its
    /// phase however long a tick took.
    fn sleep_until(&mut self, deadline: Timestamp);
}

/// The robot's clock: `CLOCK_MONOTONIC`, the clock V4L2 stamps camera frames with, and
/// absolute-deadline sleeps (`clock_nanosleep` with `TIMER_ABSTIME`) that do not drift.
#[derive(Clone, Copy, Debug, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now(&self) -> Timestamp {
        let mut time = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `time` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
        #[allow(unsafe_code)]
        let result = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut time) };
        debug_assert_eq!(result, 0, "CLOCK_MONOTONIC is always available");
        let nanos = (time.tv_sec as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(time.tv_nsec as u64);
        Timestamp::from_nanos(nanos)
    }

    fn sleep_until(&mut self, deadline: Timestamp) {
        let nanos = deadline.as_nanos();
        let Ok(tv_sec) = libc::time_t::try_from(nanos / 1_000_000_000) else {
            return; // Centuries away on a 32-bit time_t; nothing sensible to wait for.
        };
        let until = libc::timespec {
            tv_sec,
            tv_nsec: (nanos % 1_000_000_000) as _,
        };
        loop {
            // SAFETY: `until` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
            #[allow(unsafe_code)]
            let result = unsafe {
                libc::clock_nanosleep(
                    libc::CLOCK_MONOTONIC,
                    libc::TIMER_ABSTIME,
                    &until,
                    core::ptr::null_mut(),
                )
            };
            // Interrupted by a signal: sleep again to the same absolute deadline.
            if result != libc::EINTR {
                return;
            }
        }
    }
}

/// A clock that only moves when told to: simulation time, or a test's time.
///
/// Clones share one time, so a simulator can hold one handle and the control loop another.
/// `sleep_until` jumps straight to the deadline.
#[derive(Clone, Debug, Default)]
pub struct ManualClock {
    nanos: Arc<AtomicU64>,
}

impl ManualClock {
    pub fn starting_at(start: Timestamp) -> Self {
        Self {
            nanos: Arc::new(AtomicU64::new(start.as_nanos())),
        }
    }

    /// Sets the time; a clock never runs backwards, so an earlier time is ignored.
    pub fn set(&self, time: Timestamp) {
        self.nanos.fetch_max(time.as_nanos(), Ordering::AcqRel);
    }

    /// Sets the time even if it is earlier: the start of a new episode.
    pub fn restart_at(&self, time: Timestamp) {
        self.nanos.store(time.as_nanos(), Ordering::Release);
    }

    pub fn advance(&self, by: Duration) {
        let by = duration_nanos(by);
        // fetch_update cannot fail with a closure that always returns Some.
        let _ = self
            .nanos
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |now| {
                Some(now.saturating_add(by))
            });
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Timestamp {
        Timestamp::from_nanos(self.nanos.load(Ordering::Acquire))
    }

    fn sleep_until(&mut self, deadline: Timestamp) {
        self.set(deadline);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_sleeps_until_an_absolute_deadline() {
        let mut clock = MonotonicClock;
        let start = clock.now();
        let deadline = start + Duration::from_millis(5);
        clock.sleep_until(deadline);
        assert!(clock.now() >= deadline);
        // A deadline in the past returns without waiting for anything.
        clock.sleep_until(start);
        assert!(clock.now() >= deadline);
    }

    #[test]
    fn manual_clock_handles_share_one_time_and_never_go_back() {
        let loop_side = ManualClock::starting_at(Timestamp::from_nanos(100));
        let mut simulator_side = loop_side.clone();
        simulator_side.advance(Duration::from_nanos(50));
        assert_eq!(loop_side.now(), Timestamp::from_nanos(150));
        simulator_side.sleep_until(Timestamp::from_nanos(1000));
        assert_eq!(loop_side.now(), Timestamp::from_nanos(1000));
        loop_side.set(Timestamp::from_nanos(10));
        assert_eq!(simulator_side.now(), Timestamp::from_nanos(1000));
        loop_side.restart_at(Timestamp::from_nanos(10));
        assert_eq!(simulator_side.now(), Timestamp::from_nanos(10));
    }
}
