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

use anyhow::Context;
use clap::Args;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraPosition, Policy, PolicyError, PolicyInput, PolicyOutput,
    Timestamp, TopFrame, TopThumbnail,
};
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::episode_observer::EpisodeObserver;
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
    /// the ball's true position), `observable` (only what its cameras showed) or `orbit`
    /// (observable, and the goal's direction only while the top camera shows the goal).
    #[arg(long, default_value_t = Teacher::Paper)]
    expert: Teacher,
    /// Time limit per episode, simulated seconds (positive and finite); the environment
    /// truncates there.
    #[arg(long, default_value_t = 90.0, value_parser = crate::episodes::time_limit)]
    time_limit: f32,
    /// What the cameras see every episode under: `clean`, NAME:SEVERITY[,...] or `randomized`
    /// (see `dribble eval --help`); drawn from each reset's seed.
    #[arg(long, visible_alias = "conditions", default_value = "clean")]
    condition: dribble_sim::conditions::Conditions,
}

/// What one request asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Request {
    Reset(u64),
    Step([f32; 3]),
    Quit,
}

/// Why the server stops reading.
#[derive(Debug, thiserror::Error)]
enum ProtocolError {
    #[error("unknown request tag {0:#04x} (R, S or Q)")]
    UnknownTag(u8),
    #[error("reading a request: {0}")]
    Io(#[from] std::io::Error),
}

/// Reads one request; `Quit` at the end of input.
fn read_request(input: &mut impl Read) -> Result<Request, ProtocolError> {
    let mut tag = [0u8; 1];
    match input.read_exact(&mut tag) {
        Ok(()) => {}
        Err(error) if error.kind() == std::io::ErrorKind::UnexpectedEof => {
            return Ok(Request::Quit);
        }
        Err(error) => return Err(error.into()),
    }
    match tag[0] {
        b'R' => {
            let mut seed = [0u8; 8];
            input.read_exact(&mut seed)?;
            Ok(Request::Reset(u64::from_le_bytes(seed)))
        }
        b'S' => {
            let mut values = [0u8; 12];
            input.read_exact(&mut values)?;
            let value = |i: usize| {
                f32::from_le_bytes([
                    values[4 * i],
                    values[4 * i + 1],
                    values[4 * i + 2],
                    values[4 * i + 3],
                ])
            };
            Ok(Request::Step([value(0), value(1), value(2)]))
        }
        b'Q' => Ok(Request::Quit),
        other => Err(ProtocolError::UnknownTag(other)),
    }
}

/// Writes one answer: the tag, the thumbnails (for `O` and `E`), the JSON.
fn write_answer(
    output: &mut impl Write,
    tag: u8,
    thumbnails: Option<(&TopThumbnail, &BottomThumbnail)>,
    text: &str,
) -> std::io::Result<()> {
    output.write_all(&[tag])?;
    if let Some((top, bottom)) = thumbnails {
        output.write_all(top.as_bytes())?;
        output.write_all(bottom.as_bytes())?;
    }
    let length = u32::try_from(text.len()).unwrap_or(u32::MAX);
    output.write_all(&length.to_le_bytes())?;
    output.write_all(text.as_bytes())?;
    output.flush()
}

/// The state of the episode in play, shared by the policy (Python's side) and the observer
/// (the runner's side).
struct Exchange<R, W> {
    input: R,
    output: W,
    setup: EpisodeSetup,
    teacher: Expert,
    /// The state of the tick under way (set just before it).
    state: GroundTruth,
    /// Thumbnails of the newest frames, for the last observation of an episode.
    last_thumbnails: (Box<TopThumbnail>, Box<BottomThumbnail>),
    /// What Python asked for instead of an action: the episode is abandoned for it.
    interrupted_by: Option<Request>,
    /// The stream failed; the server ends with this error after the episode.
    failed: Option<anyhow::Error>,
}

impl<R: Read, W: Write> Exchange<R, W> {
    fn state_json(&self, teacher: Option<(&[f32; 3], &str)>) -> serde_json::Value {
        let GroundTruth {
            robot,
            ball,
            time_s,
            ..
        } = self.state;
        let mut state = json!({
            "seed": self.setup.seed,
            "time_s": time_s,
            "robot": [robot.x, robot.y, robot.theta],
            "ball": [ball.x, ball.y],
            "target_side": self.setup.target_side,
            "goal_centre": [FieldGeometry::SPL.goal_line_x(self.setup.target_side), 0.0],
        });
        if let Some((command, phase)) = teacher {
            state["expert_command"] = json!(command);
            state["expert_phase"] = json!(phase);
        }
        state
    }
}

type Shared<R, W> = Rc<RefCell<Exchange<R, W>>>;

/// The policy whose steps are Python's actions.
struct RemotePolicy<R, W>(Shared<R, W>);

impl<R: Read, W: Write> Policy for RemotePolicy<R, W> {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        let mut exchange = self.0.borrow_mut();
        let exchange = &mut *exchange;
        if exchange.interrupted_by.is_some() || exchange.failed.is_some() {
            // The episode is being abandoned; the runner ends it after this tick.
            return Ok(PolicyOutput::default());
        }
        let state = exchange.state;
        let (command, phase) = exchange.teacher.decide(&state);
        let info = exchange.state_json(Some((&command.as_array(), phase.name())));
        let written = write_answer(
            &mut exchange.output,
            b'O',
            Some((input.top, input.bottom)),
            &info.to_string(),
        );
        if let Err(error) = written {
            exchange.failed = Some(anyhow::Error::new(error).context("writing an observation"));
            return Ok(PolicyOutput::default());
        }
        loop {
            match read_request(&mut exchange.input) {
                Ok(Request::Step([forward, left, turn])) => {
                    return Ok(PolicyOutput {
                        forward,
                        left,
                        turn,
                    });
                }
                Ok(request) => {
                    exchange.interrupted_by = Some(request);
                    return Ok(PolicyOutput::default());
                }
                Err(ProtocolError::UnknownTag(tag)) => {
                    let message = ProtocolError::UnknownTag(tag).to_string();
                    if let Err(error) = write_answer(&mut exchange.output, b'X', None, &message) {
                        exchange.failed = Some(error.into());
                        return Ok(PolicyOutput::default());
                    }
                }
                Err(ProtocolError::Io(error)) => {
                    exchange.failed = Some(anyhow::Error::new(error).context("reading an action"));
                    return Ok(PolicyOutput::default());
                }
            }
        }
    }

