//! What the soak sees of the commands: each one's latency from its tick's start to its
//! arrival, gaps in the sequence (lost), late ticks and deadlines missed, per second
//! (`Second`, a row of soak.csv) and in total.

use std::time::Duration;

use dribble_controller::{LoopConfig, MotionCommand, Timestamp};

/// One second of the soak, as written to the CSV.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Second {
    pub(crate) elapsed_s: f64,
    pub(crate) rss_kib: u64,
    pub(crate) open_files: u64,
    pub(crate) commands: u64,
    pub(crate) new_commands: u64,
    pub(crate) stops: u64,
    pub(crate) lost: u64,
    pub(crate) over_budget: u64,
    pub(crate) late_ticks: u64,
    /// Commands over budget or begun late (a command may be both; counted once).
    pub(crate) missed: u64,
    pub(crate) latency_p50_us: f64,
    pub(crate) latency_p99_us: f64,
    pub(crate) latency_max_us: f64,
}

impl Second {
    pub(crate) const HEADER: &str = "elapsed_s,rss_kib,open_files,commands,new_commands,stops,lost,\
                          over_budget,late_ticks,missed,latency_p50_us,latency_p99_us,latency_max_us";

    pub(crate) fn csv(&self) -> String {
        format!(
            "{:.3},{},{},{},{},{},{},{},{},{},{:.1},{:.1},{:.1}",
            self.elapsed_s,
            self.rss_kib,
            self.open_files,
            self.commands,
            self.new_commands,
            self.stops,
            self.lost,
            self.over_budget,
            self.late_ticks,
            self.missed,
            self.latency_p50_us,
            self.latency_p99_us,
            self.latency_max_us
        )
    }
}

/// The commands' sequence, timing and kinds, over a second and over the whole run.
#[derive(Debug)]
pub(crate) struct CommandWatch {
    pub(crate) budget: Duration,
    pub(crate) late_after: Duration,
    pub(crate) last: Option<MotionCommand>,
    pub(crate) second: Second,
    /// This second's latencies, µs.
    pub(crate) latencies: Vec<f64>,
    /// Every latency of the run, µs (an hour at 100 Hz is 360,000 values).
    pub(crate) all_latencies: Vec<f64>,
    pub(crate) totals: Second,
}

impl CommandWatch {
    pub(crate) fn new(config: &LoopConfig) -> Self {
        Self {
            budget: config.budget,
            late_after: config.tick_period + config.tick_period / 2,
            last: None,
            second: Second::default(),
            latencies: Vec::with_capacity(200),
            all_latencies: Vec::new(),
            totals: Second::default(),
        }
    }

    /// Counts `command`, which arrived at `arrived`; returns false (and counts nothing) for a
    /// command already seen: across a publisher restart two subscribers overlap and both
    /// deliver the commands of that moment.
    pub(crate) fn take(&mut self, command: MotionCommand, arrived: Timestamp) -> bool {
        if self
            .last
            .is_some_and(|last| command.sequence <= last.sequence)
        {
            return false;
        }
        let second = &mut self.second;
        second.commands += 1;
        second.new_commands += u64::from(command.is_new());
        second.stops += u64::from(command.is_stop());
        let mut late = false;
        if let Some(last) = self.last {
            second.lost += command.sequence.saturating_sub(last.sequence + 1);
            let interval = command.timestamp().saturating_since(last.timestamp());
            late = interval > self.late_after;
        }
        let latency = arrived.saturating_since(command.timestamp());
        let over_budget = latency > self.budget;
        second.late_ticks += u64::from(late);
        second.over_budget += u64::from(over_budget);
        second.missed += u64::from(late || over_budget);
        self.latencies.push(latency.as_secs_f64() * 1e6);
        self.last = Some(command);
        true
    }

