//! The soak's parts beside its command (`commands::soak`): the controller process under
//! soak, the cameras' and the motion module's sides, the commands' watch, the seconds' log,
//! the faults it injects and the verdict.

pub mod cameras;
pub mod command_watch;
pub mod controller_process;
pub mod faults;
pub mod motion_side;
pub mod replacement_policy;
pub mod second_log;
pub mod verdict;
