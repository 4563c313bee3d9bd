//! The soak's seconds: each closed one is a row of `soak.csv`, kept for the summary, and
//! moves the progress bar.

use std::fs;
use std::io::Write as _;
use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use dribble_controller::Timestamp;
use indicatif::{ProgressBar, ProgressStyle};

use super::command_watch::{CommandWatch, Second};
use super::controller_process::sample_process;

/// The soak's seconds: each closed one is a row of `soak.csv`, kept for the summary, and
/// moves the progress bar.
pub(crate) struct SecondLog {
    pub(crate) csv: fs::File,
    pub(crate) start: Timestamp,
    /// When the next second closes.
    pub(crate) next: Timestamp,
    pub(crate) seconds: Vec<Second>,
    pub(crate) progress: ProgressBar,
}

impl SecondLog {
    pub(crate) fn create(
        path: &Path,
        start: Timestamp,
        duration: Duration,
    ) -> anyhow::Result<Self> {
        let mut csv =
            fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
        writeln!(csv, "{}", Second::HEADER)?;
        let progress = ProgressBar::new(duration.as_secs());
        progress.set_style(
            ProgressStyle::with_template("{bar:30} {pos}/{len} s  {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        Ok(Self {
            csv,
            start,
            next: start + Duration::from_secs(1),
            seconds: Vec::new(),
            progress,
        })
    }

    /// Closes the second that ended at `now`, with the controller's memory and open files.
    pub(crate) fn close(
        &mut self,
        now: Timestamp,
        pid: u32,
        watch: &mut CommandWatch,
    ) -> anyhow::Result<()> {
        let elapsed_s = now.saturating_since(self.start).as_secs_f64();
        let (rss_kib, open_files) = sample_process(pid)?;
        let second = watch.close_second(elapsed_s, rss_kib, open_files);
        writeln!(self.csv, "{}", second.csv())?;
        self.progress.set_position(elapsed_s as u64);
        self.progress.set_message(format!(
            "RSS {} KiB, {} files, latency p99 {:.0} µs, lost {}",
            rss_kib, open_files, second.latency_p99_us, watch.totals.lost
        ));
        self.seconds.push(second);
        self.next = self.next + Duration::from_secs(1);
        Ok(())
    }
}
