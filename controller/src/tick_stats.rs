//! Per-tick timing statistics in fixed-size storage: min, median, p99, max and overruns.
//!
//! Durations go into a log-linear histogram (as HdrHistogram does): exact below 128 ns, then
//! 64 buckets per power of two, so any quantile is within 1/64 (1.6 %) of the true value.
//! Recording is a few integer operations and never allocates.

use core::fmt;
use core::time::Duration;

use crate::units::duration_nanos;

const SUB_BUCKET_BITS: u32 = 6;
const SUB_BUCKETS: u64 = 1 << SUB_BUCKET_BITS;
/// Values below this get a bucket each.
const EXACT_BELOW: u64 = 2 * SUB_BUCKETS;
/// Exact buckets, then 64 for each power of two from 2^7 to 2^63.
const BUCKETS: usize = (EXACT_BELOW + (64 - SUB_BUCKET_BITS as u64 - 1) * SUB_BUCKETS) as usize;

fn bucket_of(nanos: u64) -> usize {
    if nanos < EXACT_BELOW {
        return nanos as usize;
    }
    let top_bit = 63 - nanos.leading_zeros();
    let shift = top_bit - SUB_BUCKET_BITS;
    let sub_bucket = (nanos >> shift) - SUB_BUCKETS;
    (EXACT_BELOW + u64::from(shift - 1) * SUB_BUCKETS + sub_bucket) as usize
}

/// The smallest and largest value that land in `bucket`.
fn bucket_range(bucket: usize) -> (u64, u64) {
    let bucket = bucket as u64;
    if bucket < EXACT_BELOW {
        return (bucket, bucket);
    }
    let shift = (bucket - EXACT_BELOW) / SUB_BUCKETS + 1;
    let sub_bucket = (bucket - EXACT_BELOW) % SUB_BUCKETS + SUB_BUCKETS;
    let low = sub_bucket << shift;
    (low, low + ((1 << shift) - 1))
}

/// Timing statistics of the ticks so far, against a time budget per tick.
#[derive(Clone)]
pub struct TickStats {
    budget: Duration,
    counts: [u64; BUCKETS],
    ticks: u64,
    total_nanos: u128,
    min_nanos: u64,
    max_nanos: u64,
    overruns: u64,
}

impl TickStats {
    pub fn new(budget: Duration) -> Self {
        Self {
            budget,
            counts: [0; BUCKETS],
            ticks: 0,
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
        self.counts[bucket_of(nanos)] += 1;
        self.ticks += 1;
        self.total_nanos += u128::from(nanos);
        self.min_nanos = self.min_nanos.min(nanos);
        self.max_nanos = self.max_nanos.max(nanos);
        if tick > self.budget {
            self.overruns += 1;
        }
    }

    /// Adds `other`'s ticks to these (same budget assumed: overruns are added as counted).
    pub fn merge(&mut self, other: &TickStats) {
        for (mine, theirs) in self.counts.iter_mut().zip(other.counts.iter()) {
            *mine += theirs;
        }
        self.ticks += other.ticks;
        self.total_nanos += other.total_nanos;
        self.min_nanos = self.min_nanos.min(other.min_nanos);
        self.max_nanos = self.max_nanos.max(other.max_nanos);
        self.overruns += other.overruns;
    }

    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    pub fn overruns(&self) -> u64 {
        self.overruns
    }

    /// The duration below which a fraction `q` (0..=1) of the ticks fall, within 1.6 %.
    /// `None` before the first tick.
    pub fn quantile(&self, q: f64) -> Option<Duration> {
        if self.ticks == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.ticks as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (bucket, &count) in self.counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                let (low, high) = bucket_range(bucket);
                let middle = low + (high - low) / 2;
                return Some(Duration::from_nanos(
                    middle.clamp(self.min_nanos, self.max_nanos),
                ));
            }
        }
        Some(Duration::from_nanos(self.max_nanos))
    }

    /// The figures worth printing, `None` before the first tick.
    pub fn summary(&self) -> Option<TickSummary> {
        Some(TickSummary {
            ticks: self.ticks,
            min: Duration::from_nanos(self.min_nanos),
            median: self.quantile(0.5)?,
            p99: self.quantile(0.99)?,
            max: Duration::from_nanos(self.max_nanos),
            mean: Duration::from_nanos((self.total_nanos / u128::from(self.ticks)) as u64),
            overruns: self.overruns,
            budget: self.budget,
        })
    }
}

impl fmt::Debug for TickStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TickStats")
            .field("ticks", &self.ticks)
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
    fn buckets_cover_every_value_in_order() {
        let mut previous_high = None;
        for bucket in 0..BUCKETS {
            let (low, high) = bucket_range(bucket);
            assert!(low <= high);
            if let Some(previous) = previous_high {
                assert_eq!(low, previous + 1, "bucket {bucket} leaves a gap");
            }
            assert_eq!(bucket_of(low), bucket);
            assert_eq!(bucket_of(high), bucket);
            previous_high = Some(high);
        }
        assert_eq!(previous_high, Some(u64::MAX));
    }

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
    fn has_no_summary_before_the_first_tick() {
        assert_eq!(TickStats::new(Duration::from_millis(2)).summary(), None);
    }

    proptest! {
        #[test]
        fn quantiles_are_within_one_sixty_fourth_of_the_exact_ones(
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
            prop_assert!((estimate - exact).abs() <= exact / 64.0, "{estimate} vs {exact}");
        }
    }
}
