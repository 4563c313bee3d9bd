//! `dribble record`: the expert plays episodes while both cameras are rendered; every
//! computed command is stored with the thumbnails it was computed from.

use std::fs;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail, ensure};
use clap::{Args, ValueEnum};
use dribble_controller::policy::manifest::PolicyManifest;
use dribble_sim::conditions::Conditions;
use dribble_sim::dataset::{DatasetIndex, EpisodeRecording};
use dribble_sim::episode::{EpisodeSetup, reserved_range};
use dribble_sim::episode_observer::{EpisodeObserver, NoObserver};
use dribble_sim::expert::{Expert, ExpertConfig};
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Multisampling;
use dribble_sim::runner::{Driver, EpisodeConfig, ExpertLabels, run_episode_observed};

use crate::controller_session::{ControllerOptions, ControllerSession};
use crate::episodes::Episodes;
use crate::foxglove_episodes::FoxgloveArgs;
use crate::recording::{
    announce, configuration, episode_progress, keep_episode, open_index, report_dataset,
};
use dribble_sim::expert::Teacher;

/// Who labels the states a learned policy visits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Labeller {
    /// The scripted teacher that `--teacher` names (`expert` is accepted for the same).
    #[value(alias = "expert")]
    Teacher,
}

#[derive(Debug, Args)]
pub struct RecordArgs {
    /// `train` (seeds 0..99), `test` (10000..10019) or a seed range such as `0..10`.
    #[arg(long, default_value = "train")]
    pub(crate) episodes: Episodes,
    /// Dataset directory: one `episode_SEED.npz` per episode and `dataset.json`. Episodes
    /// already there are kept and skipped, so an interrupted recording resumes.
    #[arg(long, default_value = "dataset")]
    pub(crate) out: PathBuf,
    /// Time limit per episode, simulated seconds (positive and finite).
    #[arg(long, default_value_t = 90.0, value_parser = crate::episodes::time_limit)]
    pub(crate) time_limit: f32,
    /// `teacher` (the scripted teacher `--teacher` names drives; `expert` is accepted for the
    /// same), or the path of a policy's `policy.toml`: it drives through its controller and
    /// `--label-with` labels the states it visits.
    #[arg(long, default_value = crate::episodes::TEACHER_DRIVER)]
    pub(crate) driver: String,
    /// Who labels a policy-driven episode's rows (needed with a policy `--driver`).
    #[arg(long, value_enum)]
    pub(crate) label_with: Option<Labeller>,
    /// Probability, per computed command, that the labeller's command is executed instead
    /// of the policy's (DAgger's β; drawn from a generator seeded by the episode).
    #[arg(long, default_value_t = 0.0)]
    pub(crate) beta: f64,
    /// Which teacher drives (with `--driver teacher`) or labels (with `--label-with
    /// teacher`): `paper`, the paper's expert, which reads the ball's true position; or
    /// `observable`, which knows the ball only while a camera shows it and where it last
    /// saw it (DESIGN.md, "Teachers"); or `orbit`, the observable one that also walks straight
    /// to the ball and circles it to the left until the top camera shows the target goal; or
    /// `detector`, the observable one seeing the ball only where enough of it is unoccluded in
    /// an image; or `detector-one-way`, the detector one going around the ball always
    /// clockwise where it must go around it. Recorded in dataset.json.
    #[arg(long, alias = "expert", default_value_t = Teacher::Paper)]
    pub(crate) teacher: Teacher,
    /// What the cameras see the episodes under: `clean`, NAME:SEVERITY[,...] (see `dribble
    /// eval --help`) or `randomized` (each episode draws its own conditions from its seed,
    /// never the unseen venue). Recorded in dataset.json, per episode.
    #[arg(long, visible_alias = "conditions", default_value = "clean")]
    pub(crate) condition: Conditions,
    /// Also render every frame as a clean camera in clean light would show the same scene (no
    /// camera effect, no light condition; the venue and the robots standing about kept) and
    /// store its thumbnails beside the row's (`top_clean`, `bottom_clean`): a policy trained
    /// on clean renders can then label conditioned rows from what it would have seen (the
    /// trainer's `--distill-camera-clean`). Up to twice the rendering time.
    #[arg(long)]
    pub(crate) clean_twin: bool,
    /// Samples a pixel of the cameras' images: 4 (every shipped result's frames) or 1 (about
    /// two fifths of the CPU of a clean episode; see `dribble eval --help`). Named in
    /// dataset.json's simulator when not 4, so a dataset never mixes the two.
    #[arg(long, default_value_t = Multisampling::Four)]
    pub(crate) camera_samples: Multisampling,
    #[command(flatten)]
    pub(crate) controller: ControllerOptions,
    #[command(flatten)]
    pub(crate) foxglove: FoxgloveArgs,
}