    /// Closes the second: its latency quantiles, added to the totals.
    pub(crate) fn close_second(&mut self, elapsed_s: f64, rss_kib: u64, open_files: u64) -> Second {
        self.latencies.sort_by(f64::total_cmp);
        let quantile = |q: f64| quantile(&self.latencies, q);
        let mut second = Second {
            elapsed_s,
            rss_kib,
            open_files,
            latency_p50_us: quantile(0.5),
            latency_p99_us: quantile(0.99),
            latency_max_us: quantile(1.0),
            ..self.second
        };
        if self.latencies.is_empty() {
            second.latency_max_us = 0.0;
        }
        let totals = &mut self.totals;
        totals.commands += second.commands;
        totals.new_commands += second.new_commands;
        totals.stops += second.stops;
        totals.lost += second.lost;
        totals.over_budget += second.over_budget;
        totals.late_ticks += second.late_ticks;
        totals.missed += second.missed;
        self.all_latencies.extend_from_slice(&self.latencies);
        self.latencies.clear();
        self.second = Second::default();
        second
    }
}

pub(crate) fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

#[cfg(test)]
mod tests {
    use super::*;
    use dribble_controller::{CommandFlags, SpeedCommand};

    pub(crate) fn command(sequence: u64, tick_ms: u64) -> MotionCommand {
        MotionCommand {
            sequence,
            timestamp_ns: tick_ms * 1_000_000,
            top_sequence: 0,
            bottom_sequence: 0,
            speed: SpeedCommand::STOP,
            flags: CommandFlags::NEW,
        }
    }

    pub(crate) fn at_us(us: u64) -> Timestamp {
        Timestamp::from_nanos(us * 1000)
    }

    #[test]
    pub(crate) fn gaps_late_ticks_and_slow_commands_are_counted_once_each() {
        let mut watch = CommandWatch::new(&LoopConfig::default());
        watch.take(command(1, 10), at_us(10_100)); // 100 µs
        watch.take(command(2, 20), at_us(20_200));
        watch.take(command(5, 30), at_us(30_300)); // 3 and 4 lost
        watch.take(command(6, 50), at_us(50_100)); // begun 20 ms after the last: late
        watch.take(command(7, 60), at_us(63_000)); // 3 ms after its start: over budget
        watch.take(command(8, 80), at_us(83_000)); // both: missed once
        let second = watch.close_second(1.0, 100, 5);
        assert_eq!(second.commands, 6);
        assert_eq!(second.lost, 2);
        assert_eq!(second.late_ticks, 2);
        assert_eq!(second.over_budget, 2);
        assert_eq!(second.missed, 3);
        assert_eq!(second.latency_max_us, 3000.0);
        assert_eq!(second.latency_p50_us, 300.0); // of 100, 100, 200, 300, 3000, 3000 µs
        assert_eq!(watch.totals.lost, 2);
        // The next second starts from zero, the totals go on.
        watch.take(command(9, 90), at_us(90_050));
        let next = watch.close_second(2.0, 100, 5);
        assert_eq!((next.commands, next.lost, next.missed), (1, 0, 0));
        assert_eq!(watch.totals.commands, 7);
        assert_eq!(watch.all_latencies.len(), 7);
    }

    #[test]
    pub(crate) fn a_command_seen_twice_counts_once_and_a_gap_across_a_restart_is_lost() {
        let mut watch = CommandWatch::new(&LoopConfig::default());
        assert!(watch.take(command(1, 10), at_us(10_100)));
        // The second subscriber of a restart delivers 1 again, then 2 and 4.
        assert!(!watch.take(command(1, 10), at_us(10_300)));
        assert!(watch.take(command(2, 20), at_us(20_100)));
        assert!(watch.take(command(4, 40), at_us(40_100)));
        let second = watch.close_second(1.0, 100, 5);
        assert_eq!((second.commands, second.lost), (3, 1));
    }

    #[test]
    pub(crate) fn a_csv_row_has_a_value_for_every_column() {
        let columns = Second::HEADER.split(',').count();
        assert_eq!(Second::default().csv().split(',').count(), columns);
    }
}
