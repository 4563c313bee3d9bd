//! One controller tick with the hand-written test policy, against the 2 ms budget:
//! the worst case (both cameras new: two thumbnails and a policy step) and the common case
//! (no new pair: the last command repeats).

use criterion::{Criterion, criterion_group, criterion_main};
use dribble_controller::policy::BrightnessPolicy;
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::{
    BottomFrame, CameraInput, Clock, ControlLoop, LoopConfig, ManualClock, Timestamp, TopFrame,
};
use std::hint::black_box;
use std::time::Duration;

fn ticks(c: &mut Criterion) {
    let pattern = TestPattern::default();
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    pattern.paint(&mut top, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom, 0, Timestamp::ZERO);
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(
        LoopConfig::default(),
        BrightnessPolicy::default(),
        clock.clone(),
    );
    let mut sequence = 0;

    let mut group = c.benchmark_group("tick");
    group.bench_function("both cameras new (thumbnails + policy)", |b| {
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
    group.bench_function("no new pair (repeat)", |b| {
        b.iter(|| {
            clock.advance(Duration::from_micros(10));
            black_box(control.tick(black_box(CameraInput::default())))
        })
    });
    group.finish();
    assert_eq!(control.counters().policy_failures, 0);
}

criterion_group!(benches, ticks);
criterion_main!(benches);
