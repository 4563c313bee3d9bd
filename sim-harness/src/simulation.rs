//! The world, the walk and the cameras' schedule together: one physics step at a time,
//! a motion cycle every third step (100 Hz), and a camera frame due every fifth step, the
//! top and bottom cameras taking turns (30 Hz each, the bottom half a period later).

use dribble_controller::{CameraPosition, SpeedCommand, Timestamp};

use crate::camera_geometry::CameraGeometry;
use crate::camera_model::CameraModel;
use crate::episode::EpisodeSetup;
use crate::field::FieldGeometry;
use crate::render::SceneState;
use crate::walk::{Walk, WalkConfig};
use crate::world::{STEP_SECONDS, STEPS_PER_SECOND, World, WorldConfig};

/// Mixed into the episode seed for the walk's noise, so that its random stream is not the
/// one that placed the robot and the ball.
const WALK_SEED_SALT: u64 = 0x5EED_0F0D_D5D5_A1C3;

/// Physics steps per motion cycle (100 Hz).
pub const STEPS_PER_MOTION_CYCLE: u64 = 3;

/// A running episode's physical side.
#[derive(Debug)]
pub struct Simulation {
    world: World,
    walk: Walk,
    cameras: CameraGeometry,
    command: SpeedCommand,
    steps_per_frame: u64,
}

impl Simulation {
    /// The world of `setup`; the walk's noise is seeded from the setup's seed.
    pub fn new(
        setup: &EpisodeSetup,
        world: WorldConfig,
        walk: WalkConfig,
        cameras: CameraGeometry,
    ) -> Self {
        let steps_per_frame = (STEPS_PER_SECOND as f32 / cameras.frame_rate_hz).round() as u64;
        Self {
            world: World::new(world, FieldGeometry::SPL, setup.robot, setup.ball),
            walk: Walk::new(walk, setup.seed ^ WALK_SEED_SALT),
            cameras,
            command: SpeedCommand::STOP,
            steps_per_frame: steps_per_frame.max(2),
        }
    }

    /// The command the walk takes at its next motion cycle.
    pub fn set_command(&mut self, command: SpeedCommand) {
        self.command = command;
    }

    /// Advances one physics step; returns the camera whose frame is due at the new time.
    pub fn step(&mut self) -> Option<CameraPosition> {
        if self.world.steps().is_multiple_of(STEPS_PER_MOTION_CYCLE) {
            self.walk
                .motion_cycle(self.command, STEP_SECONDS * STEPS_PER_MOTION_CYCLE as f32);
        }
        let next = self.walk.advance(self.world.robot_pose(), STEP_SECONDS);
        self.world.step(next);
        self.camera_due()
    }

    /// The camera whose frame falls on the current step, if any.
    pub fn camera_due(&self) -> Option<CameraPosition> {
        let phase = self.world.steps() % self.steps_per_frame;
        if phase == 0 {
            Some(CameraPosition::Top)
        } else if phase == self.steps_per_frame / 2 {
            Some(CameraPosition::Bottom)
        } else {
            None
        }
    }

    /// The camera as it is now, gait sway included.
    pub fn camera(&self, position: CameraPosition) -> CameraModel {
        CameraModel::new(
            self.cameras.mount(position),
            self.world.robot_pose(),
            self.walk.sway(),
        )
    }

    pub fn scene(&self) -> SceneState {
        let ball = self.world.ball();
        SceneState {
            ball: Some((ball.position, ball.rotation)),
            time_ns: self.world.time().as_nanos(),
        }
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn world_mut(&mut self) -> &mut World {
        &mut self.world
    }

    pub fn time(&self) -> Timestamp {
        self.world.time()
    }

    pub fn cameras(&self) -> &CameraGeometry {
        &self.cameras
    }

    /// The sequence number of the frame due now for `camera` (frames count from zero).
    pub fn frame_sequence(&self, camera: CameraPosition) -> u64 {
        let offset = match camera {
            CameraPosition::Top => 0,
            CameraPosition::Bottom => self.steps_per_frame / 2,
        };
        self.world.steps().saturating_sub(offset) / self.steps_per_frame
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    #[test]
    fn cameras_take_turns_at_thirty_hertz_each() {
        let setup = EpisodeSetup::placed(Default::default(), Vec2::new(2.0, 0.0));
        let mut sim = Simulation::new(
            &setup,
            WorldConfig::default(),
            WalkConfig::default(),
            CameraGeometry::nao(),
        );
        assert_eq!(sim.camera_due(), Some(CameraPosition::Top));
        let mut due = Vec::new();
        for _ in 0..STEPS_PER_SECOND {
            if let Some(camera) = sim.step() {
                due.push((camera, sim.time().as_nanos(), sim.frame_sequence(camera)));
            }
        }
        let tops = due.iter().filter(|d| d.0 == CameraPosition::Top).count();
        let bottoms = due.iter().filter(|d| d.0 == CameraPosition::Bottom).count();
        assert_eq!((tops, bottoms), (30, 30));
        assert_eq!(due[0], (CameraPosition::Bottom, 16_666_666, 0));
        assert_eq!(due[1], (CameraPosition::Top, 33_333_333, 1));
    }
}
