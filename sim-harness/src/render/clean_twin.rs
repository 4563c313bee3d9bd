//! The clean twin of a conditioned episode: each frame rendered a second time as a clean
//! camera in clean light shows the same scene ([`EpisodeLook::clean_twin`]: no camera effect,
//! no light condition; the venue and the robots standing about kept), and made into
//! thumbnails by the robot's own code. A policy trained on clean renders sees a conditioned
//! row's twin as it learned to, so its command there can label the row (`dribble record
//! --clean-twin`, the trainer's `--distill-camera-clean`).
//!
//! Where the episode's look is its own clean twin (clean, or only venue and robots) nothing
//! is rendered twice: the twin's thumbnails are then the row's own.

use dribble_controller::thumbnail::downscale;
use dribble_controller::{BottomFrame, BottomThumbnail, CameraPosition, TopFrame, TopThumbnail};

use super::{RenderError, Renderer, SceneState};
use crate::camera_model::CameraModel;
use crate::conditions::EpisodeLook;

/// A second renderer that draws every frame without the episode's camera effects and light,
/// its newest frame of each camera and the thumbnails made from them.
#[derive(Debug)]
pub struct CleanTwin {
    renderer: Renderer,
    top: Box<TopFrame>,
    bottom: Box<BottomFrame>,
    top_thumbnail: Box<TopThumbnail>,
    bottom_thumbnail: Box<BottomThumbnail>,
    /// The episode's look is its own twin: nothing to render twice.
    same_as_episode: bool,
}

impl CleanTwin {
    pub(super) fn new(renderer: Renderer) -> Self {
        Self {
            renderer,
            top: TopFrame::new_boxed(),
            bottom: BottomFrame::new_boxed(),
            top_thumbnail: Box::new(TopThumbnail::black()),
            bottom_thumbnail: Box::new(BottomThumbnail::black()),
            same_as_episode: true,
        }
    }

    pub(super) fn begin_episode(&mut self, look: &EpisodeLook) {
        let twin = look.clean_twin();
        self.same_as_episode = twin == *look;
        self.renderer.begin_episode(&twin);
    }

    /// Renders what `camera` would see of `scene` without camera effects and light (nothing
    /// when the episode is its own twin).
    pub fn render(
        &mut self,
        position: CameraPosition,
        camera: &CameraModel,
        scene: &SceneState,
    ) -> Result<(), RenderError> {
        if self.same_as_episode {
            return Ok(());
        }
        match position {
            CameraPosition::Top => self.renderer.render(position, camera, scene, &mut self.top),
            CameraPosition::Bottom => {
                self.renderer
                    .render(position, camera, scene, &mut self.bottom)
            }
        }
    }

    /// The thumbnails of the newest twin frames, or `None` where the episode is its own
    /// twin (the row's own thumbnails are then the twin's).
    pub fn thumbnails(&mut self) -> Option<(&TopThumbnail, &BottomThumbnail)> {
        if self.same_as_episode {
            return None;
        }
        downscale(&self.top, &mut self.top_thumbnail);
        downscale(&self.bottom, &mut self.bottom_thumbnail);
        Some((&self.top_thumbnail, &self.bottom_thumbnail))
    }
}
