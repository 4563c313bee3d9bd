//! `dribble inspect`: is a recorded dataset sane? Counts, outcomes, the distribution of the
//! expert's commands and phases, a contact sheet of what the policy will see, and how often
//! the ball and the target goal are inside the cameras' images in each phase (the
//! measurement that sets the head pitch; `--head-pitch-sweep` repeats it for other pitches
//! on the same recorded paths, which the expert walks the same whatever the cameras see).

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, bail, ensure};
use clap::Args;
use dribble_sim::camera_geometry::CameraGeometry;
use dribble_sim::dataset::{DatasetIndex, NpyArray, read_npz};
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::Phase;
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use dribble_sim::visibility::{Visibility, VisibilityShares};

use crate::dataset_pictures::{BINS, Sample, draw_contact_sheet, draw_histograms};

#[derive(Debug, Args)]
pub struct InspectArgs {
    /// The dataset directory (with dataset.json).
    dataset: PathBuf,
    /// Where to write the histograms of commands and phases.
    #[arg(long, default_value = "dataset_histograms.png")]
    histograms: PathBuf,
    /// Where to write the contact sheet of sample thumbnails.
    #[arg(long, default_value = "dataset_thumbnails.png")]
    thumbnails: PathBuf,
    /// Measure visibility with this head pitch (degrees, positive down) instead of the one the
    /// dataset was recorded with.
    #[arg(long, allow_hyphen_values = true)]
    head_pitch: Option<f32>,
    /// Also measure visibility over the Nao's HeadPitch range on the recorded paths, to choose
    /// the pitch for `sim-harness/config/nao_cameras.toml`.
    #[arg(long)]
    head_pitch_sweep: bool,
}

/// Head pitches the sweep measures, degrees (the Nao's range is -38.5..29.5).
const SWEEP_DEG: [f32; 10] = [-10.0, -5.0, 0.0, 5.0, 10.0, 15.0, 18.0, 21.0, 25.0, 29.5];

