//! Policy steps of the committed fixture policies (the paper's architectures with seeded
//! weights), and a whole tick with the CNN: thumbnails of both cameras plus the step.
//!
//! To measure with the Nao's instruction set (SSE only, no AVX or FMA) on this machine:
//! `TRACT_CPU_ISA=-avx,-avx2,-fma,-f16c,-avx512f cargo bench --bench policy`.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use dribble_controller::policy::OnnxPolicy;
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraInput, Clock, ControlLoop, LoopConfig, ManualClock, Policy,
    PolicyInput, Timestamp, TopFrame, TopThumbnail,
};

fn load(kind: &str) -> OnnxPolicy {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models/fixtures")
        .join(kind)
        .join("policy.toml");
    OnnxPolicy::load(&manifest)
        .unwrap_or_else(|error| panic!("{error}"))
        .0
}

fn policies(c: &mut Criterion) {
    let pattern = TestPattern::default();
    let (mut top_frame, mut bottom_frame) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    pattern.paint(&mut top_frame, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom_frame, 0, Timestamp::ZERO);
    let (mut top, mut bottom) = (
        Box::new(TopThumbnail::black()),
        Box::new(BottomThumbnail::black()),
    );
    downscale(&top_frame, &mut top);
    downscale(&bottom_frame, &mut bottom);

    let mut group = c.benchmark_group("policy step");
    for (name, kind) in [("CNN", "cnn"), ("H-CNN", "hcnn"), ("R-CNN", "rcnn")] {
        let mut policy = load(kind);
        group.bench_function(name, |b| {
            b.iter(|| {
                let input = PolicyInput {
                    top: black_box(&top),
                    bottom: black_box(&bottom),
                };
                black_box(policy.step(input).expect("step"))
            })
        });
    }
    group.finish();

    let clock = ManualClock::default();
    let mut control = ControlLoop::new(LoopConfig::default(), load("cnn"), clock.clone());
    let mut sequence = 0;
    c.bench_function("tick/both cameras new (thumbnails + CNN)", |b| {
        b.iter(|| {
            sequence += 1;
            clock.advance(Duration::from_millis(33));
            top_frame.restamp(sequence, clock.now());
            bottom_frame.restamp(sequence, clock.now());
            let input = CameraInput {
                top: Some(&top_frame),
                bottom: Some(&bottom_frame),
            };
            black_box(control.tick(black_box(input)))
        })
    });
    assert_eq!(control.counters().policy_failures, 0);
}

criterion_group!(benches, policies);
criterion_main!(benches);
