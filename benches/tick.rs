//! One controller tick against the 2 ms budget: the worst case (both cameras new: two
//! thumbnails and a policy step) with the hand-written test policy and with the paper's CNN
//! on the compiled engine and on tract, and the common case (no new pair: the last command
//! repeats).

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::{BrightnessPolicy, Engine, EngineOptions, OnnxPolicy};
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::{
    BottomFrame, CameraInput, Clock, ControlLoop, LoopConfig, ManualClock, Policy, Timestamp,
    TopFrame,
};

mod support;

/// The CNN fixture on `engine`, the compiled one on `isa` (`None`: the best this CPU runs).
fn cnn(engine: Engine, isa: Option<Isa>) -> OnnxPolicy {
    let manifest = support::fixture_manifest("cnn");
    OnnxPolicy::load_with(&manifest, EngineOptions { engine, isa })
        .unwrap_or_else(|error| panic!("{error}"))
        .0
}

/// Both cameras new every iteration, a tick period apart: the computing path.
fn computing<P: Policy>(c: &mut Criterion, name: &str, policy: P) {
    let pattern = TestPattern::default();
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    pattern.paint(&mut top, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom, 0, Timestamp::ZERO);
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(LoopConfig::default(), policy, clock.clone());
    let mut sequence = 0;
    c.bench_function(&format!("tick/both cameras new ({name})"), |b| {
        b.iter(|| {
            sequence += 1;
            clock.advance(Duration::from_millis(10));
            top.restamp(sequence, clock.now());
            bottom.restamp(sequence, clock.now());
            let input = CameraInput {
                top: Some(&top),
                bottom: Some(&bottom),
            };
            black_box(control.tick(black_box(input)))
        })
    });
    assert_eq!(control.counters().policy_failures, 0);
    assert_eq!(
        control.counters().stops,
        0,
        "the computing path was measured"
    );
}

/// The tick after a computing one, with no new frame: only that tick is timed, and the
/// cameras never fall silent, so every measured tick repeats (none stops).
fn repeating(c: &mut Criterion) {
    let pattern = TestPattern::default();
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    pattern.paint(&mut top, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom, 0, Timestamp::ZERO);
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(
        LoopConfig::default(),
        BrightnessPolicy::default(),
        clock.clone(),
    );
    let mut sequence = 0;
    c.bench_function("tick/no new pair (repeat)", |b| {
        b.iter_custom(|iterations| {
            let mut timed = Duration::ZERO;
            for _ in 0..iterations {
                sequence += 1;
                clock.advance(Duration::from_millis(10));
                top.restamp(sequence, clock.now());
                bottom.restamp(sequence, clock.now());
                control.tick(CameraInput {
                    top: Some(&top),
                    bottom: Some(&bottom),
                });
                clock.advance(Duration::from_millis(10));
                let started = Instant::now();
                black_box(control.tick(black_box(CameraInput::default())));
                timed += started.elapsed();
            }
            timed
        })
    });
    let counters = control.counters();
    assert_eq!(
        counters.stops, 0,
        "the repeat path was measured: {counters:?}"
    );
    assert_eq!(counters.repeated_commands, counters.new_commands);
}

fn ticks(c: &mut Criterion) {
    computing(c, "thumbnails + test policy", BrightnessPolicy::default());
    computing(
        c,
        &format!("thumbnails + CNN, compiled engine {}", Isa::detect()),
        cnn(Engine::Compiled, None),
    );
    // The target names AVX2+FMA; on an AVX-512 machine that is not the best set.
    if Isa::Avx2Fma.is_available() && Isa::detect() != Isa::Avx2Fma {
        computing(
            c,
            &format!("thumbnails + CNN, compiled engine {}", Isa::Avx2Fma),
            cnn(Engine::Compiled, Some(Isa::Avx2Fma)),
        );
    }
    computing(c, "thumbnails + CNN, tract", cnn(Engine::Tract, None));
    repeating(c);
}

criterion_group!(benches, ticks);
criterion_main!(benches);