pub fn run(args: &RecordArgs) -> anyhow::Result<()> {
    if args.label_with.is_some() {
        refuse_reserved_seeds(args.episodes.0.clone())?;
    }
    fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        multisampling: args.camera_samples,
        ..EpisodeConfig::default()
    };
    let expert_config = ExpertConfig::default();
    let policy = policy_driver(args)?;
    let (simulator, expert, driver) =
        configuration(args, &config, &expert_config, policy.as_ref())?;
    let mut index = open_index(args, simulator, expert, driver)?;
    let todo = episodes_to_record(args, &index);
    let mut renderer = config.renderer()?;
    if args.clean_twin {
        renderer = renderer.with_clean_twin()?;
    }
    println!("adapter: {}", renderer.adapter());

    let progress = episode_progress(todo.len());
    let started = Instant::now();
    let (mut simulated, mut bytes_written) = (0.0f64, 0u64);
    let mut session: Option<ControllerSession> = None;
    if policy.is_some() && !todo.is_empty() {
        args.controller.start_log()?;
    }
    let mut foxglove = args.foxglove.observer(true)?;
    for seed in todo.iter().copied() {
        progress.set_message(format!("seed {seed}"));
        let setup = EpisodeSetup::from_seed(seed).under(args.condition);
        let mut recording = EpisodeRecording::default();
        let expert = Expert::teaching(
            args.teacher,
            expert_config,
            FieldGeometry::SPL,
            config.cameras,
        );
        let driver = match &policy {
            None => Driver::Expert(expert),
            Some((path, _)) => {
                let open = || ControllerSession::open(&args.controller, path, config.control);
                let link = match &mut session {
                    Some(session) => session.link(),
                    None => session.insert(progress.suspend(open)?).link(),
                };
                let labels = ExpertLabels::new(expert, args.beta, seed);
                Driver::LabelledController(link, Box::new(labels))
            }
        };
        let mut no_observer = NoObserver;
        let observer: &mut dyn EpisodeObserver = match foxglove.as_mut() {
            Some(foxglove) => foxglove,
            None => &mut no_observer,
        };
        let result = run_episode_observed(
            &setup,
            &config,
            driver,
            Some(&mut renderer),
            Some(&mut recording),
            observer,
        )
        .with_context(|| format!("episode {seed}"))?;
        if let Some(failure) = foxglove.as_mut().and_then(|f| f.take_failure()) {
            return Err(failure.context(format!("episode {seed}: writing it for Foxglove")));
        }
        if let Some(failure) = &result.failure {
            // Nothing of a failed episode is kept; the episodes before it are.
            if let Some(session) = session.take() {
                session.finish(&args.controller);
            }
            bail!(
                "episode {seed} failed: {failure}; the episodes before it are kept, and running \
                 the same command again resumes with it (the controller's log: {})",
                args.controller.controller_log.display()
            );
        }
        let bytes = keep_episode(args, &mut index, seed, &result, &recording)?;
        simulated += f64::from(result.duration_s);
        bytes_written += bytes;
        progress.suspend(|| announce(seed, &result, &recording, bytes, policy.is_some()));
        progress.inc(1);
    }
    progress.finish_and_clear();
    if let Some(session) = session.take() {
        session.finish(&args.controller);
    }
    if !todo.is_empty() {
        let wall = started.elapsed().as_secs_f64();
        println!(
            "recorded {} episodes in {wall:.1} s: {:.1} episodes per minute, {:.1} simulated seconds per wall second, {:.1} MB",
            todo.len(),
            todo.len() as f64 / wall * 60.0,
            simulated / wall,
            bytes_written as f64 / 1e6
        );
    }
    report_dataset(args, &mut index, !todo.is_empty())
}

