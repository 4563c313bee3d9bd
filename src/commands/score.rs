//! `dribble score`: the paper's error of a learned policy on a recorded dataset, computed by
//! the robot's own code. Every episode is replayed through `OnnxPolicy` exactly as the
//! controller runs it: the R-CNN stepped from a zero state at each episode's start, the
//! H-CNN gated in Rust. The error of a row is the Euclidean distance between the command the
//! controller would send (clamped to [-1, 1], a non-finite answer sent as a stop) and the
//! expert's (DESIGN.md, "Metrics"); the trainer computes the same number in PyTorch.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail, ensure};
use clap::{Args, ValueEnum};
use dribble_controller::policy::{Engine, EngineOptions, OnnxPolicy, PolicyManifest};
use dribble_controller::{BottomThumbnail, Policy, PolicyInput, SpeedCommand, TopThumbnail};
use dribble_sim::dataset::{DatasetIndex, NpyArray, read_npz};
use dribble_sim::expert::Phase;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

#[derive(Debug, Args)]
pub struct ScoreArgs {
    /// The policy's manifest (`policy.toml`).
    #[arg(long)]
    policy: PathBuf,
    /// A recorded dataset directory (with dataset.json), e.g. from `dribble record`.
    #[arg(long)]
    dataset: PathBuf,
    /// Fail unless the dataset is the one the policy's manifest names for this role: `train`
    /// (the data it learned from) or `test` (the data its test error was measured on).
    #[arg(long, value_enum)]
    expect: Option<Role>,
    /// Also write the errors (overall, per phase, per episode) as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// The engine that runs the policy: `compiled` (the controller's default) or `tract`.
    #[arg(long, default_value = "compiled")]
    engine: Engine,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Role {
    Train,
    Test,
}

/// Sum of errors and row count.
#[derive(Clone, Copy, Debug, Default)]
struct ErrorSum {
    sum: f64,
    rows: u64,
}

impl ErrorSum {
    fn add(&mut self, error: f64) {
        self.sum += error;
        self.rows += 1;
    }

    fn mean(&self) -> Option<f64> {
        (self.rows > 0).then(|| self.sum / self.rows as f64)
    }
}

pub fn run(args: &ScoreArgs) -> anyhow::Result<()> {
    let index = DatasetIndex::load_recorded(&args.dataset)?;
    index.verify(&args.dataset)?;
    let hash = index
        .compute_content_hash()
        .context("the dataset has episodes without a hash")?;
    let options = EngineOptions {
        engine: args.engine,
        isa: None,
    };
    let (mut policy, manifest) = OnnxPolicy::load_with(&args.policy, options)
        .with_context(|| format!("loading the policy {}", args.policy.display()))?;
    let role = role_of(&manifest, &hash);
    println!(
        "policy {} ({:?}, engine {}), dataset {} ({} episodes, content hash {}): {}",
        args.policy.display(),
        manifest.kind,
        policy.engine(),
        args.dataset.display(),
        index.episodes.len(),
        short(&hash),
        match role {
            Some(Role::Train) => "the data it was trained on",
            Some(Role::Test) => "the test data named in its manifest",
            None => "data its manifest does not name",
        }
    );
    if let Some(expected) = args.expect {
        check_role(&manifest, expected, role, &hash, &args.policy)?;
    }

    let total_rows: usize = index.episodes.iter().map(|e| e.rows).sum();
    let progress = ProgressBar::new(total_rows as u64);
    progress.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} rows, {elapsed} elapsed, eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let started = Instant::now();
    let (mut overall, mut phases) = (ErrorSum::default(), [ErrorSum::default(); 4]);
    let mut episodes = Vec::new();
    let mut step_ms: Vec<f64> = Vec::with_capacity(total_rows);
    let (mut top, mut bottom) = (TopThumbnail::black(), BottomThumbnail::black());
    for entry in &index.episodes {
        let path = args.dataset.join(&entry.file);
        let (episode, rows) = score_episode(
            &mut policy,
            &path,
            (&mut top, &mut bottom),
            (&mut overall, &mut phases),
            &mut step_ms,
        )?;
        episodes.push((entry.seed, episode));
        progress.inc(rows as u64);
    }
    progress.finish_and_clear();

