//! `dribble render`: what the robot's cameras see in the simulator, as pictures.

use std::fs;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraPosition, SpeedCommand, TopFrame, TopThumbnail,
};
use dribble_sim::camera_geometry::CameraGeometry;
use dribble_sim::conditions::Conditions;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::field::FieldGeometry;
use dribble_sim::image_output::{frame_to_rgb, save_thumbnail};
use dribble_sim::render::{Multisampling, Renderer};
use dribble_sim::simulation::Simulation;
use dribble_sim::top_view::{BALL, FieldCanvas, ROBOT};
use dribble_sim::walk::WalkConfig;
use dribble_sim::world::{STEPS_PER_SECOND, WorldConfig};
use glam::Vec2;

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Episode seed: places robot and ball as the episode protocol does (training 0..99,
    /// test 10000..10019).
    #[arg(long, default_value_t = 10_000)]
    seed: u64,
    /// Directory for the PNGs (created if missing).
    #[arg(long, default_value = "render")]
    out: PathBuf,
    /// Walk this many seconds before rendering, with --forward/--left/--turn.
    #[arg(long, default_value_t = 0.0)]
    seconds: f32,
    /// Walk command, normalised: forward.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    forward: f32,
    /// Walk command, normalised: left.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    left: f32,
    /// Walk command, normalised: turn (counter-clockwise).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    turn: f32,
    /// What the cameras see the episode under: `clean`, or NAME:SEVERITY[,...] (see `dribble
    /// eval --help`); a frame is rendered a camera period before the pictured one, so blur
    /// follows the camera's motion.
    #[arg(long, visible_alias = "conditions", default_value = "clean")]
    condition: Conditions,
    /// Samples a pixel: 4 (every shipped result's frames) or 1 (see `dribble eval --help`).
    #[arg(long, default_value_t = Multisampling::Four)]
    camera_samples: Multisampling,
}

pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let command = SpeedCommand::new(args.forward, args.left, args.turn)
        .context("--forward, --left and --turn must be finite")?;
    let setup = EpisodeSetup::from_seed(args.seed).under(args.condition);
    let cameras = CameraGeometry::nao();
    let world = WorldConfig::default();
    let mut renderer = Renderer::with_multisampling(
        &FieldGeometry::SPL,
        world.goal_depth,
        &cameras,
        args.camera_samples,
    )?;
    println!("adapter: {}", renderer.adapter());
    renderer.begin_episode(&setup.conditions.resolve(setup.seed));
    let mut simulation = Simulation::new(&setup, world, WalkConfig::default(), cameras);
    simulation.set_command(command);
    let steps = (args.seconds.max(0.0) * STEPS_PER_SECOND as f32).round() as u64;
    // A camera period before the pictured frame (the camera's motion for blur and skew).
    let earlier = steps.saturating_sub(STEPS_PER_SECOND / 30);
    let mut robot_path = vec![Vec2::new(setup.robot.x, setup.robot.y)];
    let mut ball_path = vec![setup.ball];
    let mut top = TopFrame::new_boxed();
    let mut bottom = BottomFrame::new_boxed();
    for step in 0..steps {
        if step == earlier && !setup.conditions.is_clean() {
            let scene = simulation.scene();
            let top_camera = simulation.camera(CameraPosition::Top);
            let bottom_camera = simulation.camera(CameraPosition::Bottom);
            renderer.render(CameraPosition::Top, &top_camera, &scene, &mut top)?;
            renderer.render(CameraPosition::Bottom, &bottom_camera, &scene, &mut bottom)?;
        }
        simulation.step();
        let pose = simulation.world().robot_pose();
        robot_path.push(Vec2::new(pose.x, pose.y));
        ball_path.push(simulation.world().ball().position.truncate());
    }

    let scene = simulation.scene();
    let top_camera = simulation.camera(CameraPosition::Top);
    let bottom_camera = simulation.camera(CameraPosition::Bottom);
    renderer.render(CameraPosition::Top, &top_camera, &scene, &mut top)?;
    renderer.render(CameraPosition::Bottom, &bottom_camera, &scene, &mut bottom)?;
    let mut top_thumbnail = Box::new(TopThumbnail::black());
    let mut bottom_thumbnail = Box::new(BottomThumbnail::black());
    downscale(&top, &mut top_thumbnail);
    downscale(&bottom, &mut bottom_thumbnail);

    let out = |name: &str| args.out.join(name);
    frame_to_rgb(&top).save_png(&out("top.png"))?;
    frame_to_rgb(&bottom).save_png(&out("bottom.png"))?;
    save_thumbnail(&top_thumbnail, 4, &out("top_thumbnail.png"))?;
    save_thumbnail(&bottom_thumbnail, 8, &out("bottom_thumbnail.png"))?;

    let field = FieldGeometry::SPL;
    let mut canvas = FieldCanvas::new(&field, 80.0);
    canvas.camera_view(&top_camera, 6.0, [200, 200, 120]);
    canvas.camera_view(&bottom_camera, 6.0, [120, 200, 220]);
    canvas.path(&robot_path, 0.03, ROBOT);
    canvas.path(&ball_path, 0.03, BALL);
    canvas.robot(simulation.world().robot_pose(), ROBOT);
    canvas.disc(
        simulation.world().ball().position.truncate(),
        field.ball_diameter,
        BALL,
    );
    canvas.into_image().save_png(&out("top_view.png"))?;

    let pose = simulation.world().robot_pose();
    let ball = simulation.world().ball().position;
    println!(
        "seed {}: robot at ({:.2}, {:.2}) heading {:.0} deg, ball at ({:.2}, {:.2}), target goal at {}x",
        setup.seed,
        pose.x,
        pose.y,
        pose.theta.to_degrees(),
        ball.x,
        ball.y,
        if setup.target_side > 0.0 { "+" } else { "-" }
    );
    for name in [
        "top.png",
        "bottom.png",
        "top_thumbnail.png",
        "bottom_thumbnail.png",
        "top_view.png",
    ] {
        println!("wrote {}", out(name).display());
    }
    Ok(())
}
