//! # dribble-sim
//!
//! The simulator harness that stands in for SimRobot: the SPL field in rapier3d physics
//! ([`world`]), a B-Human-like walk ([`walk`]), the Nao's two head cameras rendered headless
//! with wgpu ([`render`], [`camera_model`], [`camera_geometry`]), and pictures for people
//! ([`top_view`], [`image_output`]). It depends on `dribble-controller`'s public types
//! (frames, commands), never the reverse.

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

pub mod ball_memory;
pub mod camera_geometry;
pub mod camera_model;
pub mod conditions;
pub mod controller_link;
pub mod dataset;
pub mod episode;
pub mod episode_observer;
pub mod expert;
pub mod field;
pub mod image_output;
pub mod pose;
pub mod render;
pub mod runner;
pub mod simulation;
pub mod top_view;
pub mod visibility;
pub mod walk;
pub mod world;
