//! Episodes for Foxglove: an [`EpisodeObserver`] that logs what an episode shows on the
//! Foxglove SDK's typed channels, on the simulated clock, into one MCAP file per episode
//! (`--mcap DIR`) and/or to Foxglove's WebSocket server on localhost (`--live`).
//!
//! Channels (topic, schema):
//! - `/camera/top`, `/camera/bottom`: `foxglove.RawImage`, the cameras' YUYV frames (at
//!   `camera_hz`, only when the episode renders);
//! - `/policy/thumbnail/top`, `/policy/thumbnail/bottom`: `foxglove.RawImage` (mono8), the
//!   thumbnails the policy computes from each frame (the robot's own `downscale`);
//! - `/motion/command`: JSON (`dribble.MotionCommand`), every motion cycle: normalised
//!   forward, left and turn speeds, `kind` new / repeated / stop, the frames it came from;
//! - `/field/markings`: `foxglove.SceneUpdate`, the field's carpet, lines and goals (at the
//!   start; live, again every simulated second, for viewers that join later);
//! - `/field/scene`: `foxglove.SceneUpdate`, the robot and the ball (30 Hz);
//! - `/robot/pose`, `/ball/pose`: `foxglove.PoseInFrame` in frame `field` (30 Hz), to plot;
//! - `/episode/outcome`: JSON (`dribble.EpisodeOutcome`) once, at the end.
//!
//! `sim-harness/foxglove-layout.json` arranges them in Foxglove (3D view, images, command plot).

use std::fs;
use std::io::BufWriter;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context as _;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraFrame, CameraPosition, MotionCommand, Thumbnail, Timestamp,
    TopFrame, TopThumbnail,
};
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::episode_observer::EpisodeObserver;
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use foxglove::bytes::Bytes;
use foxglove::messages::{
    Color, CubePrimitive, LinePrimitive, Point3, Pose, PoseInFrame, Quaternion, RawImage,
    SceneEntity, SceneUpdate, SpherePrimitive, Timestamp as FoxgloveTime, Vector3, line_primitive,
};
use foxglove::{
    Channel, Context, McapCompression, McapWriteOptions, McapWriter, McapWriterHandle,
    PartialMetadata, RawChannel, Schema, WebSocketServer, WebSocketServerHandle,
};
use glam::Vec2;
use serde_json::json;

/// The frame every pose and scene entity is in: the field, origin at the centre spot, x
/// towards the goal at +x, z up, metres.
const FIELD_FRAME: &str = "field";
/// Scene and pose messages per simulated second.
const STATE_HZ: f64 = 30.0;

const COMMAND_SCHEMA: &str = r#"{
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

const OUTCOME_SCHEMA: &str = r#"{
  "title": "dribble.EpisodeOutcome",
  "type": "object",
  "properties": {
    "seed": {"type": "integer"},
    "outcome": {"type": "string", "enum": ["goal", "ball_out", "time_limit", "controller_lost"]},
    "time_s": {"type": "number"}
  }
}"#;

/// The typed channels of one Foxglove context.
struct Channels {
    top: Channel<RawImage>,
    bottom: Channel<RawImage>,
    top_thumbnail: Channel<RawImage>,
    bottom_thumbnail: Channel<RawImage>,
    command: Arc<RawChannel>,
    markings: Channel<SceneUpdate>,
    scene: Channel<SceneUpdate>,
    robot_pose: Channel<PoseInFrame>,
    ball_pose: Channel<PoseInFrame>,
    outcome: Arc<RawChannel>,
}

