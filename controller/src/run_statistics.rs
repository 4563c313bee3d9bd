//! What a controller run did, printed as it stops: three lines for people and one line for
//! programs (`statistics {json}`), made from one [`RunStatistics`]. The evaluation and the
//! soak read the machine line back ([`RunStatistics::from_log`]) instead of matching the
//! human wording.

use std::fmt;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::camera_sync::SyncCounters;
use crate::control_loop::LoopCounters;
use crate::tick_stats::TickSummary;

/// The machine line starts with this; the rest of it is [`RunStatistics`] as JSON.
pub const STATISTICS_PREFIX: &str = "statistics ";

/// A run's counters and tick time, as the controller prints them when it stops. The loop's
/// counters are its own type, flattened into the JSON.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunStatistics {
    #[serde(flatten)]
    pub counters: LoopCounters,
    /// Frames accepted, top then bottom (the camera sync's counts).
    pub frames_accepted: [u64; 2],
    pub duplicates: [u64; 2],
    pub out_of_order: [u64; 2],
    /// The tick's own time; absent when no tick ran.
    pub tick_time: Option<TickTime>,
}

/// Percentiles of the time one tick took, in nanoseconds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TickTime {
    pub p50_ns: u64,
    pub p99_ns: u64,
    pub max_ns: u64,
    pub budget_ns: u64,
    /// Ticks over the budget.
    pub overruns: u64,
}

/// Why a log's statistics line could not be read.
#[derive(Debug, thiserror::Error)]
pub enum StatisticsError {
    #[error("the controller printed no statistics line (it did not stop cleanly)")]
    Missing,
    #[error("the controller's statistics line is not valid: {0}")]
    Invalid(#[from] serde_json::Error),
}

fn nanos(duration: Duration) -> u64 {
    u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX)
}

impl RunStatistics {
    pub fn new(counters: &LoopCounters, sync: &SyncCounters, tick: Option<TickSummary>) -> Self {
        Self {
            counters: *counters,
            frames_accepted: sync.accepted,
            duplicates: sync.duplicates,
            out_of_order: sync.out_of_order,
            tick_time: tick.map(|summary| TickTime {
                p50_ns: nanos(summary.median),
                p99_ns: nanos(summary.p99),
                max_ns: nanos(summary.max),
                budget_ns: nanos(summary.budget),
                overruns: summary.overruns,
            }),
        }
    }

    /// The line for programs: [`STATISTICS_PREFIX`] and the JSON.
    pub fn machine_line(&self) -> String {
        // A struct of integers and arrays always serialises.
        let json = serde_json::to_string(self).unwrap_or_default();
        format!("{STATISTICS_PREFIX}{json}")
    }

    /// The statistics of the last run in a controller's output.
    pub fn from_log(log: &str) -> Result<Self, StatisticsError> {
        let json = log
            .lines()
            .rev()
            .find_map(|line| line.strip_prefix(STATISTICS_PREFIX))
            .ok_or(StatisticsError::Missing)?;
        Ok(serde_json::from_str(json)?)
    }
}

/// The three lines for people: commands, frames, tick time.
impl fmt::Display for RunStatistics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let counters = &self.counters;
        writeln!(
            f,
            "ticks {}: {} new, {} repeated, {} stops ({} for cameras), {} policy failures, {} non-finite outputs",
            counters.ticks,
            counters.new_commands,
            counters.repeated_commands,
            counters.stops,
            counters.camera_stops,
            counters.policy_failures,
            counters.non_finite_outputs
        )?;
        writeln!(
            f,
            "frames accepted top {} bottom {}; duplicates {:?}, out of order {:?}, invalid {}, stamped after their tick {}; deadline misses {}",
            self.frames_accepted[0],
            self.frames_accepted[1],
            self.duplicates,
            self.out_of_order,
            counters.invalid_frames,
            counters.future_frames,
            counters.deadline_misses
        )?;
        match self.tick_time {
            Some(time) => write!(
                f,
                "tick time: p50 {:.1?} p99 {:.1?} max {:.1?}; {} overruns of the {:?} budget",
                Duration::from_nanos(time.p50_ns),
                Duration::from_nanos(time.p99_ns),
                Duration::from_nanos(time.max_ns),
                time.overruns,
                Duration::from_nanos(time.budget_ns)
            ),
            None => f.write_str("tick time: no ticks ran"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> RunStatistics {
        RunStatistics {
            counters: LoopCounters {
                ticks: 900,
                new_commands: 850,
                repeated_commands: 40,
                stops: 10,
                camera_stops: 7,
                policy_failures: 0,
                non_finite_outputs: 0,
                invalid_frames: 0,
                future_frames: 0,
                deadline_misses: 3,
            },
            frames_accepted: [890, 880],
            duplicates: [1, 0],
            out_of_order: [0, 2],
            tick_time: Some(TickTime {
                p50_ns: 1_234_000,
                p99_ns: 2_000_000,
                max_ns: 5_500_000,
                budget_ns: 10_000_000,
                overruns: 0,
            }),
        }
    }

    #[test]
    fn the_machine_line_reads_back_from_a_log_and_the_last_run_wins() {
        let first = example();
        let mut second = example();
        second.counters.ticks = 12;
        second.tick_time = None;
        let log = format!(
            "policy: cnn from x, engine tract\n{first}\n{}\nts=... event=stopped\n{second}\n{}\n",
            first.machine_line(),
            second.machine_line()
        );
        assert_eq!(RunStatistics::from_log(&log).expect("statistics"), second);
    }

    #[test]
    fn a_missing_or_broken_line_is_an_error_that_says_which() {
        assert!(matches!(
            RunStatistics::from_log("ticks 3: ...\n"),
            Err(StatisticsError::Missing)
        ));
        assert!(matches!(
            RunStatistics::from_log("statistics {\"ticks\": 3\n"),
            Err(StatisticsError::Invalid(_))
        ));
    }

    #[test]
    fn the_human_lines_say_the_same_figures() {
        let text = example().to_string();
        assert!(text.starts_with("ticks 900: 850 new, 40 repeated, 10 stops (7 for cameras)"));
        assert!(text.contains("frames accepted top 890 bottom 880"));
        assert!(
            text.ends_with(
                "tick time: p50 1.2ms p99 2.0ms max 5.5ms; 0 overruns of the 10ms budget"
            )
        );
    }
}
