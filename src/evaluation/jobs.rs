//! `dribble eval --jobs N`: the episodes split into N runs of consecutive seeds, each played by
//! a child `dribble eval` with a simulator, a controller and an iceoryx2 domain of its own;
//! their trajectory files are merged in seed order into the one table, plot and file a
//! serial run writes. Every episode starts from its seed and the controller forgets its state
//! between episodes, so the outcomes are a serial run's (`tests/cli_episodes.rs` checks it).
//!
//! With `--trajectories FILE` the children's files and journals are kept in `FILE.jobs/`
//! until the merged file is written, so that `--resume` (passed on to each child) continues a
//! cut run's shards where they stopped ([`crate::evaluation::journal`]).
//!
//! Children rather than threads: the controller process, the renderer and the iceoryx2 node
//! are per process already, and a child that fails takes only its own episodes with it.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use anyhow::{Context, bail, ensure};
use dribble_sim::runner::EpisodeResult;

use crate::trajectories::file::{read_played_with, read_trajectories};

/// Flags each child gets a value of its own for (the rest are passed on as given).
const PER_JOB_FLAGS: [&str; 6] = [
    "--jobs",
    "--episodes",
    "--plot",
    "--trajectories",
    "--controller-log",
    "--domain",
];

/// `seeds` in `jobs` runs of consecutive seeds, as even as can be (none empty).
pub fn shards(seeds: Range<u64>, jobs: usize) -> Vec<Range<u64>> {
    let count = seeds.end.saturating_sub(seeds.start);
    let jobs = (jobs as u64).clamp(1, count.max(1));
    let (size, extra) = (count / jobs, count % jobs);
    let mut start = seeds.start;
    (0..jobs)
        .map(|job| {
            let end = start + size + u64::from(job < extra);
            let shard = start..end;
            start = end;
            shard
        })
        .filter(|shard| !shard.is_empty())
        .collect()
}

/// `arguments` (this command's, after `eval`) without the flags each job sets for itself.
pub fn shared_arguments(arguments: &[String]) -> Vec<String> {
    let mut kept = Vec::new();
    let mut skip_value = false;
    for argument in arguments {
        if skip_value {
            skip_value = false;
            continue;
        }
        let flag = argument.split('=').next().unwrap_or_default();
        if PER_JOB_FLAGS.contains(&flag) {
            skip_value = !argument.contains('=');
            continue;
        }
        kept.push(argument.clone());
    }
    kept
}

/// What the merged run needs from the parent's arguments.
#[derive(Debug)]
pub struct JobPlan<'a> {
    pub seeds: Range<u64>,
    pub jobs: usize,
    /// This command's arguments after `eval`.
    pub arguments: &'a [String],
    /// The domain the children's are named after.
    pub domain: String,
    pub controller_log: &'a Path,
    /// Where the children's logs, plots and trajectories go (kept when one fails).
    pub scratch: PathBuf,
}

/// The iceoryx2 domain of job `index`: the parent's name and `-job<index>`, within the 32
/// characters a domain name may have. A parent name too long for the suffix keeps its start
/// and gives the rest to a hash of the whole name, so that two parents never share a job's
/// domain (a test's names carry its process id, which grows).
fn job_domain(parent: &str, index: usize) -> String {
    const MAX: usize = 32;
    let suffix = format!("-job{index}");
    if parent.len() + suffix.len() <= MAX {
        return format!("{parent}{suffix}");
    }
    // FNV-1a: stable across runs and platforms, unlike the standard library's hasher.
    let hash = parent.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    let hash = format!("{:08x}", hash as u32);
    let keep = MAX.saturating_sub(suffix.len() + hash.len() + 1);
    let start: String = parent.chars().take(keep).collect();
    format!("{start}-{hash}{suffix}")
}

/// One child `dribble eval` and where its output goes.
struct Job {
    seeds: Range<u64>,
    child: Child,
    log: PathBuf,
    trajectories: PathBuf,
}

