//! What an evaluation leaves: the trajectories file (`file`) and the figure drawn from it
//! (`plot`).

pub mod file;
pub mod plot;
