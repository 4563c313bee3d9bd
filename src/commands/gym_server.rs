//! `dribble gym-server`: the simulator behind a step interface, for the Gymnasium environment
//! `dribble/NaoDribble-v0` (`models/dribble_models/gym_env.py`) on its standard input and
//! output.
//!
//! Why a child process on pipes and not Python bindings (PyO3): the environment then runs
//! the very binary every other command runs, built once by the workspace's release build
//! (a binding crate would compile and link the simulator, renderer and controller a second
//! time, for each Python version, in CI too); and a renderer or physics fault ends the child,
//! not the researcher's Python process. An observation is 24 KB, so the pipe costs little
//! next to rendering.
//!
//! The episode runs exactly as `dribble eval` runs a policy in process: the runner, the
//! controller's own `ControlLoop` (camera sync, thumbnails, clamping of the command, a stop
//! for a non-finite one) and a [`Policy`] whose step hands the thumbnails to Python and
//! waits for its action. So an observation comes at each moment the robot would compute a
//! command, and the action is that command; between two, the robot walks on the last one.
//!
//! Protocol (every number little-endian). Requests, each a one-byte tag:
//! - `R` u64 seed: start the episode of this seed (ending any unfinished one, as
//!   [`Outcome::Abandoned`]).
//! - `S` f32 forward, f32 left, f32 turn: the normalised command for the last observation.
//! - `Q`: exit (end of input does too).
//!
//! Answers to `R` and `S`:
//! - `O` top thumbnail (120 x 160 u8), bottom thumbnail (60 x 80 u8), u32 n, n bytes of
//!   JSON: the state the command will be computed in (time, robot pose, ball, the teacher's
//!   command and phase there).
//! - `E` the thumbnails of the newest frames, u32 n, n bytes of JSON: the outcome and the
//!   episode's summary, with the last state.
//! - `X` u32 n, n bytes of message: the request was refused (the server goes on).

use std::cell::RefCell;
use std::io::{BufReader, BufWriter, Read, Write};
use std::rc::Rc;

use crate::gym_exchange::{
    Exchange, ExchangeObserver, ProtocolError, RemotePolicy, Request, read_request, write_answer,
};
use anyhow::Context;
use clap::Args;
use dribble_controller::{BottomThumbnail, TopThumbnail};
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::expert::{Expert, ExpertConfig, GroundTruth, Teacher};
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use dribble_sim::render::Renderer;
use dribble_sim::runner::{Driver, EpisodeConfig, run_episode_observed};
use glam::Vec2;
use serde_json::json;

#[derive(Debug, Args)]
pub struct GymServerArgs {
    /// The teacher whose command for each observed state goes into `info`: `paper` (reads
    /// the ball's true position), `observable` (only what its cameras showed), `orbit`
    /// (observable, and the goal's direction only while the top camera shows the goal),
    /// `detector` (observable, the ball only where enough of it is unoccluded) or
    /// `detector-one-way` (detector, around the ball always clockwise).
    #[arg(long, alias = "expert", default_value_t = Teacher::Paper)]
    teacher: Teacher,
    /// Time limit per episode, simulated seconds (positive and finite); the environment
    /// truncates there.
    #[arg(long, default_value_t = 90.0, value_parser = crate::episodes::time_limit)]
    time_limit: f32,
    /// What the cameras see every episode under: `clean`, NAME:SEVERITY[,...] or `randomized`
    /// (see `dribble eval --help`); drawn from each reset's seed.
    #[arg(long, visible_alias = "conditions", default_value = "clean")]
    condition: dribble_sim::conditions::Conditions,
    /// Samples a pixel of the cameras' images: 4 (every shipped result's frames) or 1 (about
    /// two fifths of the CPU of a clean step; see `dribble eval --help`).
    #[arg(long, default_value_t = dribble_sim::render::Multisampling::Four)]
    camera_samples: dribble_sim::render::Multisampling,
}