/// Plays every episode in `plan.jobs` children; their results in seed order, and the engine
/// they name (the same for all, or an error).
pub fn play(plan: &JobPlan<'_>) -> anyhow::Result<(Vec<EpisodeResult>, Option<String>)> {
    std::fs::create_dir_all(&plan.scratch)
        .with_context(|| format!("cannot create {}", plan.scratch.display()))?;
    let program = std::env::current_exe().context("cannot find this program")?;
    let shared = shared_arguments(plan.arguments);
    let mut jobs = Vec::new();
    for (index, seeds) in shards(plan.seeds.clone(), plan.jobs)
        .into_iter()
        .enumerate()
    {
        let file = |extension: &str| plan.scratch.join(format!("job-{index}.{extension}"));
        let (log, trajectories) = (file("log"), file("json"));
        let controller_log = plan
            .controller_log
            .with_extension(format!("job-{index}.log"));
        let output = std::fs::File::create(&log)
            .with_context(|| format!("cannot write {}", log.display()))?;
        let child = Command::new(&program)
            .arg("eval")
            .args(&shared)
            .arg("--episodes")
            .arg(format!("{}..{}", seeds.start, seeds.end))
            .arg("--domain")
            .arg(job_domain(&plan.domain, index))
            .arg("--plot")
            .arg(file("png"))
            .arg("--trajectories")
            .arg(&trajectories)
            .arg("--controller-log")
            .arg(&controller_log)
            .arg("--keep-journal")
            .stdin(Stdio::null())
            .stdout(output.try_clone()?)
            .stderr(output)
            .spawn()
            .with_context(|| format!("cannot start {}", program.display()))?;
        println!(
            "job {index}: seeds {}..{} (log {})",
            seeds.start,
            seeds.end,
            log.display()
        );
        jobs.push(Job {
            seeds,
            child,
            log,
            trajectories,
        });
    }
    let mut results = Vec::new();
    let mut played_with = Vec::new();
    let mut failed = Vec::new();
    for (index, mut job) in jobs.into_iter().enumerate() {
        let status = job.child.wait()?;
        if !status.success() {
            failed.push(format!(
                "job {index} (seeds {}..{}) {status}; its log {}:\n{}",
                job.seeds.start,
                job.seeds.end,
                job.log.display(),
                tail(&job.log, 12)
            ));
            continue;
        }
        let episodes = read_trajectories(&job.trajectories)?;
        let goals = episodes
            .iter()
            .filter(|r| r.outcome == dribble_sim::dataset::Outcome::Goal)
            .count();
        println!(
            "job {index}: seeds {}..{} done, {goals} goals of {}",
            job.seeds.start,
            job.seeds.end,
            episodes.len()
        );
        played_with.push(read_played_with(&job.trajectories)?);
        results.extend(episodes);
    }
    if !failed.is_empty() {
        bail!("{}", failed.join("\n"));
    }
    results.sort_by_key(|r| r.setup.seed);
    let expected: Vec<u64> = plan.seeds.clone().collect();
    let played: Vec<u64> = results.iter().map(|r| r.setup.seed).collect();
    ensure!(
        played == expected,
        "the jobs played other seeds than asked for"
    );
    played_with.dedup();
    ensure!(
        played_with.len() <= 1,
        "the jobs ran different engines or camera samples: {played_with:?}"
    );
    Ok((results, played_with.pop().and_then(|with| with.engine)))
}

/// The last `lines` lines of a log.
fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_every_seed_once_in_order() {
        assert_eq!(shards(10000..10020, 2), [10000..10010, 10010..10020]);
        assert_eq!(shards(0..7, 3), [0..3, 3..5, 5..7]);
        assert_eq!(shards(5..7, 4), [5..6, 6..7]);
        assert_eq!(shards(3..4, 1), vec![(3..4)]);
    }

    #[test]
    fn a_long_parent_domain_gives_valid_distinct_job_domains() {
        assert_eq!(job_domain("mine", 3), "mine-job3");
        let (a, b) = (
            "dribble-jobs-test-jobs-19833",
            "dribble-jobs-test-jobs-19834",
        );
        for index in [0, 1, 12] {
            let (x, y) = (job_domain(a, index), job_domain(b, index));
            assert!(x.len() <= 32 && y.len() <= 32, "{x} {y}");
            assert_ne!(x, y);
            assert!(x.ends_with(&format!("-job{index}")), "{x}");
            assert!(
                dribble_controller::transport::ipc::Domain::new(Some(&x)).is_ok(),
                "{x}"
            );
        }
        assert_eq!(job_domain(a, 0), job_domain(a, 0));
    }

    #[test]
    fn each_job_sets_its_own_episodes_outputs_and_domain() {
        let arguments: Vec<String> = [
            "--driver",
            "p.toml",
            "--jobs=2",
            "--episodes",
            "test",
            "--plot",
            "a.png",
            "--isa",
            "avx2+fma",
            "--domain=mine",
            "--trajectories",
            "t.json",
            "--controller-log",
            "c.log",
            "--time-limit",
            "5",
        ]
        .map(String::from)
        .to_vec();
        assert_eq!(
            shared_arguments(&arguments),
            [
                "--driver",
                "p.toml",
                "--isa",
                "avx2+fma",
                "--time-limit",
                "5"
            ]
        );
    }
}
