//! What an episode shows, logged as it happens: `FoxgloveEpisodes` as the runner's
//! [`EpisodeObserver`].

use std::fs;
use std::io::BufWriter;

use super::FoxgloveEpisodes;
use super::channels::{FIELD_FRAME, STATE_HZ, due, foxglove_time, log_camera, pose};
use anyhow::Context as _;
use dribble_controller::{BottomFrame, CameraPosition, MotionCommand, Timestamp, TopFrame};
use dribble_sim::dataset::Outcome;
use dribble_sim::episode::EpisodeSetup;
use dribble_sim::episode_observer::EpisodeObserver;
use dribble_sim::pose::FieldPose;
use foxglove::messages::PoseInFrame;
use foxglove::{McapCompression, McapWriteOptions, McapWriter};
use glam::Vec2;
use serde_json::json;

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
            CameraPosition::Top => log_camera(channels, camera, time, top, due, top_thumbnail),
            CameraPosition::Bottom => {
                log_camera(channels, camera, time, bottom, due, bottom_thumbnail)
            }
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
