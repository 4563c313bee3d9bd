//! What a rendered camera pair costs, and what it looks like, bit for bit: renders PAIRS
//! pairs (top and bottom, 10 physics steps apart) of episode SEED under CONDITIONS and
//! prints the CPU time a pair took in every thread of the process (lavapipe's rasterizer
//! threads included) and a digest of all frames, so that a renderer change can be timed
//! and checked for identical frames in one run:
//!
//! `cargo run --release -p dribble-sim --example render_cost -- [PAIRS] [CONDITIONS] [SEED]
//! [SAMPLES]` (defaults: 300, clean, 0, 4; SAMPLES 1 draws one sample a pixel).
use std::error::Error;
use std::hash::{DefaultHasher, Hasher};

use dribble_controller::{BottomFrame, CameraPosition, SpeedCommand, TopFrame};
use dribble_sim::camera_geometry::CameraGeometry;
use dribble_sim::conditions::Conditions;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::field::FieldGeometry;
use dribble_sim::render::{Multisampling, Renderer};
use dribble_sim::simulation::Simulation;
use dribble_sim::walk::WalkConfig;
use dribble_sim::world::WorldConfig;

/// User and system time of every thread of this process so far, seconds.
fn process_cpu_s() -> Result<f64, Box<dyn Error>> {
    let stat = std::fs::read_to_string("/proc/self/stat")?;
    let after_name = stat
        .rsplit_once(") ")
        .ok_or("unreadable /proc/self/stat")?
        .1;
    let fields: Vec<&str> = after_name.split(' ').collect();
    let ticks = |index: usize| -> Result<f64, Box<dyn Error>> {
        Ok(fields.get(index).ok_or("short /proc/self/stat")?.parse()?)
    };
    // utime and stime, fields 14 and 15 of proc(5), in clock ticks (100 a second on Linux).
    Ok((ticks(11)? + ticks(12)?) / 100.0)
}

fn main() -> Result<(), Box<dyn Error>> {
    let mut args = std::env::args().skip(1);
    let pairs: usize = args.next().map_or(Ok(300), |n| n.parse())?;
    let conditions: Conditions = args.next().as_deref().unwrap_or("clean").parse()?;
    let seed: u64 = args.next().map_or(Ok(0), |n| n.parse())?;
    let multisampling: Multisampling = args.next().as_deref().unwrap_or("4").parse()?;
    let setup = EpisodeSetup::from_seed(seed).under(conditions);
    let cameras = CameraGeometry::nao();
    let field = FieldGeometry::SPL;
    let mut renderer = Renderer::with_multisampling(
        &field,
        WorldConfig::default().goal_depth,
        &cameras,
        multisampling,
    )?;
    renderer.begin_episode(&conditions.resolve(seed));
    let mut simulation = Simulation::new(
        &setup,
        WorldConfig::default(),
        WalkConfig::default(),
        cameras,
    );
    simulation.set_command(SpeedCommand::new(1.0, 0.0, 0.3)?);
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    let mut digest = DefaultHasher::new();
    let mut render_pair = |digest: &mut DefaultHasher| -> Result<(), Box<dyn Error>> {
        for _ in 0..10 {
            simulation.step();
        }
        let scene = simulation.scene();
        let top_camera = simulation.camera(CameraPosition::Top);
        let bottom_camera = simulation.camera(CameraPosition::Bottom);
        renderer.render(CameraPosition::Top, &top_camera, &scene, &mut top)?;
        renderer.render(CameraPosition::Bottom, &bottom_camera, &scene, &mut bottom)?;
        digest.write(top.as_bytes());
        digest.write(bottom.as_bytes());
        Ok(())
    };
    // Shaders are compiled at their first frames: leave those out of the time.
    let mut warm_up = DefaultHasher::new();
    for _ in 0..20 {
        render_pair(&mut warm_up)?;
    }
    let (cpu_s, wall) = (process_cpu_s()?, std::time::Instant::now());
    for _ in 0..pairs {
        render_pair(&mut digest)?;
    }
    let cpu_s = process_cpu_s()? - cpu_s;
    println!(
        "{pairs} pairs of seed {seed} ({conditions}): {:.1} ms CPU a pair, {:.1} ms wall; \
         frames' digest {:016x}",
        cpu_s * 1e3 / pairs as f64,
        wall.elapsed().as_secs_f64() * 1e3 / pairs as f64,
        digest.finish()
    );
    Ok(())
}