pub fn run(args: &GymServerArgs) -> anyhow::Result<()> {
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        multisampling: args.camera_samples,
        ..EpisodeConfig::default()
    };
    let mut renderer = config.renderer()?;
    eprintln!("gym-server: adapter {}", renderer.adapter());
    let input = BufReader::new(std::io::stdin().lock());
    let output = BufWriter::new(std::io::stdout().lock());
    serve(args, &config, &mut renderer, input, output)
}

/// Answers requests until `Q` or the end of input.
fn serve<R: Read, W: Write>(
    args: &GymServerArgs,
    config: &EpisodeConfig,
    renderer: &mut Renderer,
    input: R,
    output: W,
) -> anyhow::Result<()> {
    let teacher = || {
        Expert::teaching(
            args.teacher,
            ExpertConfig::default(),
            FieldGeometry::SPL,
            config.cameras,
        )
    };
    let shared = Rc::new(RefCell::new(Exchange {
        input,
        output,
        setup: EpisodeSetup::from_seed(0),
        teacher: teacher(),
        state: GroundTruth {
            robot: FieldPose::new(0.0, 0.0, 0.0),
            ball: Vec2::ZERO,
            target_side: 1.0,
            time_s: 0.0,
        },
        last_thumbnails: (
            Box::new(TopThumbnail::black()),
            Box::new(BottomThumbnail::black()),
        ),
        interrupted_by: None,
        failed: None,
    }));
    let mut request = read_request(&mut shared.borrow_mut().input);
    loop {
        let seed = match request {
            Ok(Request::Reset(seed)) => seed,
            Ok(Request::Quit) => return Ok(()),
            Ok(Request::Step(_)) => {
                let message = "a step needs an episode: reset first (or after the last one ended)";
                let mut exchange = shared.borrow_mut();
                write_answer(&mut exchange.output, b'X', None, message)?;
                request = read_request(&mut exchange.input);
                continue;
            }
            Err(ProtocolError::UnknownTag(tag)) => {
                let message = ProtocolError::UnknownTag(tag).to_string();
                let mut exchange = shared.borrow_mut();
                write_answer(&mut exchange.output, b'X', None, &message)?;
                request = read_request(&mut exchange.input);
                continue;
            }
            Err(error) => return Err(error.into()),
        };
        let setup = EpisodeSetup::from_seed(seed).under(args.condition);
        {
            let mut exchange = shared.borrow_mut();
            exchange.setup = setup;
            exchange.teacher = teacher();
            exchange.interrupted_by = None;
        }
        let mut policy = RemotePolicy(Rc::clone(&shared));
        let mut observer = ExchangeObserver {
            shared: Rc::clone(&shared),
            top: Box::new(TopThumbnail::black()),
            bottom: Box::new(BottomThumbnail::black()),
        };
        let result = run_episode_observed(
            &setup,
            config,
            Driver::Policy(&mut policy),
            Some(renderer),
            None,
            &mut observer,
        )
        .with_context(|| format!("episode {seed}"))?;
        let mut exchange = shared.borrow_mut();
        if let Some(error) = exchange.failed.take() {
            return Err(error);
        }
        if let Some(next) = exchange.interrupted_by.take() {
            // Python asked for another episode (or to quit) instead of an action.
            request = Ok(next);
            continue;
        }
        let mut summary = exchange.state_json(None);
        summary["outcome"] = json!(result.outcome);
        summary["duration_s"] = json!(result.duration_s);
        summary["walked_m"] = json!(result.distance_walked_m);
        summary["computed_commands"] = json!(result.computed_commands);
        summary["first_sighting_s"] = json!(result.first_sighting_s);
        // The 10 Hz paths `dribble eval --trajectories` writes, from the same trace.
        let points = |path: &[Vec2]| path.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>();
        summary["trajectory"] = json!({
            "robot": points(&result.robot_path),
            "ball": points(&result.ball_path),
            "heading": result.heading_path,
        });
        let exchange = &mut *exchange;
        let (top, bottom) = &exchange.last_thumbnails;
        write_answer(
            &mut exchange.output,
            b'E',
            Some((top, bottom)),
            &summary.to_string(),
        )?;
        request = read_request(&mut exchange.input);
    }
}