impl Channels {
    fn new(context: &Arc<Context>) -> anyhow::Result<Self> {
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

/// `--mcap`, `--live` and `--mcap-camera-hz` of `dribble eval` and `dribble record`.
#[derive(Clone, Debug, clap::Args)]
pub struct FoxgloveArgs {
    /// Write one Foxglove MCAP file per episode into DIR (`episode_NNNNN.mcap`): camera
    /// images, the thumbnails the policy saw, every command, robot and ball poses and the
    /// outcome, on the simulated clock. Open them in Foxglove with
    /// `sim-harness/foxglove-layout.json`.
    #[arg(long, value_name = "DIR")]
    pub mcap: Option<PathBuf>,
    /// Serve the same channels on ws://127.0.0.1:PORT (default 8765) while the episodes play,
    /// paced to the simulated clock, to watch in Foxglove (Open connection, Foxglove
    /// WebSocket).
    #[arg(long, value_name = "PORT", num_args = 0..=1, default_missing_value = "8765")]
    pub live: Option<u16>,
    /// Camera images per simulated second and camera in the MCAP files and the live view
    /// (the thumbnails go at the cameras' 30 Hz).
    #[arg(long, default_value_t = 10.0, value_parser = positive_rate)]
    pub mcap_camera_hz: f64,
}

fn positive_rate(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(hz) if hz.is_finite() && hz > 0.0 => Ok(hz),
        _ => Err(format!("{text:?} is not a positive rate in Hz")),
    }
}

impl FoxgloveArgs {
    /// The observer these arguments ask for, `None` if neither MCAP nor live.
    pub fn observer(&self, renders: bool) -> anyhow::Result<Option<FoxgloveEpisodes>> {
        if self.mcap.is_none() && self.live.is_none() {
            return Ok(None);
        }
        FoxgloveEpisodes::new(FoxgloveOptions {
            mcap_dir: self.mcap.clone(),
            live_port: self.live,
            camera_hz: self.mcap_camera_hz,
            renders,
        })
        .map(Some)
    }
}

/// Where the episodes go and how densely.
#[derive(Clone, Debug)]
pub struct FoxgloveOptions {
    /// One `episode_NNNNN.mcap` per episode in this directory.
    pub mcap_dir: Option<PathBuf>,
    /// Serve the channels on `ws://127.0.0.1:PORT` while the episodes play, paced to the
    /// simulated clock (port 0: any free one).
    pub live_port: Option<u16>,
    /// Camera images per simulated second and camera (the thumbnails go at the cameras'
    /// full rate).
    pub camera_hz: f64,
    /// Whether the episodes render their cameras (without, there are no images to show).
    pub renders: bool,
}

/// Logs episodes to Foxglove (see the module documentation).
pub struct FoxgloveEpisodes {
    context: Arc<Context>,
    channels: Channels,
    options: FoxgloveOptions,
    server: Option<WebSocketServerHandle>,
    writer: Option<(McapWriterHandle<BufWriter<fs::File>>, PathBuf)>,
    seed: u64,
    /// When each camera's next image and the next state are due (simulated ns).
    next_camera_ns: [u64; 2],
    next_state_ns: u64,
    /// Wall-clock start of the episode, to pace a live view.
    started: std::time::Instant,
    thumbnails: (Box<TopThumbnail>, Box<BottomThumbnail>),
    /// The first write failure of the episode, reported when it ends.
    failure: Option<anyhow::Error>,
    written: Vec<PathBuf>,
}

impl std::fmt::Debug for FoxgloveEpisodes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FoxgloveEpisodes")
            .field("options", &self.options)
            .field("seed", &self.seed)
            .finish_non_exhaustive()
    }
}