/// A labelled round (DAgger) is training data: none of its seeds may be one kept for choosing
/// or reporting (test, selection, fresh).
fn refuse_reserved_seeds(seeds: std::ops::Range<u64>) -> anyhow::Result<()> {
    let reserved: Vec<String> = seeds
        .filter_map(|seed| reserved_range(seed).map(|range| format!("{seed} ({range})")))
        .take(5)
        .collect();
    ensure!(
        reserved.is_empty(),
        "a labelled round is training data, and {} are seeds kept for choosing or reporting, \
         never trained on: DAgger rounds take seeds from 1000..9999",
        reserved.join(", ")
    );
    Ok(())
}

/// The asked-for seeds whose episodes are not in the dataset yet (a rerun resumes).
fn episodes_to_record(args: &RecordArgs, index: &DatasetIndex) -> Vec<u64> {
    let done = |seed: u64| {
        index
            .episodes
            .iter()
            .any(|e| e.seed == seed && args.out.join(&e.file).is_file())
    };
    let todo: Vec<u64> = args.episodes.0.clone().filter(|&s| !done(s)).collect();
    let skipped = args.episodes.0.clone().count() - todo.len();
    if skipped > 0 {
        println!(
            "{skipped} episode(s) already recorded in {}, kept",
            args.out.display()
        );
    }
    todo
}

/// The policy that drives, when `--driver` names one, with its manifest; checks the flags
/// that go with it.
fn policy_driver(args: &RecordArgs) -> anyhow::Result<Option<(PathBuf, PolicyManifest)>> {
    if !(0.0..=1.0).contains(&args.beta) {
        bail!("--beta {} is not a probability (0 to 1)", args.beta);
    }
    if crate::episodes::is_teacher_driver(&args.driver) {
        if args.label_with.is_some() || args.beta != 0.0 {
            bail!(
                "--label-with and --beta go with a policy --driver; the teacher labels its own \
                 demonstrations"
            );
        }
        return Ok(None);
    }
    if args.label_with.is_none() {
        bail!(
            "a policy --driver needs --label-with teacher: the rows must hold the teacher's \
             commands for the states the policy visits"
        );
    }
    let path = PathBuf::from(&args.driver);
    let manifest = PolicyManifest::load(&path)?;
    println!(
        "driver: {} policy {} (trained on {:?}), labelled by the {} teacher, beta {}, transport {}",
        manifest.kind,
        path.display(),
        manifest.training.dataset,
        args.teacher.name(),
        args.beta,
        args.controller.describe()
    );
    Ok(Some((path, manifest)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_labelled_round_refuses_the_seeds_kept_for_choosing_and_reporting() {
        for seeds in [
            20_000..20_005,
            10_000..10_020,
            30_050..30_051,
            9_990..10_001,
        ] {
            let error = refuse_reserved_seeds(seeds.clone()).expect_err("refused");
            assert!(
                error.to_string().contains("never trained on"),
                "{seeds:?}: {error}"
            );
        }
        assert!(refuse_reserved_seeds(1000..1020).is_ok());
        assert!(refuse_reserved_seeds(0..100).is_ok());
    }
}
