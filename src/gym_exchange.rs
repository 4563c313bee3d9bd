//! The step interface between `dribble gym-server` and the Gymnasium environment
//! (`models/dribble_models/gym_env.py`): the requests and answers on standard input and
//! output, and the two sides of the runner they stand in for: a policy whose commands come
//! from the environment's actions (`RemotePolicy`), and an observer that sends each
//! observation and the episode's end (`ExchangeObserver`).

use std::cell::RefCell;
use std::io::{Read, Write};
use std::rc::Rc;

use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraPosition, Policy, PolicyError, PolicyInput, PolicyOutput,
    Timestamp, TopFrame, TopThumbnail,
};
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::episode_observer::EpisodeObserver;
use dribble_sim::expert::{Expert, GroundTruth};
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use glam::Vec2;
use serde_json::json;

/// What one request asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Request {
    Reset(u64),
    Step([f32; 3]),
    Quit,
}

/// Why the server stops reading.
#[derive(Debug, thiserror::Error)]
pub(crate) enum ProtocolError {
    #[error("unknown request tag {0:#04x} (R, S or Q)")]
    UnknownTag(u8),
    #[error("reading a request: {0}")]
    Io(#[from] std::io::Error),
}

/// Reads one request; `Quit` at the end of input.
pub(crate) fn read_request(input: &mut impl Read) -> Result<Request, ProtocolError> {
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
pub(crate) fn write_answer(
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
pub(crate) struct Exchange<R, W> {
    pub(crate) input: R,
    pub(crate) output: W,
    pub(crate) setup: EpisodeSetup,
    pub(crate) teacher: Expert,
    /// The state of the tick under way (set just before it).
    pub(crate) state: GroundTruth,
    /// Thumbnails of the newest frames, for the last observation of an episode.
    pub(crate) last_thumbnails: (Box<TopThumbnail>, Box<BottomThumbnail>),
    /// What Python asked for instead of an action: the episode is abandoned for it.
    pub(crate) interrupted_by: Option<Request>,
    /// The stream failed; the server ends with this error after the episode.
    pub(crate) failed: Option<anyhow::Error>,
}

impl<R: Read, W: Write> Exchange<R, W> {
    pub(crate) fn state_json(&self, teacher: Option<(&[f32; 3], &str)>) -> serde_json::Value {
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

pub(crate) type Shared<R, W> = Rc<RefCell<Exchange<R, W>>>;

/// The policy whose steps are Python's actions.
pub(crate) struct RemotePolicy<R, W>(pub(crate) Shared<R, W>);

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
pub(crate) struct ExchangeObserver<R, W> {
    pub(crate) shared: Shared<R, W>,
    pub(crate) top: Box<TopThumbnail>,
    pub(crate) bottom: Box<BottomThumbnail>,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    pub(crate) fn requests_are_read_as_written_and_the_end_of_input_quits() {
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
    pub(crate) fn an_answer_is_tag_thumbnails_length_and_text() {
        let (top, bottom) = (TopThumbnail::black(), BottomThumbnail::black());
        let mut bytes = Vec::new();
        write_answer(&mut bytes, b'O', Some((&top, &bottom)), "{}").expect("written");
        assert_eq!(bytes.len(), 1 + 160 * 120 + 80 * 60 + 4 + 2);
        assert_eq!(bytes[0], b'O');
        assert_eq!(&bytes[bytes.len() - 6..], b"\x02\x00\x00\x00{}");
    }
}
