//! Closed-loop evaluations beyond one process: several at once (`jobs`), resumable
//! (`journal`), and how sure a goal count is (`goal_rate`).

pub mod closed_loop;
pub mod goal_rate;
pub mod jobs;
pub mod journal;