impl FoxgloveEpisodes {
    pub fn new(options: FoxgloveOptions) -> anyhow::Result<Self> {
        let context = Context::new();
        let channels = Channels::new(&context)?;
        if let Some(dir) = &options.mcap_dir {
            fs::create_dir_all(dir)
                .with_context(|| format!("cannot create the MCAP directory {}", dir.display()))?;
        }
        let server = match options.live_port {
            Some(port) => {
                let server = WebSocketServer::new()
                    .name("dribble")
                    .bind("127.0.0.1", port)
                    .context(&context)
                    .start_blocking()
                    .with_context(|| {
                        format!("starting Foxglove's WebSocket server on port {port}")
                    })?;
                tracing::info!(
                    event = "foxglove_live",
                    url = %format!("ws://127.0.0.1:{}", server.port()),
                    action = "open it in Foxglove: Open connection, Foxglove WebSocket",
                );
                Some(server)
            }
            None => None,
        };
        Ok(Self {
            context,
            channels,
            options,
            server,
            writer: None,
            seed: 0,
            next_camera_ns: [0; 2],
            next_state_ns: 0,
            started: std::time::Instant::now(),
            thumbnails: (
                Box::new(TopThumbnail::black()),
                Box::new(BottomThumbnail::black()),
            ),
            failure: None,
            written: Vec::new(),
        })
    }

    /// The MCAP files written so far.
    pub fn written(&self) -> &[PathBuf] {
        &self.written
    }

    /// The first failure of the last episode's file, if any (taken: reported once).
    pub fn take_failure(&mut self) -> Option<anyhow::Error> {
        self.failure.take()
    }

    fn fail(&mut self, error: anyhow::Error) {
        if self.failure.is_none() {
            self.failure = Some(error);
        }
    }

    fn log_json(channel: &RawChannel, time: Timestamp, value: &serde_json::Value) {
        let bytes = value.to_string();
        channel.log_with_meta(
            bytes.as_bytes(),
            PartialMetadata {
                log_time: Some(time.as_nanos()),
            },
        );
    }

    fn scene_of_field(time: Timestamp) -> SceneUpdate {
        let field = FieldGeometry::SPL;
        let lines = LinePrimitive {
            r#type: line_primitive::Type::LineList as i32,
            pose: Some(pose(0.0, 0.0, 0.0, 0.0)),
            thickness: f64::from(field.line_width),
            scale_invariant: false,
            points: field
                .line_polylines(48)
                .iter()
                .flat_map(|line| line.windows(2))
                .flat_map(|pair| [point(pair[0], 0.002), point(pair[1], 0.002)])
                .collect(),
            color: Some(colour(0.94, 0.94, 0.94)),
            ..Default::default()
        };
        let mut cubes = vec![CubePrimitive {
            pose: Some(pose(0.0, 0.0, -0.005, 0.0)),
            size: Some(vector(
                field.length + 2.0 * field.border,
                field.width + 2.0 * field.border,
                0.01,
            )),
            color: Some(colour(0.24, 0.55, 0.27)),
        }];
        for side in [-1.0f32, 1.0] {
            let [(x, left), (_, right)] = field.goal_post_centres(side);
            let post = f64::from(field.goal_post_diameter);
            for y in [left, right] {
                cubes.push(CubePrimitive {
                    pose: Some(pose(x, y, field.goal_height / 2.0, 0.0)),
                    size: Some(Vector3 {
                        x: post,
                        y: post,
                        z: f64::from(field.goal_height),
                    }),
                    color: Some(colour(0.98, 0.86, 0.16)),
                });
            }
            cubes.push(CubePrimitive {
                pose: Some(pose(x, 0.0, field.goal_height, 0.0)),
                size: Some(Vector3 {
                    x: post,
                    y: f64::from(right - left) + post,
                    z: post,
                }),
                color: Some(colour(0.98, 0.86, 0.16)),
            });
        }
        SceneUpdate {
            deletions: Vec::new(),
            entities: vec![SceneEntity {
                timestamp: Some(foxglove_time(time)),
                frame_id: FIELD_FRAME.into(),
                id: "field".into(),
                lifetime: None,
                frame_locked: true,
                lines: vec![lines],
                cubes,
                ..Default::default()
            }],
        }
    }

