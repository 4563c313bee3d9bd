//! # dribble-controller
//!
//! The robot side of dribble: a fixed-rate loop that turns the Nao's two camera images into
//! walk speed commands with a learned policy, as in *End-to-End Deep Imitation Learning:
//! Robot Soccer Case Study* (Aşık, Görer, Akın). One tick reads as the paper's pipeline:
//!
//! frames ([`frame`]) → synchronisation ([`camera_sync`]) → thumbnails ([`thumbnail`]) →
//! policy ([`policy`]) → command ([`speed_command`], [`motion_command`]),
//!
//! put together by [`control_loop::ControlLoop`] and timed by a [`clock::Clock`]. After
//! start-up a tick allocates nothing. [`transport`] brings frames in and takes commands out:
//! iceoryx2 shared memory between processes, or channels to a thread. This crate knows nothing of the simulator; the
//! simulator depends on it.

#![deny(unsafe_code)]

#[cfg(test)]
/// This package's directory: the one cargo names when it runs the test (`CARGO_MANIFEST_DIR`
/// in the environment: the checkout under test, even when its build directory was shared with
/// a checkout elsewhere), else the one the test was compiled in.
pub(crate) fn package_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(
        || env!("CARGO_MANIFEST_DIR").into(),
        std::path::PathBuf::from,
    )
}

pub mod camera_sync;
pub mod clock;
pub mod control_loop;
pub mod frame;
pub mod histogram;
pub mod log_output;
pub mod motion_command;
pub mod policy;
pub mod realtime;
pub mod run_statistics;
pub mod shutdown;
pub mod speed_command;
pub mod test_pattern;
pub mod thumbnail;
pub mod tick_stats;
pub mod transport;
pub mod units;

pub use camera_sync::{CameraSync, SyncConfig, SyncDecision};
pub use clock::{Clock, ManualClock, MonotonicClock};
pub use control_loop::{CameraInput, ControlLoop, LoopConfig, LoopCounters};
pub use frame::{BottomFrame, CameraFrame, CameraPosition, FrameError, FrameHeader, TopFrame};
pub use motion_command::{CommandFlags, MotionCommand};
pub use policy::{Policy, PolicyError, PolicyInput, PolicyOutput};
pub use speed_command::{SpeedCommand, WalkLimits};
pub use thumbnail::{BottomThumbnail, Thumbnail, TopThumbnail};
pub use units::Timestamp;
