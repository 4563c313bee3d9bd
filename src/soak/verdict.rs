//! The soak's verdict: the controller's memory account, the faults' reports, the printed
//! and JSON summary, and every criterion missed.

use std::fs;

use anyhow::{Context, bail};

use crate::soak::faults::FaultReport;
use serde_json::json;

use super::command_watch::{CommandWatch, Second, quantile};
use crate::commands::soak::SoakArgs;
use dribble_controller::policy::engine::Isa;
use dribble_controller::run_statistics::RunStatistics;

/// Every criterion the soak missed, in words (empty: it passed).
pub(crate) fn failures(
    args: &SoakArgs,
    totals: &Second,
    missed_share: f64,
    growth: u64,
    files: (u64, u64),
    faults: Option<&[FaultReport]>,
) -> Vec<String> {
    let mut failures = Vec::new();
    if totals.commands == 0 {
        failures.push("no command arrived".to_owned());
    }
    if totals.lost > 0 {
        failures.push(format!("{} commands lost", totals.lost));
    }
    if missed_share > args.max_missed_share {
        failures.push(format!(
            "{:.4} % of ticks missed their deadline (allowed {:.4} %)",
            100.0 * missed_share,
            100.0 * args.max_missed_share
        ));
    }
    if growth > args.max_rss_growth_kib {
        failures.push(format!(
            "the controller's memory grew {growth} KiB after the warm-up (allowed {} KiB)",
            args.max_rss_growth_kib
        ));
    }
    if files.1 > files.0 {
        failures.push(format!("open files grew from {} to {}", files.0, files.1));
    }
    for report in faults.unwrap_or_default().iter().filter(|r| !r.passed) {
        failures.push(format!("fault {}: {}", report.kind.name(), report.detail));
    }
    failures
}

/// Prints and writes the summary; fails if a criterion is not met.
/// The controller's memory and open files over the soak.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MemoryAccount {
    /// Resident set at the end of the warm-up (or at the first second after it), KiB.
    pub(crate) rss_start: u64,
    pub(crate) rss_end: u64,
    /// The most after the warm-up, KiB, and its growth over `rss_start`.
    pub(crate) rss_max: u64,
    pub(crate) growth: u64,
    /// Open files in the first and the last second.
    pub(crate) files: (u64, u64),
}

impl MemoryAccount {
    pub(crate) fn of(seconds: &[Second], warm_up_s: f64) -> Self {
        let (warm_up, settled): (Vec<&Second>, Vec<&Second>) =
            seconds.iter().partition(|s| s.elapsed_s <= warm_up_s);
        let rss_start = warm_up
            .last()
            .or(settled.first())
            .map_or(0, |second| second.rss_kib);
        let rss_max = settled.iter().map(|s| s.rss_kib).max().unwrap_or(rss_start);
        Self {
            rss_start,
            rss_end: seconds.last().map_or(0, |second| second.rss_kib),
            rss_max,
            growth: rss_max.saturating_sub(rss_start),
            files: (
                seconds.first().map_or(0, |s| s.open_files),
                seconds.last().map_or(0, |s| s.open_files),
            ),
        }
    }
}

/// Prints each fault's verdict; the same as JSON for soak.json.
pub(crate) fn fault_reports(faults: &[FaultReport]) -> Vec<serde_json::Value> {
    for report in faults {
        let verdict = if report.passed {
            "as documented"
        } else {
            "NOT as documented"
        };
        let (kind, detail) = (report.kind.name(), &report.detail);
        println!("soak: fault {kind}: {verdict} ({detail})");
    }
    faults
        .iter()
        .map(|r| json!({"fault": r.kind.name(), "passed": r.passed, "detail": r.detail}))
        .collect()
}

/// The engine the controller's start-up line names (`policy: ... , engine compiled (ssse3)`),
/// if it printed one.
fn engine_of(controller_log: &str) -> Option<&str> {
    controller_log
        .lines()
        .find(|line| line.starts_with("policy: "))
        .and_then(|line| line.rsplit_once(", engine "))
        .map(|(_, engine)| engine.trim())
}

