//! The Foxglove channels an episode is logged on, their schemas, and the conversions from
//! the simulator's types to Foxglove's messages.

use std::sync::Arc;

use anyhow::Context as _;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{CameraFrame, CameraPosition, Thumbnail, Timestamp};
use foxglove::bytes::Bytes;
use foxglove::messages::{
    Color, Point3, Pose, PoseInFrame, Quaternion, RawImage, SceneUpdate, Timestamp as FoxgloveTime,
    Vector3,
};
use foxglove::{Channel, Context, RawChannel, Schema};
use glam::Vec2;

/// The frame every pose and scene entity is in: the field, origin at the centre spot, x
/// towards the goal at +x, z up, metres.
pub(crate) const FIELD_FRAME: &str = "field";

/// Scene and pose messages per simulated second.
pub(crate) const STATE_HZ: f64 = 30.0;

pub(crate) const COMMAND_SCHEMA: &str = r#"{
  "title": "dribble.MotionCommand",
  "type": "object",
  "properties": {
    "forward": {"type": "number", "description": "normalised forward speed, -1..1"},
    "left": {"type": "number", "description": "normalised sideways speed, -1..1, + left"},
    "turn": {"type": "number", "description": "normalised turn speed, -1..1, + left"},
    "kind": {"type": "string", "enum": ["new", "repeated", "stop"]},
    "sequence": {"type": "integer"},
    "top_sequence": {"type": "integer", "description": "top frame computed from"},
    "bottom_sequence": {"type": "integer", "description": "bottom frame computed from"}
  }
}"#;

pub(crate) const OUTCOME_SCHEMA: &str = r#"{
  "title": "dribble.EpisodeOutcome",
  "type": "object",
  "properties": {
    "seed": {"type": "integer"},
    "outcome": {"type": "string", "enum": ["goal", "ball_out", "time_limit", "controller_lost"]},
    "time_s": {"type": "number"}
  }
}"#;

/// The typed channels of one Foxglove context.
pub(crate) struct Channels {
    pub(crate) top: Channel<RawImage>,
    pub(crate) bottom: Channel<RawImage>,
    pub(crate) top_thumbnail: Channel<RawImage>,
    pub(crate) bottom_thumbnail: Channel<RawImage>,
    pub(crate) command: Arc<RawChannel>,
    pub(crate) markings: Channel<SceneUpdate>,
    pub(crate) scene: Channel<SceneUpdate>,
    pub(crate) robot_pose: Channel<PoseInFrame>,
    pub(crate) ball_pose: Channel<PoseInFrame>,
    pub(crate) outcome: Arc<RawChannel>,
}

impl Channels {
    pub(crate) fn new(context: &Arc<Context>) -> anyhow::Result<Self> {
        let json_channel = |topic: &str, name: &str, schema: &'static str| {
            context
                .channel_builder(topic)
                .message_encoding("json")
                .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
                .build_raw()
                .with_context(|| format!("creating the Foxglove channel {topic}"))
        };
        Ok(Self {
            top: context.channel_builder("/camera/top").build(),
            bottom: context.channel_builder("/camera/bottom").build(),
            top_thumbnail: context.channel_builder("/policy/thumbnail/top").build(),
            bottom_thumbnail: context.channel_builder("/policy/thumbnail/bottom").build(),
            command: json_channel("/motion/command", "dribble.MotionCommand", COMMAND_SCHEMA)?,
            markings: context.channel_builder("/field/markings").build(),
            scene: context.channel_builder("/field/scene").build(),
            robot_pose: context.channel_builder("/robot/pose").build(),
            ball_pose: context.channel_builder("/ball/pose").build(),
            outcome: json_channel("/episode/outcome", "dribble.EpisodeOutcome", OUTCOME_SCHEMA)?,
        })
    }
}

/// One camera's frame at `time`: the image when one is due, and the thumbnail the policy
/// computes from it (the robot's own `downscale`), every frame.
pub(crate) fn log_camera<const FW: usize, const FH: usize, const TW: usize, const TH: usize>(
    channels: &Channels,
    camera: CameraPosition,
    time: Timestamp,
    frame: &CameraFrame<FW, FH>,
    image_due: bool,
    thumbnail: &mut Thumbnail<TW, TH>,
) {
    let (image_channel, thumbnail_channel, frame_id) = match camera {
        CameraPosition::Top => (&channels.top, &channels.top_thumbnail, "camera_top"),
        CameraPosition::Bottom => (
            &channels.bottom,
            &channels.bottom_thumbnail,
            "camera_bottom",
        ),
    };
    if image_due {
        log_image(
            image_channel,
            time,
            frame_id,
            [FW, FH],
            "yuyv",
            frame.as_bytes(),
        );
    }
    downscale(frame, thumbnail);
    log_image(
        thumbnail_channel,
        time,
        frame_id,
        [TW, TH],
        "mono8",
        thumbnail.as_bytes(),
    );
}

/// `bytes`, rows of `width` pixels in `encoding`, as a `foxglove.RawImage` at `time`.
pub(crate) fn log_image(
    channel: &Channel<RawImage>,
    time: Timestamp,
    frame_id: &str,
    [width, height]: [usize; 2],
    encoding: &str,
    bytes: &[u8],
) {
    channel.log_with_time(
        &RawImage {
            timestamp: Some(foxglove_time(time)),
            frame_id: frame_id.into(),
            width: width as u32,
            height: height as u32,
            encoding: encoding.into(),
            step: (bytes.len() / height.max(1)) as u32,
            data: Bytes::copy_from_slice(bytes),
        },
        time.as_nanos(),
    );
}

/// Whether a message of a stream at `hz` is due at `time`; if so, moves `next` on by whole
/// periods past `time` (so the stream keeps its rate on average whatever the event grid).
pub(crate) fn due(next: &mut u64, time: Timestamp, hz: f64) -> bool {
    let now = time.as_nanos();
    if now < *next {
        return false;
    }
    let period = ((1e9 / hz) as u64).max(1);
    *next += period * ((now - *next) / period + 1);
    true
}

pub(crate) fn foxglove_time(time: Timestamp) -> FoxgloveTime {
    let ns = time.as_nanos();
    FoxgloveTime::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

pub(crate) fn vector(x: f32, y: f32, z: f32) -> Vector3 {
    Vector3 {
        x: f64::from(x),
        y: f64::from(y),
        z: f64::from(z),
    }
}

pub(crate) fn point(p: Vec2, z: f32) -> Point3 {
    Point3 {
        x: f64::from(p.x),
        y: f64::from(p.y),
        z: f64::from(z),
    }
}

pub(crate) fn colour(r: f64, g: f64, b: f64) -> Color {
    Color { r, g, b, a: 1.0 }
}

/// A pose at (x, y, z) turned by `yaw` about z.
pub(crate) fn pose(x: f32, y: f32, z: f32, yaw: f32) -> Pose {
    let half = f64::from(yaw) / 2.0;
    Pose {
        position: Some(vector(x, y, z)),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: half.sin(),
            w: half.cos(),
        }),
    }
}
