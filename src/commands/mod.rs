//! One file a subcommand: its arguments (clap) and `run`, which turns them into the options of
//! the domain modules beside this folder and calls them.

pub mod eval;
pub mod gym_server;
pub mod inspect;
pub mod merge;
pub mod plot;
pub mod record;
pub mod render;
pub mod score;
pub mod soak;
pub mod thumbnail;
