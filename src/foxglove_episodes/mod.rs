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
use dribble_controller::{BottomThumbnail, Timestamp, TopThumbnail};
use dribble_sim::field::FieldGeometry;
use dribble_sim::pose::FieldPose;
use foxglove::messages::{
    CubePrimitive, LinePrimitive, SceneEntity, SceneUpdate, SpherePrimitive, Vector3,
    line_primitive,
};
use foxglove::{
    Context, McapWriterHandle, PartialMetadata, RawChannel, WebSocketServer, WebSocketServerHandle,
};
use glam::Vec2;
mod channels;
mod observer;

use channels::{Channels, FIELD_FRAME, colour, foxglove_time, point, pose, vector};

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