    fn scene_of_state(time: Timestamp, robot: FieldPose, ball: Vec2) -> SceneUpdate {
        let entity = |id: &str| SceneEntity {
            timestamp: Some(foxglove_time(time)),
            frame_id: FIELD_FRAME.into(),
            id: id.into(),
            frame_locked: true,
            ..Default::default()
        };
        let ball_diameter = f64::from(FieldGeometry::SPL.ball_diameter);
        SceneUpdate {
            deletions: Vec::new(),
            entities: vec![
                SceneEntity {
                    cubes: vec![CubePrimitive {
                        // The Nao's footprint and height, roughly.
                        pose: Some(pose(robot.x, robot.y, 0.29, robot.theta)),
                        size: Some(vector(0.16, 0.28, 0.58)),
                        color: Some(colour(0.12, 0.24, 0.78)),
                    }],
                    arrows: vec![foxglove::messages::ArrowPrimitive {
                        pose: Some(pose(robot.x, robot.y, 0.6, robot.theta)),
                        shaft_length: 0.3,
                        shaft_diameter: 0.03,
                        head_length: 0.1,
                        head_diameter: 0.08,
                        color: Some(colour(0.12, 0.24, 0.78)),
                    }],
                    ..entity("robot")
                },
                SceneEntity {
                    spheres: vec![SpherePrimitive {
                        pose: Some(pose(
                            ball.x,
                            ball.y,
                            FieldGeometry::SPL.ball_diameter / 2.0,
                            0.0,
                        )),
                        size: Some(Vector3 {
                            x: ball_diameter,
                            y: ball_diameter,
                            z: ball_diameter,
                        }),
                        color: Some(colour(0.98, 0.43, 0.08)),
                    }],
                    ..entity("ball")
                },
            ],
        }
    }
}

impl EpisodeObserver for FoxgloveEpisodes {
    fn start(&mut self, setup: &EpisodeSetup) {
        self.seed = setup.seed;
        self.next_camera_ns = [0; 2];
        self.next_state_ns = 0;
        self.started = std::time::Instant::now();
        self.failure = None;
        if let Some(dir) = &self.options.mcap_dir {
            let path = dir.join(format!("episode_{:05}.mcap", setup.seed));
            let options = McapWriteOptions::default()
                .compression(Some(McapCompression::Zstd))
                .profile("dribble");
            let created = fs::File::create(&path)
                .with_context(|| format!("cannot create {}", path.display()))
                .and_then(|file| {
                    McapWriter::with_options(options)
                        .context(&self.context)
                        .create(BufWriter::new(file))
                        .with_context(|| format!("cannot start the MCAP file {}", path.display()))
                });
            match created {
                Ok(writer) => self.writer = Some((writer, path)),
                Err(error) => self.fail(error),
            }
        }
        let markings = Self::scene_of_field(Timestamp::ZERO);
        self.channels.markings.log_with_time(&markings, 0u64);
    }

    fn frame(
        &mut self,
        time: Timestamp,
        camera: CameraPosition,
        top: &TopFrame,
        bottom: &BottomFrame,
    ) {
        if !self.options.renders {
            return;
        }
        let index = match camera {
            CameraPosition::Top => 0,
            CameraPosition::Bottom => 1,
        };
        let due = due(
            &mut self.next_camera_ns[index],
            time,
            self.options.camera_hz,
        );
        let (top_thumbnail, bottom_thumbnail) = &mut self.thumbnails;
        let channels = &self.channels;
        match camera {
            CameraPosition::Top => log_camera(
                [&channels.top, &channels.top_thumbnail],
                "camera_top",
                time,
                top,
                due,
                top_thumbnail,
            ),
            CameraPosition::Bottom => log_camera(
                [&channels.bottom, &channels.bottom_thumbnail],
                "camera_bottom",
                time,
                bottom,
                due,
                bottom_thumbnail,
            ),
        }
    }

    fn command(&mut self, time: Timestamp, command: &MotionCommand) {
        let kind = if command.is_new() {
            "new"
        } else if command.is_stop() {
            "stop"
        } else {
            "repeated"
        };
        let [forward, left, turn] = command.speed.as_array();
        Self::log_json(
            &self.channels.command,
            time,
            &json!({
                "forward": forward,
                "left": left,
                "turn": turn,
                "kind": kind,
                "sequence": command.sequence,
                "top_sequence": command.top_sequence,
                "bottom_sequence": command.bottom_sequence,
            }),
        );
    }