    let mean = overall.mean().context("the dataset has no rows")?;
    step_ms.sort_by(f64::total_cmp);
    let quantile = |q: f64| step_ms[((step_ms.len() - 1) as f64 * q).round() as usize];
    let (median_ms, p99_ms) = (quantile(0.5), quantile(0.99));
    println!(
        "error {mean:.4} over {} rows ({:.1} s; policy step median {median_ms:.3} ms, p99 {p99_ms:.3} ms, this machine)",
        overall.rows,
        started.elapsed().as_secs_f64(),
    );
    for (phase, sum) in Phase::ALL.iter().zip(&phases) {
        match sum.mean() {
            Some(error) => println!("  {:<9} {error:.4} ({} rows)", phase.name(), sum.rows),
            None => println!("  {:<9} -      (0 rows)", phase.name()),
        }
    }
    // A committed modal CNN: how often it changed hypotheses (a reset is no change).
    let switches = match &policy {
        OnnxPolicy::Cnn(cnn, _) => cnn.commitment().map(|commitment| {
            println!(
                "hypothesis switches: {} in {} rows ({:.2} % of the rows; {} hypotheses, switch margin {})",
                commitment.switches(),
                overall.rows,
                100.0 * commitment.switches() as f64 / overall.rows as f64,
                commitment.count(),
                commitment.switch_margin()
            );
            commitment.switches()
        }),
        _ => None,
    };
    if let Some(path) = &args.json {
        let report = json!({
            "hypothesis_switches": switches,
            "policy": args.policy,
            "dataset": args.dataset,
            "dataset_hash": hash,
            "role": role.map(|r| format!("{r:?}").to_lowercase()),
            "error": mean,
            "rows": overall.rows,
            "step_ms": {"median": median_ms, "p99": p99_ms},
            "engine": policy.engine().to_string(),
            "phases": Phase::ALL.iter().zip(&phases).map(|(p, s)| {
                (p.name().to_owned(), json!({"error": s.mean(), "rows": s.rows}))
            }).collect::<serde_json::Map<_, _>>(),
            "episodes": episodes.iter().map(|(seed, s)| {
                json!({"seed": seed, "error": s.mean(), "rows": s.rows})
            }).collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Runs `policy` over one episode's rows from its first (state reset), adding each row's
/// error to `overall` and its phase's sum and each step's time to `step_ms`; the episode's
/// own sum and its rows.
fn score_episode(
    policy: &mut OnnxPolicy,
    path: &std::path::Path,
    (top, bottom): (&mut TopThumbnail, &mut BottomThumbnail),
    (overall, phases): (&mut ErrorSum, &mut [ErrorSum; 4]),
    step_ms: &mut Vec<f64>,
) -> anyhow::Result<(ErrorSum, usize)> {
    let arrays = read_npz(path)?;
    let array = |name: &str| {
        arrays
            .get(name)
            .with_context(|| format!("{} has no {name} array", path.display()))
    };
    let (tops, bottoms) = (&array("top")?.data, &array("bottom")?.data);
    let commands = array("command")?.as_f32();
    let phase = &array("phase")?.data;
    let rows = phase.len();
    let executed = ExecutedCommands::of(&arrays, &commands, rows, path)?;
    ensure!(
        tops.len() == rows * top.as_bytes().len()
            && bottoms.len() == rows * bottom.as_bytes().len()
            && commands.len() == rows * 3,
        "{}: the arrays disagree on the number of rows ({rows} phases)",
        path.display()
    );
    policy.reset();
    let mut episode = ErrorSum::default();
    for row in 0..rows {
        top.as_bytes_mut()
            .copy_from_slice(&tops[row * 19_200..(row + 1) * 19_200]);
        bottom
            .as_bytes_mut()
            .copy_from_slice(&bottoms[row * 4_800..(row + 1) * 4_800]);
        let step_started = Instant::now();
        let answer = policy.step(PolicyInput {
            top: &*top,
            bottom: &*bottom,
            previous: executed.previous(row),
        });
        step_ms.push(step_started.elapsed().as_secs_f64() * 1e3);
        let sent = match answer {
            Ok(out) => {
                SpeedCommand::new(out.forward, out.left, out.turn).unwrap_or(SpeedCommand::STOP)
            }
            Err(_) => SpeedCommand::STOP,
        };
        let expert = &commands[row * 3..row * 3 + 3];
        let error = sent
            .as_array()
            .iter()
            .zip(expert)
            .map(|(a, b)| f64::from(a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        overall.add(error);
        episode.add(error);
        if let Some(sum) = phases.get_mut(usize::from(phase[row])) {
            sum.add(error);
        }
    }
    Ok((episode, rows))
}

/// Which of the manifest's datasets has content hash `hash`.
/// The command each row's robot executed: the label in an expert-driven episode; in a
/// policy-driven one the policy's, or the expert's where DAgger's draw executed it
/// (`expert_executed`). A network that reads the last command is given, at each row, the
/// command executed at the row before (clamped, as sent), a stop at an episode's first.
struct ExecutedCommands<'a> {
    labels: &'a [f32],
    driven: Option<(Vec<f32>, &'a [u8])>,
}

impl<'a> ExecutedCommands<'a> {
    fn of(
        arrays: &'a std::collections::BTreeMap<String, NpyArray>,
        labels: &'a [f32],
        rows: usize,
        path: &std::path::Path,
    ) -> anyhow::Result<Self> {
        let driven = match (arrays.get("policy_command"), arrays.get("expert_executed")) {
            (Some(commands), Some(flags)) => {
                let commands = commands.as_f32();
                ensure!(
                    commands.len() == rows * 3 && flags.data.len() == rows,
                    "{}: policy_command or expert_executed disagrees with the {rows} rows",
                    path.display()
                );
                Some((commands, &flags.data[..]))
            }
            (None, None) => None,
            _ => bail!(
                "{}: a policy-driven episode needs both policy_command and expert_executed",
                path.display()
            ),
        };
        Ok(Self { labels, driven })
    }

    /// The command executed before `row`, as the controller would have sent it.
    fn previous(&self, row: usize) -> SpeedCommand {
        let Some(before) = row.checked_sub(1) else {
            return SpeedCommand::STOP;
        };
        let values = match &self.driven {
            Some((commands, flags)) if flags[before] == 0 => &commands[before * 3..before * 3 + 3],
            _ => &self.labels[before * 3..before * 3 + 3],
        };
        SpeedCommand::new(values[0], values[1], values[2]).unwrap_or(SpeedCommand::STOP)
    }
}

fn role_of(manifest: &PolicyManifest, hash: &str) -> Option<Role> {
    let training = &manifest.training;
    if training.dataset_hash.as_deref() == Some(hash) {
        Some(Role::Train)
    } else if training.test_dataset_hash.as_deref() == Some(hash) {
        Some(Role::Test)
    } else {
        None
    }
}

fn check_role(
    manifest: &PolicyManifest,
    expected: Role,
    found: Option<Role>,
    hash: &str,
    policy: &Path,
) -> anyhow::Result<()> {
    if found == Some(expected) {
        return Ok(());
    }
    let named = match expected {
        Role::Train => manifest.training.dataset_hash.as_deref(),
        Role::Test => manifest.training.test_dataset_hash.as_deref(),
    };
    let what = match expected {
        Role::Train => "trained on",
        Role::Test => "tested on",
    };
    match named {
        Some(named) => bail!(
            "{} was {what} dataset {} ({}), but this dataset is {}: a model trained on other \
             data, or a dataset with episodes missing, added or re-recorded",
            policy.display(),
            short(named),
            manifest.training.dataset,
            short(hash)
        ),
        None => bail!(
            "{} names no dataset it was {what} (its [training] record has no hash)",
            policy.display()
        ),
    }
}

fn short(hash: &str) -> &str {
    hash.get(..12).unwrap_or(hash)
}
