//! DAgger's labelled episodes: a policy drives through a controller, and every recorded row
//! holds the thumbnails the policy saw, the policy's own command and the expert's command
//! for that state. Needs a wgpu adapter (lavapipe on CPU machines).

use std::hash::{DefaultHasher, Hash, Hasher};
use std::sync::{Arc, Mutex};

use dribble_controller::{LoopConfig, Policy, PolicyError, PolicyInput, PolicyOutput};
use dribble_sim::camera_geometry::CameraGeometry;
use dribble_sim::controller_link::{LinkTimeouts, ThreadLink};
use dribble_sim::dataset::{EpisodeRecording, NpyArray, read_npz};
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::{Expert, ExpertConfig, GroundTruth, Phase};
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, EpisodeResult, ExpertLabels, run_episode};
use dribble_sim::world::WorldConfig;

/// Walks forward and turns, whatever it sees, and notes a hash of every pair it saw.
struct Walker {
    seen: Arc<Mutex<Vec<u64>>>,
}

const WALKER: PolicyOutput = PolicyOutput {
    forward: 0.5,
    left: 0.0,
    turn: 0.4,
};

impl Policy for Walker {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        let mut hasher = DefaultHasher::new();
        input.top.as_bytes().hash(&mut hasher);
        input.bottom.as_bytes().hash(&mut hasher);
        if let Ok(mut seen) = self.seen.lock() {
            seen.push(hasher.finish());
        }
        Ok(WALKER)
    }

    fn reset(&mut self) {}
}

fn config() -> EpisodeConfig {
    EpisodeConfig {
        time_limit_s: 6.0,
        ..EpisodeConfig::default()
    }
}

fn renderer() -> Renderer {
    Renderer::new(
        &FieldGeometry::SPL,
        WorldConfig::default().goal_depth,
        &CameraGeometry::nao(),
    )
    .unwrap_or_else(|error| panic!("{error}"))
}

fn expert() -> Expert {
    Expert::new(ExpertConfig::default(), FieldGeometry::SPL)
}

/// A labelled episode driven by the walker in a controller thread: its result, its rows
/// and the hashes of the thumbnails the walker saw.
fn labelled(seed: u64, beta: f64) -> (EpisodeResult, Rows, Vec<u64>) {
    labelled_under(&EpisodeSetup::from_seed(seed), beta, &mut renderer())
}

fn labelled_under(
    setup: &EpisodeSetup,
    beta: f64,
    renderer: &mut Renderer,
) -> (EpisodeResult, Rows, Vec<u64>) {
    let seed = setup.seed;
    let seen = Arc::new(Mutex::new(Vec::new()));
    let walker_seen = Arc::clone(&seen);
    let load = move || Ok(Box::new(Walker { seen: walker_seen }) as Box<dyn Policy>);
    let mut link =
        ThreadLink::spawn(LoopConfig::default(), load, LinkTimeouts::default()).expect("spawn");
    let mut recording = EpisodeRecording::default();
    let labels = ExpertLabels::new(expert(), beta, seed);
    let result = run_episode(
        setup,
        &config(),
        Driver::LabelledController(&mut link, Box::new(labels)),
        Some(renderer),
        Some(&mut recording),
    )
    .expect("renders");
    assert!(result.failure.is_none(), "{:?}", result.failure);
    let seen = seen.lock().expect("not poisoned").clone();
    (result, Rows::of(&recording, seed), seen)
}

/// A recorded episode's arrays, read back from its `.npz`.
struct Rows {
    arrays: std::collections::BTreeMap<String, NpyArray>,
}

impl Rows {
    fn of(recording: &EpisodeRecording, seed: u64) -> Self {
        let path = std::env::temp_dir().join(format!(
            "dribble-labelled-{}-{seed}-{:p}.npz",
            std::process::id(),
            recording
        ));
        recording.write(&path).expect("write");
        let arrays = read_npz(&path).expect("read back");
        std::fs::remove_file(&path).expect("clean up");
        Self { arrays }
    }

    fn len(&self) -> usize {
        self.arrays["phase"].data.len()
    }

    fn f32s(&self, name: &str) -> Vec<f32> {
        self.arrays[name].as_f32()
    }

    fn thumbnail_hashes(&self) -> Vec<u64> {
        self.hashes_of("top", "bottom")
    }

    fn hashes_of(&self, top: &str, bottom: &str) -> Vec<u64> {
        let (top, bottom) = (&self.arrays[top].data, &self.arrays[bottom].data);
        (0..self.len())
            .map(|i| {
                let mut hasher = DefaultHasher::new();
                top[i * 120 * 160..(i + 1) * 120 * 160].hash(&mut hasher);
                bottom[i * 60 * 80..(i + 1) * 60 * 80].hash(&mut hasher);
                hasher.finish()
            })
            .collect()
    }
}

