//! Thumbnail downscaling: a top frame (614 KB read) and a bottom frame (154 KB read).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use dribble_controller::test_pattern::TestPattern;
use dribble_controller::thumbnail::{downscale, downscale_portable};
use dribble_controller::{BottomFrame, BottomThumbnail, Timestamp, TopFrame, TopThumbnail};
use std::hint::black_box;

fn thumbnails(c: &mut Criterion) {
    let pattern = TestPattern::default();
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    pattern.paint(&mut top, 0, Timestamp::ZERO);
    pattern.paint(&mut bottom, 0, Timestamp::ZERO);
    let mut top_thumbnail = Box::new(TopThumbnail::black());
    let mut bottom_thumbnail = Box::new(BottomThumbnail::black());

    let mut group = c.benchmark_group("thumbnail");
    group.throughput(Throughput::Bytes(TopFrame::PIXEL_BYTES as u64));
    group.bench_function("top 640x480 to 160x120", |b| {
        b.iter(|| downscale(black_box(&*top), black_box(&mut *top_thumbnail)))
    });
    // The plain integer code that runs where SSE2 does not (the same bytes).
    group.bench_function("top 640x480 to 160x120, portable", |b| {
        b.iter(|| downscale_portable(black_box(&*top), black_box(&mut *top_thumbnail)))
    });
    group.throughput(Throughput::Bytes(BottomFrame::PIXEL_BYTES as u64));
    group.bench_function("bottom 320x240 to 80x60", |b| {
        b.iter(|| downscale(black_box(&*bottom), black_box(&mut *bottom_thumbnail)))
    });
    group.finish();
}

criterion_group!(benches, thumbnails);
criterion_main!(benches);