    fn reset(&mut self) {}
}

/// The runner's side: the state before each tick, the newest frames' thumbnails, and an
/// interrupted episode ended.
struct ExchangeObserver<R, W> {
    shared: Shared<R, W>,
    top: Box<TopThumbnail>,
    bottom: Box<BottomThumbnail>,
}

impl<R: Read, W: Write> EpisodeObserver for ExchangeObserver<R, W> {
    fn frame(
        &mut self,
        _time: Timestamp,
        camera: CameraPosition,
        top: &TopFrame,
        bottom: &BottomFrame,
    ) {
        match camera {
            CameraPosition::Top => downscale(top, &mut self.top),
            CameraPosition::Bottom => downscale(bottom, &mut self.bottom),
        }
    }

    fn before_tick(&mut self, time: Timestamp, robot: FieldPose, ball: Vec2) {
        let mut exchange = self.shared.borrow_mut();
        exchange.state = GroundTruth {
            robot,
            ball,
            target_side: exchange.setup.target_side,
            time_s: time.as_nanos() as f64 / 1e9,
        };
    }

    fn state(&mut self, time: Timestamp, robot: FieldPose, ball: Vec2) {
        // Kept for the last observation: the state at the episode's end.
        self.before_tick(time, robot, ball);
    }

    fn abandon(&mut self) -> bool {
        let exchange = self.shared.borrow();
        exchange.interrupted_by.is_some() || exchange.failed.is_some()
    }

    fn end(&mut self, _time: Timestamp, _outcome: Outcome) {
        let mut exchange = self.shared.borrow_mut();
        exchange.last_thumbnails.0.clone_from(&self.top);
        exchange.last_thumbnails.1.clone_from(&self.bottom);
    }
}

pub fn run(args: &GymServerArgs) -> anyhow::Result<()> {
    let config = EpisodeConfig {
        time_limit_s: args.time_limit,
        ..EpisodeConfig::default()
    };
    let mut renderer = Renderer::new(
        &FieldGeometry::SPL,
        config.world.goal_depth,
        &config.cameras,
    )?;
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
            args.expert,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_read_as_written_and_the_end_of_input_quits() {
        let mut bytes = vec![b'R'];
        bytes.extend_from_slice(&10_007u64.to_le_bytes());
        bytes.push(b'S');
        for value in [0.5f32, -0.25, 1.0] {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
        bytes.push(b'Q');
        let mut input = bytes.as_slice();
        assert_eq!(read_request(&mut input).ok(), Some(Request::Reset(10_007)));
        assert_eq!(
            read_request(&mut input).ok(),
            Some(Request::Step([0.5, -0.25, 1.0]))
        );
        assert_eq!(read_request(&mut input).ok(), Some(Request::Quit));
        assert_eq!(read_request(&mut input).ok(), Some(Request::Quit));
        assert!(matches!(
            read_request(&mut &b"Z"[..]),
            Err(ProtocolError::UnknownTag(b'Z'))
        ));
        assert!(matches!(
            read_request(&mut &b"S\x00\x00"[..]),
            Err(ProtocolError::Io(_))
        ));
    }

    #[test]
    fn an_answer_is_tag_thumbnails_length_and_text() {
        let (top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
        let mut bytes = Vec::new();
        write_answer(&mut bytes, b'O', Some((&top, &bottom)), "{}").expect("written");
        assert_eq!(bytes.len(), 1 + 160 * 120 + 80 * 60 + 4 + 2);
        assert_eq!(bytes[0], b'O');
        assert_eq!(&bytes[bytes.len() - 6..], b"\x02\x00\x00\x00{}");
    }
}
