//! # dribble-sim
//!
//! The simulator harness that stands in for SimRobot: the SPL field, physics, the two Nao
//! cameras, the expert, the episode runner, the recorder and the evaluator. It depends on
//! `dribble-controller`'s public types (frames, commands, the policy trait), never the reverse.
//!
//! Today it holds the field geometry of DESIGN.md; physics and rendering build on it.

pub mod field;