    fn state(&mut self, time: Timestamp, robot: FieldPose, ball: Vec2) {
        if !due(&mut self.next_state_ns, time, STATE_HZ) {
            return;
        }
        let ns = time.as_nanos();
        if self.server.is_some() {
            // A viewer that joined since the start has not seen the field.
            if ns % 1_000_000_000 < (1e9 / STATE_HZ) as u64 {
                let markings = Self::scene_of_field(time);
                self.channels.markings.log_with_time(&markings, ns);
            }
            // Live: no faster than the simulated clock, so that people can watch.
            let due = std::time::Duration::from_nanos(ns);
            if let Some(ahead) = due.checked_sub(self.started.elapsed()) {
                std::thread::sleep(ahead);
            }
        }
        self.channels
            .scene
            .log_with_time(&Self::scene_of_state(time, robot, ball), ns);
        let in_field = |x: f32, y: f32, z: f32, theta: f32| PoseInFrame {
            timestamp: Some(foxglove_time(time)),
            frame_id: FIELD_FRAME.into(),
            pose: Some(pose(x, y, z, theta)),
        };
        self.channels
            .robot_pose
            .log_with_time(&in_field(robot.x, robot.y, 0.0, robot.theta), ns);
        self.channels
            .ball_pose
            .log_with_time(&in_field(ball.x, ball.y, 0.0, 0.0), ns);
    }

    fn end(&mut self, time: Timestamp, outcome: Outcome) {
        Self::log_json(
            &self.channels.outcome,
            time,
            &json!({
                "seed": self.seed,
                "outcome": serde_json::to_value(outcome).unwrap_or_default(),
                "time_s": time.as_nanos() as f64 / 1e9,
            }),
        );
        if let Some((writer, path)) = self.writer.take() {
            match writer.close() {
                Ok(_) => self.written.push(path),
                Err(error) => {
                    let error = anyhow::Error::from(error)
                        .context(format!("cannot finish the MCAP file {}", path.display()));
                    self.fail(error);
                }
            }
        }
    }
}

/// One camera's frame at `time`: the image when one is due, and the thumbnail the policy
/// computes from it (the robot's own `downscale`), every frame.
fn log_camera<const FW: usize, const FH: usize, const TW: usize, const TH: usize>(
    [image_channel, thumbnail_channel]: [&Channel<RawImage>; 2],
    frame_id: &str,
    time: Timestamp,
    frame: &CameraFrame<FW, FH>,
    image_due: bool,
    thumbnail: &mut Thumbnail<TW, TH>,
) {
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
fn log_image(
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
fn due(next: &mut u64, time: Timestamp, hz: f64) -> bool {
    let now = time.as_nanos();
    if now < *next {
        return false;
    }
    let period = ((1e9 / hz) as u64).max(1);
    *next += period * ((now - *next) / period + 1);
    true
}

fn foxglove_time(time: Timestamp) -> FoxgloveTime {
    let ns = time.as_nanos();
    FoxgloveTime::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

fn vector(x: f32, y: f32, z: f32) -> Vector3 {
    Vector3 {
        x: f64::from(x),
        y: f64::from(y),
        z: f64::from(z),
    }
}

fn point(p: Vec2, z: f32) -> Point3 {
    Point3 {
        x: f64::from(p.x),
        y: f64::from(p.y),
        z: f64::from(z),
    }
}

fn colour(r: f64, g: f64, b: f64) -> Color {
    Color { r, g, b, a: 1.0 }
}

/// A pose at (x, y, z) turned by `yaw` about z.
fn pose(x: f32, y: f32, z: f32, yaw: f32) -> Pose {
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