pub(crate) fn summarise(
    args: &SoakArgs,
    seconds: &[Second],
    watch: &mut CommandWatch,
    faults: Option<&[FaultReport]>,
) -> anyhow::Result<()> {
    let totals = watch.totals;
    let MemoryAccount {
        rss_start,
        rss_end,
        rss_max,
        growth,
        files,
    } = MemoryAccount::of(seconds, args.warm_up_s);
    watch.all_latencies.sort_by(f64::total_cmp);
    let latency = |q: f64| quantile(&watch.all_latencies, q);
    let missed = totals.missed;
    let missed_share = missed as f64 / totals.commands.max(1) as f64;
    println!(
        "soak: {:.1} min, {} commands ({} computed, {} stops), {} lost",
        seconds.last().map_or(0.0, |s| s.elapsed_s) / 60.0,
        totals.commands,
        totals.new_commands,
        totals.stops,
        totals.lost
    );
    println!(
        "soak: latency from tick start to arrival p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs; \
         missed deadlines {missed} ({:.4} %: {} over the {:?} budget, {} ticks begun late)",
        latency(0.5),
        latency(0.99),
        latency(1.0),
        100.0 * missed_share,
        totals.over_budget,
        watch.budget,
        totals.late_ticks
    );
    println!(
        "soak: controller RSS {rss_start} KiB after the {:.0} s warm-up, {rss_end} KiB at the \
         end (max {rss_max}, growth {growth} KiB); open files {} -> {}",
        args.warm_up_s, files.0, files.1
    );
    let fault_json = fault_reports(faults.unwrap_or_default());
    // The controller's own account, printed as it stops (SIGTERM): ticks, frames and its tick
    // time from inside the loop.
    let controller_log = fs::read_to_string(args.out.join("controller.log")).unwrap_or_default();
    let controller_statistics = match RunStatistics::from_log(&controller_log) {
        Ok(statistics) => {
            for line in statistics.to_string().lines() {
                println!("soak: the controller says: {line}");
            }
            serde_json::to_value(&statistics)?
        }
        Err(why) => {
            println!("soak: {why}");
            serde_json::Value::Null
        }
    };
    let failures = failures(args, &totals, missed_share, growth, files, faults);
    let summary = json!({
        "failures": failures,
        "faults": fault_json,
        "controller_statistics": controller_statistics,
        "policy": args.policy,
        "isa": args.isa.map(Isa::name),
        "engine": engine_of(&controller_log),
        "minutes": args.minutes,
        "commands": totals.commands,
        "computed": totals.new_commands,
        "stops": totals.stops,
        "lost": totals.lost,
        "missed": missed,
        "missed_share": missed_share,
        "over_budget": totals.over_budget,
        "late_ticks": totals.late_ticks,
        "latency_us": {"p50": latency(0.5), "p99": latency(0.99), "max": latency(1.0)},
        "rss_kib": {"after_warm_up": rss_start, "end": rss_end, "max": rss_max, "growth": growth},
        "open_files": {"start": files.0, "end": files.1},
        "limits": {
            "max_rss_growth_kib": args.max_rss_growth_kib,
            "max_missed_share": args.max_missed_share,
        },
    });
    let summary_path = args.out.join("soak.json");
    fs::write(&summary_path, format!("{summary:#}\n"))
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    println!(
        "soak: wrote {} and {}",
        args.out.join("soak.csv").display(),
        summary_path.display()
    );
    if !failures.is_empty() {
        bail!("soak failed: {}", failures.join("; "));
    }
    println!("soak: passed");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::engine_of;

    #[test]
    fn the_engine_is_read_from_the_controllers_start_up_line() {
        let log = "ts=... event=controller_started\n\
                   policy: cnn from models/policy/x (1 network file(s), fp32, trained on \"train\"), engine compiled (ssse3)\n\
                   statistics {}\n";
        assert_eq!(engine_of(log), Some("compiled (ssse3)"));
        assert_eq!(engine_of("no such line\n"), None);
    }
}