pub fn run(args: &InspectArgs) -> anyhow::Result<()> {
    let index = DatasetIndex::load_recorded(&args.dataset)?;
    let mut outcomes: BTreeMap<&str, usize> = BTreeMap::new();
    let mut histograms = [[0u64; BINS]; 3];
    let mut phases = [0u64; 4];
    let (mut rows, mut bytes, mut seconds) = (0usize, 0u64, 0.0f64);
    let total_rows: usize = index.episodes.iter().map(|e| e.rows).sum();
    let every = (total_rows / 16).max(1);
    let mut samples = Vec::new();
    let recorded_pitch = recorded_head_pitch(&index);
    let pitch = args.head_pitch.unwrap_or(recorded_pitch);
    let mut pitches = vec![pitch];
    if args.head_pitch_sweep {
        pitches.extend(SWEEP_DEG.iter().filter(|&&p| p != pitch));
    }
    let geometries = pitches
        .iter()
        .map(|&p| CameraGeometry::nao().with_head_pitch(p))
        .collect::<Result<Vec<_>, _>>()?;
    let mut visibility = vec![[VisibilityShares::default(); 4]; pitches.len()];
    let mut driven = PolicyDriven::default();
    for entry in &index.episodes {
        *outcomes.entry(entry.outcome.name()).or_default() += 1;
        let arrays = read_npz(&args.dataset.join(&entry.file))?;
        let array = |name: &str| -> anyhow::Result<&NpyArray> {
            arrays
                .get(name)
                .with_context(|| format!("{} has no {name} array", entry.file))
        };
        check_shapes(&arrays, entry.rows, &entry.file)?;
        let command = array("command")?.as_f32();
        let phase = &array("phase")?.data;
        if let (Some(policy), Some(executed)) =
            (arrays.get("policy_command"), arrays.get("expert_executed"))
        {
            driven.add(&command, &policy.as_f32(), &executed.data, phase);
        }
        let poses = array("robot_pose")?.as_f32();
        let balls = array("ball")?.as_f32();
        let target_side = EpisodeSetup::from_seed(entry.seed).target_side;
        for (row, (pose, ball)) in poses.chunks_exact(3).zip(balls.chunks_exact(2)).enumerate() {
            let p = usize::from(phase[row]);
            if p >= Phase::ALL.len() {
                continue;
            };
            let robot = FieldPose::new(pose[0], pose[1], pose[2]);
            for (geometry, shares) in geometries.iter().zip(&mut visibility) {
                shares[p].add(Visibility::of(
                    geometry,
                    &FieldGeometry::SPL,
                    robot,
                    glam::Vec2::new(ball[0], ball[1]),
                    target_side,
                ));
            }
        }
        for (i, c) in command.chunks_exact(3).enumerate() {
            for (histogram, value) in histograms.iter_mut().zip(c) {
                let bin = (((value + 1.0) / 2.0 * BINS as f32) as usize).min(BINS - 1);
                histogram[bin] += 1;
            }
            if let Some(count) = phases.get_mut(usize::from(phase[i])) {
                *count += 1;
            }
            if (rows + i) % every == 0 && samples.len() < 16 {
                samples.push(Sample {
                    seed: entry.seed,
                    row: i,
                    phase: phase[i],
                    command: [c[0], c[1], c[2]],
                    top: array("top")?.data[i * 19_200..(i + 1) * 19_200].to_vec(),
                    bottom: array("bottom")?.data[i * 4_800..(i + 1) * 4_800].to_vec(),
                });
            }
        }
        rows += entry.rows;
        bytes += entry.bytes;
        seconds += entry.duration_s;
    }
    println!(
        "{}: {} episodes, {} rows, {:.0} simulated seconds, {:.1} MB on disk",
        args.dataset.display(),
        index.episodes.len(),
        rows,
        seconds,
        bytes as f64 / 1e6
    );
    let outcome_list: Vec<String> = outcomes.iter().map(|(k, v)| format!("{k}: {v}")).collect();
    println!("outcomes: {}", outcome_list.join(", "));
    let phase_list: Vec<String> = Phase::ALL
        .iter()
        .zip(phases)
        .map(|(p, n)| format!("{} {:.1}%", p.name(), 100.0 * n as f64 / rows.max(1) as f64))
        .collect();
    println!("phases: {}", phase_list.join(", "));
    if let Some(driver) = &index.driver {
        println!("driven by: {driver}");
        driven.print();
    }
    print_visibility(pitch, recorded_pitch, &visibility[0]);
    if args.head_pitch_sweep {
        print_sweep(&pitches, &visibility);
    }
    draw_histograms(&histograms, &phases, &args.histograms)?;
    println!("histograms: {}", args.histograms.display());
    draw_contact_sheet(&samples, &args.thumbnails)?;
    println!("thumbnails: {}", args.thumbnails.display());
    Ok(())
}

/// A policy-driven dataset's rows: how far the policy's commands were from the expert's
/// labels (the paper's metric on the states the policy itself visits), per phase, and how
/// often the expert's command was executed.
#[derive(Debug, Default)]
struct PolicyDriven {
    distance: [f64; 4],
    rows: [u64; 4],
    executed: u64,
}

impl PolicyDriven {
    fn add(&mut self, labels: &[f32], policy: &[f32], executed: &[u8], phases: &[u8]) {
        let rows = labels.chunks_exact(3).zip(policy.chunks_exact(3));
        for ((label, own), (&phase, &by_expert)) in rows.zip(phases.iter().zip(executed)) {
            let p = usize::from(phase).min(3);
            let squared: f32 = label.iter().zip(own).map(|(a, b)| (a - b) * (a - b)).sum();
            self.distance[p] += f64::from(squared.sqrt());
            self.rows[p] += 1;
            self.executed += u64::from(by_expert);
        }
    }

    fn print(&self) {
        let rows: u64 = self.rows.iter().sum();
        if rows == 0 {
            return;
        }
        let mean = |d: f64, n: u64| if n == 0 { f64::NAN } else { d / n as f64 };
        let phases: Vec<String> = Phase::ALL
            .iter()
            .enumerate()
            .filter(|(p, _)| self.rows[*p] > 0)
            .map(|(p, phase)| {
                format!(
                    "{} {:.3}",
                    phase.name(),
                    mean(self.distance[p], self.rows[p])
                )
            })
            .collect();
        println!(
            "policy vs the expert's labels on the visited states: error {:.3} ({}); the expert's command executed in {:.1}% of rows",
            mean(self.distance.iter().sum(), rows),
            phases.join(", "),
            100.0 * self.executed as f64 / rows as f64
        );
    }
}

