//! Simulator throughput: a camera pair rendered (both cameras, 4x multisampling, YUYV
//! packing and read-back included) and a physics step. Target: 100 pairs per second on a
//! 2-core machine with lavapipe, over three times real time.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use dribble_controller::{BottomFrame, CameraPosition, SpeedCommand, TopFrame};
use dribble_sim::camera_geometry::CameraGeometry;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::Renderer;
use dribble_sim::simulation::Simulation;
use dribble_sim::walk::WalkConfig;
use dribble_sim::world::WorldConfig;

fn simulator(c: &mut Criterion) {
    let cameras = CameraGeometry::nao();
    let mut renderer = Renderer::new(
        &FieldGeometry::SPL,
        WorldConfig::default().goal_depth,
        &cameras,
    )
    .unwrap_or_else(|error| panic!("{error}"));
    eprintln!("adapter: {}", renderer.adapter());
    let mut simulation = Simulation::new(
        &EpisodeSetup::from_seed(10_000),
        WorldConfig::default(),
        WalkConfig::default(),
        cameras,
    );
    simulation.set_command(SpeedCommand::new(1.0, 0.0, 0.3).expect("finite"));
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());

    let mut group = c.benchmark_group("simulator");
    group.sample_size(30);
    group.bench_function("render camera pair (top + bottom, MSAA 4x, YUYV)", |b| {
        b.iter(|| {
            for _ in 0..10 {
                simulation.step();
            }
            let scene = simulation.scene();
            let top_camera = simulation.camera(CameraPosition::Top);
            let bottom_camera = simulation.camera(CameraPosition::Bottom);
            renderer
                .render(CameraPosition::Top, &top_camera, &scene, &mut top)
                .expect("render");
            renderer
                .render(CameraPosition::Bottom, &bottom_camera, &scene, &mut bottom)
                .expect("render");
            black_box((top.luma(0, 0), bottom.luma(0, 0)))
        })
    });
    group.sample_size(100);
    group.bench_function("simulation step (walk + physics)", |b| {
        b.iter(|| black_box(simulation.step()))
    });
    group.finish();
}

criterion_group!(benches, simulator);
criterion_main!(benches);
