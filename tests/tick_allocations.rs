//! The controller tick allocates nothing after start-up, with the test policy and with a
//! real ONNX policy of each kind on the compiled engine (the CNN also in int8), on every instruction set this CPU
//! runs (the SSE paths the robots take, with and without Winograd, included), with the
//! once-a-second check of the policy files inside the counted ticks.
//!
//! A counting global allocator counts the allocations made on this test's thread while
//! counting is switched on; the tick runs over random frames with drops, duplicates,
//! reordering, camera silences and broken headers, with a policy that sometimes fails or
//! answers NaN, so every branch of the tick is exercised (the counters prove each ran).

mod support;

use std::time::Duration;

use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::file_watch::PolicyFileWatch;
use dribble_controller::policy::{BrightnessPolicy, Engine, EngineOptions, OnnxPolicy};
use dribble_controller::{
    CameraFrame, CameraInput, Clock, ControlLoop, LoopConfig, ManualClock, Policy, PolicyError,
    PolicyInput, PolicyOutput,
};
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::counting_allocator::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// The test policy, except that about one step in 50 fails (as an allocation-free engine
/// reports a failure) and one in 50 answers NaN.
#[derive(Debug, Default)]
struct FlakyPolicy {
    inner: BrightnessPolicy,
    steps: u64,
}

impl Policy for FlakyPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        self.steps += 1;
        // A fixed pattern, different from the cameras' random one.
        match self.steps.wrapping_mul(0x9e37_79b9_7f4a_7c15) % 50 {
            0 => Err(PolicyError::Engine("flaky on purpose")),
            1 => Ok(PolicyOutput {
                forward: f32::NAN,
                ..PolicyOutput::default()
            }),
            _ => self.inner.step(input),
        }
    }

    fn reset(&mut self) {
        self.inner.reset();
    }
}

/// A camera that mostly delivers its next frame, and sometimes drops one, sends one twice,
/// sends an older one, sends one with a broken header, or goes silent for a while.
struct UnreliableCamera<const W: usize, const H: usize> {
    /// Frames with random pixels, made before counting starts; sent in turn. The last one
    /// has a header no camera may send (a wrong width).
    pool: Vec<Box<CameraFrame<W, H>>>,
    next_sequence: u64,
    silent_ticks: u32,
}

impl<const W: usize, const H: usize> UnreliableCamera<W, H> {
    fn new(rng: &mut ChaCha8Rng) -> Self {
        let mut pool: Vec<_> = (0..4)
            .map(|_| {
                let mut frame = CameraFrame::<W, H>::new_boxed();
                rng.fill_bytes(frame.as_bytes_mut());
                frame
            })
            .collect();
        pool[3].header_mut().width = W as u32 + 1;
        Self {
            pool,
            next_sequence: 0,
            silent_ticks: 0,
        }
    }

    fn frame(&mut self, rng: &mut ChaCha8Rng, clock: &ManualClock) -> Option<&CameraFrame<W, H>> {
        if self.silent_ticks > 0 {
            self.silent_ticks -= 1;
            return None;
        }
        let sequence = match rng.random_range(0..100) {
            0..45 => {
                self.next_sequence += 1;
                self.next_sequence
            }
            45..80 => return None, // no frame this tick
            80..88 => {
                self.next_sequence += 2; // one dropped
                self.next_sequence
            }
            88..94 => self.next_sequence,                   // duplicate
            94..98 => self.next_sequence.saturating_sub(3), // late, out of order
            98 => {
                let broken = &mut self.pool[3];
                broken.header_mut().sequence = self.next_sequence + 1;
                broken.header_mut().timestamp_ns = clock.now().as_nanos();
                return Some(broken);
            }
            _ => {
                self.silent_ticks = rng.random_range(5..20); // 50 to 200 ms silence
                return None;
            }
        };
        let frame = &mut self.pool[(sequence % 3) as usize];
        frame.restamp(sequence, clock.now());
        Some(frame)
    }
}

/// Runs `ticks` ticks of `policy` over unreliable cameras after a warm-up of 100, calling
/// `after_tick` with each tick's number; returns the allocations and bytes counted, and the
/// loop.
fn unreliable_ticks<P: Policy>(
    policy: P,
    ticks: u32,
    mut after_tick: impl FnMut(u32),
) -> ((u64, u64), ControlLoop<P, ManualClock>) {
    let mut rng = ChaCha8Rng::seed_from_u64(2016);
    let mut top = UnreliableCamera::<640, 480>::new(&mut rng);
    let mut bottom = UnreliableCamera::<320, 240>::new(&mut rng);
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(LoopConfig::default(), policy, clock.clone());
    let mut run = |ticks: u32| {
        for tick in 0..ticks {
            let input = CameraInput {
                top: top.frame(&mut rng, &clock),
                bottom: bottom.frame(&mut rng, &clock),
            };
            control.tick(input);
            // Some ticks run long, so that deadlines are missed too.
            if rng.random_bool(0.01) {
                clock.advance(Duration::from_millis(25));
            }
            control.wait_for_next_tick();
            after_tick(tick);
        }
    };
    run(100); // warm-up
    let counted = count_allocations(|| run(ticks));
    (counted, control)
}