/// The head pitch the dataset was recorded with; 0 for datasets from before the head could
/// pitch (their camera record is not structured).
fn recorded_head_pitch(index: &DatasetIndex) -> f32 {
    index.simulator["cameras"]["head"]["pitch_deg"]
        .as_f64()
        .map_or(0.0, |p| p as f32)
}

/// Per phase: rows with the ball inside the top, the bottom, either image, and with a post of
/// the target goal inside the top image.
fn print_visibility(pitch: f32, recorded: f32, shares: &[VisibilityShares; 4]) {
    let source = if pitch == recorded {
        "as recorded"
    } else {
        "not as recorded: geometry on the recorded paths"
    };
    println!("visibility, head pitch {pitch:.1} deg ({source}):");
    println!(
        "  {:<10} {:>7} {:>10} {:>13} {:>13} {:>16}",
        "phase", "rows", "ball top", "ball bottom", "ball either", "target post top"
    );
    let mut all = VisibilityShares::default();
    for (phase, s) in Phase::ALL.iter().zip(shares) {
        all.merge(s);
        print_visibility_row(phase.name(), s);
    }
    print_visibility_row("all", &all);
}

fn print_visibility_row(name: &str, s: &VisibilityShares) {
    println!(
        "  {:<10} {:>7} {:>9.1}% {:>12.1}% {:>12.1}% {:>15.1}%",
        name,
        s.rows,
        s.percent(s.ball_in_top),
        s.percent(s.ball_in_bottom),
        s.percent(s.ball_in_either),
        s.percent(s.target_post_in_top)
    );
}

/// One line per pitch: the ball in either image over approach, align and dribble rows (the
/// aim is at least 95 %), per phase, and the target goal in the top image.
fn print_sweep(pitches: &[f32], visibility: &[[VisibilityShares; 4]]) {
    println!("head pitch sweep (geometry on the recorded paths):");
    println!(
        "  {:>6} {:>22} {:>9} {:>7} {:>8} {:>17} {:>16}",
        "pitch",
        "ball either app+al+dr",
        "approach",
        "align",
        "dribble",
        "post top (all)",
        "post top (al+dr)"
    );
    let mut order: Vec<usize> = (0..pitches.len()).collect();
    order.sort_by(|&a, &b| pitches[a].total_cmp(&pitches[b]));
    for i in order {
        let [search, approach, align, dribble] = visibility[i];
        let mut moving = approach;
        moving.merge(&align);
        moving.merge(&dribble);
        let mut all = moving;
        all.merge(&search);
        let mut near = align;
        near.merge(&dribble);
        println!(
            "  {:>6.1} {:>21.1}% {:>8.1}% {:>6.1}% {:>7.1}% {:>16.1}% {:>15.1}%",
            pitches[i],
            moving.percent(moving.ball_in_either),
            approach.percent(approach.ball_in_either),
            align.percent(align.ball_in_either),
            dribble.percent(dribble.ball_in_either),
            all.percent(all.target_post_in_top),
            near.percent(near.target_post_in_top)
        );
    }
}

fn check_shapes(
    arrays: &BTreeMap<String, NpyArray>,
    rows: usize,
    file: &str,
) -> anyhow::Result<()> {
    let expected: [(&str, &str, Vec<usize>); 7] = [
        ("top", "|u1", vec![rows, 120, 160]),
        ("bottom", "|u1", vec![rows, 60, 80]),
        ("command", "<f4", vec![rows, 3]),
        ("robot_pose", "<f4", vec![rows, 3]),
        ("ball", "<f4", vec![rows, 2]),
        ("time_s", "<f8", vec![rows]),
        ("phase", "|u1", vec![rows]),
    ];
    for (name, descr, shape) in expected {
        let Some(array) = arrays.get(name) else {
            bail!("{file} has no {name} array");
        };
        ensure!(
            array.descr == descr && array.shape == shape,
            "{file}: {name} is {} {:?}, expected {descr} {shape:?}",
            array.descr,
            array.shape
        );
    }
    Ok(())
}
