//! Per-tick timing statistics: min, median, p99, max and overruns.
//!
//! Durations go into an HdrHistogram (`hdrhistogram`, two significant digits: any quantile
//! within 1/128 of the true value) allocated once, at construction, for ticks from 1 ns to an
//! hour (36 KB); a longer one counts as an hour in the quantiles, while min, max and mean stay
//! exact. Recording is a few integer operations and never allocates (the allocation tests run
//! it on every tick).

use core::fmt;
use core::time::Duration;

use hdrhistogram::Histogram;

use crate::units::duration_nanos;

/// The longest tick the histogram tells apart, in nanoseconds (an hour).
const HIGHEST_NANOS: u64 = 3_600_000_000_000;
/// Significant decimal digits the histogram keeps.
const SIGNIFICANT_DIGITS: u8 = 2;

/// Timing statistics of the ticks so far, against a time budget per tick.
#[derive(Clone)]
pub struct TickStats {
    budget: Duration,
    histogram: Histogram<u64>,
    total_nanos: u128,
    min_nanos: u64,
    max_nanos: u64,
    overruns: u64,
}

impl TickStats {
    pub fn new(budget: Duration) -> Self {
        Self {
            budget,
            histogram: Histogram::new_with_bounds(1, HIGHEST_NANOS, SIGNIFICANT_DIGITS)
                .expect("constant bounds HdrHistogram accepts"),
            total_nanos: 0,
            min_nanos: u64::MAX,
            max_nanos: 0,
            overruns: 0,
        }
    }

    pub fn budget(&self) -> Duration {
        self.budget
    }

    /// Adds one tick's duration; a tick longer than the budget counts as an overrun.
    pub fn record(&mut self, tick: Duration) {
        let nanos = duration_nanos(tick);
        self.histogram.saturating_record(nanos);
        self.total_nanos += u128::from(nanos);
        self.min_nanos = self.min_nanos.min(nanos);
        self.max_nanos = self.max_nanos.max(nanos);
        if tick > self.budget {
            self.overruns += 1;
        }
    }

    /// Adds `other`'s ticks to these (same budget assumed: overruns are added as counted).
    pub fn merge(&mut self, other: &TickStats) {
        // Both histograms have the same constant bounds, so adding cannot run out of range.
        let _ = self.histogram.add(&other.histogram);
        self.total_nanos += other.total_nanos;
        self.min_nanos = self.min_nanos.min(other.min_nanos);
        self.max_nanos = self.max_nanos.max(other.max_nanos);
        self.overruns += other.overruns;
    }

    pub fn ticks(&self) -> u64 {
        self.histogram.len()
    }

    pub fn overruns(&self) -> u64 {
        self.overruns
    }

    /// The duration below which a fraction `q` (0..=1) of the ticks fall, within 1/128.
    /// `None` before the first tick.
    pub fn quantile(&self, q: f64) -> Option<Duration> {
        if self.histogram.is_empty() {
            return None;
        }
        let value = self.histogram.value_at_quantile(q.clamp(0.0, 1.0));
        // The histogram answers with its bucket's top; the exact extremes bound it.
        Some(Duration::from_nanos(
            value.clamp(self.min_nanos, self.max_nanos),
        ))
    }

    /// The figures worth printing, `None` before the first tick.
    pub fn summary(&self) -> Option<TickSummary> {
        Some(TickSummary {
            ticks: self.ticks(),
            min: Duration::from_nanos(self.min_nanos),
            median: self.quantile(0.5)?,
            p99: self.quantile(0.99)?,
            max: Duration::from_nanos(self.max_nanos),
            mean: Duration::from_nanos((self.total_nanos / u128::from(self.ticks())) as u64),
            overruns: self.overruns,
            budget: self.budget,
        })
    }
}

impl fmt::Debug for TickStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TickStats")
            .field("ticks", &self.ticks())
            .field("summary", &self.summary())
            .finish_non_exhaustive()
    }
}

/// Tick timing at a glance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TickSummary {
    pub ticks: u64,
    pub min: Duration,
    pub median: Duration,
    pub p99: Duration,
    pub max: Duration,
    pub mean: Duration,
    pub overruns: u64,
    pub budget: Duration,
}

impl fmt::Display for TickSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ticks: min {:.1?} median {:.1?} p99 {:.1?} max {:.1?} mean {:.1?}; {} over the {:?} budget",
            self.ticks,
            self.min,
            self.median,
            self.p99,
            self.max,
            self.mean,
            self.overruns,
            self.budget
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn counts_overruns_against_the_budget() {
        let mut stats = TickStats::new(Duration::from_millis(2));
        stats.record(Duration::from_micros(1999));
        stats.record(Duration::from_millis(2));
        stats.record(Duration::from_micros(2001));
        assert_eq!(stats.overruns(), 1);
        let summary = stats.summary().expect("ticks recorded");
        assert_eq!(summary.max, Duration::from_micros(2001));
        assert_eq!(summary.min, Duration::from_micros(1999));
    }

    #[test]
    fn merging_is_recording_everything_in_one() {
        let budget = Duration::from_millis(2);
        let (mut a, mut b, mut all) = (
            TickStats::new(budget),
            TickStats::new(budget),
            TickStats::new(budget),
        );
        for (i, micros) in [5u64, 3000, 40, 700, 90, 2500].into_iter().enumerate() {
            let d = Duration::from_micros(micros);
            if i % 2 == 0 {
                a.record(d)
            } else {
                b.record(d)
            }
            all.record(d);
        }
        a.merge(&b);
        assert_eq!(a.summary(), all.summary());
    }

    #[test]
    fn a_tick_beyond_the_histogram_keeps_its_exact_maximum() {
        let mut stats = TickStats::new(Duration::from_millis(2));
        stats.record(Duration::from_micros(100));
        stats.record(Duration::from_secs(2 * 3600));
        let summary = stats.summary().expect("ticks recorded");
        assert_eq!(summary.max, Duration::from_secs(2 * 3600));
        assert_eq!(summary.ticks, 2);
        assert_eq!(summary.overruns, 1);
        let p99 = stats.quantile(0.99).expect("ticks recorded");
        assert!(p99 >= Duration::from_secs(3590), "{p99:?}");
    }

    #[test]
    fn has_no_summary_before_the_first_tick() {
        assert_eq!(TickStats::new(Duration::from_millis(2)).summary(), None);
    }

    proptest! {
        #[test]
        fn quantiles_are_within_one_128th_of_the_exact_ones(
            mut nanos in proptest::collection::vec(1u64..50_000_000, 1..500),
            q in 0.0f64..=1.0,
        ) {
            let mut stats = TickStats::new(Duration::from_millis(2));
            for &n in &nanos {
                stats.record(Duration::from_nanos(n));
            }
            nanos.sort_unstable();
            let rank = ((q * nanos.len() as f64).ceil() as usize).max(1);
            let exact = nanos[rank - 1] as f64;
            let estimate = stats.quantile(q).expect("ticks recorded").as_nanos() as f64;
            prop_assert!((estimate - exact).abs() <= exact / 128.0, "{estimate} vs {exact}");
        }
    }
}