#[test]
fn ten_thousand_ticks_allocate_nothing_after_start_up() {
    support::install_log_subscriber();
    let ((allocations, bytes), control) = unreliable_ticks(FlakyPolicy::default(), 10_000, |_| {});
    println!("allocations in 10,000 ticks after warm-up: {allocations} ({bytes} bytes)");

    let counters = *control.counters();
    let sync = *control.sync_counters();
    println!("{counters:?}\n{sync:?}");
    assert_eq!(counters.ticks, 10_100);
    assert!(counters.new_commands > 1000, "{counters:?}");
    assert!(counters.repeated_commands > 1000, "{counters:?}");
    assert!(counters.camera_stops > 0, "{counters:?}");
    assert!(counters.deadline_misses > 0, "{counters:?}");
    assert!(counters.invalid_frames > 0, "{counters:?}");
    assert!(counters.policy_failures > 0, "{counters:?}");
    assert!(counters.non_finite_outputs > 0, "{counters:?}");
    assert!(sync.duplicates.iter().all(|&n| n > 0), "{sync:?}");
    assert!(sync.out_of_order.iter().all(|&n| n > 0), "{sync:?}");
    assert!(sync.restarts.iter().all(|&n| n > 0), "{sync:?}");
    assert_eq!(allocations, 0, "the tick allocated {bytes} bytes");
}

#[test]
fn ticks_with_a_real_policy_of_each_kind_allocate_nothing_on_every_instruction_set() {
    support::install_log_subscriber();
    let models = support::package_dir().join("models");
    // The shipped policies are part of the repository: a missing one is a failure.
    let shipped = std::fs::read_to_string(models.join("policy/HOST_MODEL")).expect("HOST_MODEL");
    let shipped = format!("policy/{}", shipped.trim());
    // The robot package's policy (cross/package), whatever the rule chose.
    let robot = std::fs::read_to_string(models.join("policy/ROBOT_MODEL")).expect("ROBOT_MODEL");
    let robot = format!("policy/{}", robot.trim());
    for name in [
        "fixtures/cnn",
        "fixtures/cnn-int8",
        "fixtures/hcnn",
        "fixtures/rcnn",
        "policy/cnn-modal",
        // Its 4-output layer runs SSSE3's panels of 4 (the narrow network's V5 tick).
        "policy/cnn-8-16-4-8-observable-int8",
        // Its 4-output float layers run the blocked portable convolution on every set.
        "policy/cnn-4-16-4-8-distilled-dagger2-observable",
        // Its thumbnails standardised before the network ([normalisation] standardise).
        "policy/cnn-conditions-standardised",
        shipped.as_str(),
        robot.as_str(),
    ] {
        let manifest = models.join(name).join("policy.toml");
        assert!(manifest.is_file(), "{} is missing", manifest.display());
        for isa in Isa::available() {
            let options = EngineOptions {
                engine: Engine::Compiled,
                isa: Some(isa),
            };
            let (policy, loaded) = OnnxPolicy::load_with(&manifest, options).expect("loads");
            let engine = policy.engine().to_string();
            assert!(
                engine.starts_with(&format!("compiled ({isa}")),
                "{name}: {engine}"
            );
            // The int8 policy on its integer kernels, not its network's float reading.
            assert_eq!(
                policy.engine().int8,
                name.ends_with("int8"),
                "{name}: {engine}"
            );
            // The controller polls the policy files about once a second (every 100 ticks
            // at the default 10 ms): the poll runs inside the counted ticks.
            let mut watches: Vec<PolicyFileWatch> = std::iter::once(manifest.clone())
                .chain(loaded.network_paths())
                .filter_map(|path| PolicyFileWatch::new(&path))
                .collect();
            assert!(watches.len() >= 2, "{name}: manifest and networks watched");
            let mut polls = 0u32;
            let ((allocations, bytes), control) = unreliable_ticks(policy, 1_500, |tick| {
                if tick % 100 == 0 {
                    polls += 1;
                    for watch in &mut watches {
                        assert!(!watch.changed(), "a policy file changed during the test");
                    }
                }
            });
            let counters = *control.counters();
            println!(
                "{name} ({engine}): {allocations} allocations ({bytes} bytes) in 1,500 ticks, {} of them computing, {polls} file checks",
                counters.new_commands
            );
            assert!(counters.new_commands > 200, "{counters:?}");
            assert!(polls >= 15);
            assert_eq!(counters.policy_failures, 0);
            assert_eq!(
                allocations, 0,
                "{name}, {isa}: the tick allocated {bytes} bytes"
            );
        }
    }
}

#[test]
fn the_counter_sees_allocations() {
    // Without this, a broken counter would let the test above pass whatever the tick did.
    let (allocations, bytes) = count_allocations(|| {
        std::hint::black_box(vec![0u8; 100]);
    });
    assert_eq!((allocations, bytes), (1, 100));
}
