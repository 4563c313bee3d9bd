//! The policy interface: two thumbnails in, a speed command out.
//!
//! Implementations own whatever scratch memory they need, sized when they are built, and
//! read the caller's thumbnails in place, so an allocation-free engine can sit behind it.
//! The control loop checks what comes out (clamping, non-finite values) before it reaches
//! the walk.

mod brightness;
pub mod commitment;
pub mod engine;
pub mod file_watch;
mod learned;
pub mod manifest;
pub mod model_limits;
pub mod network_input;
mod onnx_network;

pub use brightness::BrightnessPolicy;
pub use learned::{
    CnnPolicy, Engine, EngineOptions, EngineReport, HcnnPolicy, OnnxPolicy, RcnnPolicy,
};
pub use manifest::{PolicyKind, PolicyManifest};

use std::path::PathBuf;

use crate::speed_command::SpeedCommand;
use crate::thumbnail::{BottomThumbnail, TopThumbnail};

/// What a policy sees at one step: the newest thumbnail of each camera, owned by the caller,
/// and the command the controller sent last (a stop at an episode's start and wherever it
/// sent a stop). Only a network whose manifest names `[inputs] previous` reads `previous`.
#[derive(Clone, Copy, Debug)]
pub struct PolicyInput<'a> {
    pub top: &'a TopThumbnail,
    pub bottom: &'a BottomThumbnail,
    pub previous: SpeedCommand,
}

impl<'a> PolicyInput<'a> {
    /// The thumbnails with a stop as the last command: an episode's first step, or a policy
    /// that reads no last command.
    pub fn at_rest(top: &'a TopThumbnail, bottom: &'a BottomThumbnail) -> Self {
        Self {
            top,
            bottom,
            previous: SpeedCommand::STOP,
        }
    }
}

/// A policy's raw answer in normalised units, before the controller clamps it and turns
/// non-finite values into a stop.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PolicyOutput {
    pub forward: f32,
    pub left: f32,
    pub turn: f32,
}

/// A policy step that produced no command. The tick publishes a stop and counts it.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    /// The tract engine failed; the message (tract's error) says why. tract allocates on
    /// every run anyway, so building the message does too.
    #[error("inference failed: {0}")]
    Inference(String),
    /// An allocation-free engine failed for a reason known when it was written: reporting
    /// it allocates nothing, so the failure path of a tick stays allocation-free.
    #[error("inference failed: {0}")]
    Engine(&'static str),
}

/// Why a policy could not be loaded. Every variant names the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum PolicyLoadError {
    #[error("cannot read {}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("bad policy manifest {}: {problem}", path.display())]
    Manifest { path: PathBuf, problem: String },
    #[error("{} {problem}", path.display())]
    Onnx { path: PathBuf, problem: String },
    #[error("{}: {what} must be {expected}, found {found}", path.display())]
    Mismatch {
        path: PathBuf,
        what: String,
        expected: String,
        found: String,
    },
}

/// A driving policy run by the controller at camera rate.
pub trait Policy {
    /// One step on the newest pair of thumbnails.
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError>;

    /// Forgets any state carried between steps (the R-CNN's LSTM state); called at an
    /// episode's start.
    fn reset(&mut self);
}

impl<P: Policy + ?Sized> Policy for &mut P {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        (**self).step(input)
    }

    fn reset(&mut self) {
        (**self).reset()
    }
}

impl<P: Policy + ?Sized> Policy for Box<P> {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        (**self).step(input)
    }

    fn reset(&mut self) {
        (**self).reset()
    }
}