#[test]
fn labels_are_the_experts_commands_for_the_states_the_policy_visited() {
    let seed = 1_000;
    let (result, rows, seen) = labelled(seed, 0.5);
    let n = rows.len();
    assert_eq!(n as u64, result.computed_commands);
    assert!(n > 100, "{n} rows in 6 s");

    // The thumbnails stored are the ones the policy was given, row for row.
    assert_eq!(rows.thumbnail_hashes(), seen);

    // The expert, called directly on the recorded states in order, gives the labels.
    let setup = EpisodeSetup::from_seed(seed);
    let (pose, ball) = (rows.f32s("robot_pose"), rows.f32s("ball"));
    let (labels, phases) = (rows.f32s("command"), &rows.arrays["phase"].data);
    let mut expert = expert();
    for i in 0..n {
        let truth = GroundTruth {
            robot: FieldPose::new(pose[3 * i], pose[3 * i + 1], pose[3 * i + 2]),
            ball: glam::Vec2::new(ball[2 * i], ball[2 * i + 1]),
            target_side: setup.target_side,
            time_s: 0.0, // the paper's expert does not read the clock
        };
        let (command, phase) = expert.decide(&truth);
        assert_eq!(command.as_array(), labels[3 * i..3 * i + 3], "row {i}");
        assert_eq!(phase as u8, phases[i], "row {i}");
    }

    // The policy's own commands are kept beside the labels; the expert's replaced about
    // half of them, as beta says, and the count matches the rows' flags.
    let policy = rows.f32s("policy_command");
    for i in 0..n {
        assert_eq!(
            policy[3 * i..3 * i + 3],
            [WALKER.forward, WALKER.left, WALKER.turn]
        );
    }
    let executed = &rows.arrays["expert_executed"].data;
    let count = executed.iter().filter(|&&e| e == 1).count();
    assert_eq!(count as u64, result.expert_executed);
    assert!(
        (n * 35 / 100..=n * 65 / 100).contains(&count),
        "{count} of {n}"
    );
    // The walker's steady turn would differ from the expert's labels somewhere.
    assert!(labels.chunks(3).any(|l| l != [0.5, 0.0, 0.4]));
}

#[test]
fn beta_one_replays_the_experts_own_episode_and_the_draws_are_seeded() {
    let seed = 1_001;
    let (_, followed, _) = labelled(seed, 1.0);
    let mut recording = EpisodeRecording::default();
    run_episode(
        &EpisodeSetup::from_seed(seed),
        &config(),
        Driver::Expert(expert()),
        Some(&mut renderer()),
        Some(&mut recording),
    )
    .expect("renders");
    let driven = Rows::of(&recording, seed);
    // With the expert's command always executed, the robot goes where the expert takes it.
    assert_eq!(followed.len(), driven.len());
    assert_eq!(followed.f32s("robot_pose"), driven.f32s("robot_pose"));
    assert_eq!(followed.f32s("command"), driven.f32s("command"));
    assert!(
        followed.arrays["phase"]
            .data
            .iter()
            .any(|&p| p != Phase::Search as u8)
    );

    // The same seed and beta draw the same executions; beta 0 lets the policy drive alone.
    let (_, once, _) = labelled(seed + 1, 0.3);
    let (_, again, _) = labelled(seed + 1, 0.3);
    assert_eq!(
        once.arrays["expert_executed"].data,
        again.arrays["expert_executed"].data
    );
    assert_eq!(once.f32s("robot_pose"), again.f32s("robot_pose"));
    let (alone, _, _) = labelled(seed + 1, 0.0);
    assert_eq!(alone.expert_executed, 0);
}

/// The expert driving in this process, its rows with their clean twin's thumbnails when the
/// renderer has one.
fn demonstrated_under(setup: &EpisodeSetup, renderer: &mut Renderer) -> Rows {
    let mut recording = EpisodeRecording::default();
    let result = run_episode(
        setup,
        &config(),
        Driver::Expert(expert()),
        Some(renderer),
        Some(&mut recording),
    )
    .expect("renders");
    assert!(result.failure.is_none(), "{:?}", result.failure);
    Rows::of(&recording, setup.seed)
}

#[test]
fn a_clean_twin_holds_what_the_clean_render_shows_of_the_same_states() {
    // Neither the walker nor the paper's expert reads the images, so an episode under a
    // camera condition visits the clean episode's states: its twin must be the clean rows.
    let seed = 31;
    let conditioned =
        EpisodeSetup::from_seed(seed).under("contrast:3,noise:2".parse().expect("valid"));
    let clean = EpisodeSetup::from_seed(seed);
    let mut twin_renderer = renderer().with_clean_twin().expect("twin");

    let (_, clean_rows, _) = labelled_under(&clean, 0.0, &mut renderer());
    assert!(
        !clean_rows.arrays.contains_key("top_clean"),
        "no twin asked for"
    );
    let (_, rows, _) = labelled_under(&conditioned, 0.0, &mut twin_renderer);
    assert_eq!(
        rows.hashes_of("top_clean", "bottom_clean"),
        clean_rows.thumbnail_hashes()
    );
    let differing = rows
        .thumbnail_hashes()
        .iter()
        .zip(rows.hashes_of("top_clean", "bottom_clean"))
        .filter(|(seen, twin)| **seen != *twin)
        .count();
    assert_eq!(
        differing,
        rows.len(),
        "the conditioned rows are not their twins"
    );

    let demonstrated = demonstrated_under(&conditioned, &mut twin_renderer);
    let clean_demonstrated = demonstrated_under(&clean, &mut renderer());
    assert_eq!(
        demonstrated.hashes_of("top_clean", "bottom_clean"),
        clean_demonstrated.thumbnail_hashes()
    );
    // A clean episode is its own twin: its rows are copied, not rendered again.
    let own = demonstrated_under(&clean, &mut twin_renderer);
    assert_eq!(
        own.hashes_of("top_clean", "bottom_clean"),
        own.thumbnail_hashes()
    );
}
