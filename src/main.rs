//! `dribble`: the project's command-line tool: look at the simulated cameras, inspect raw
//! frames. Recording and evaluation (`record`, `eval`, `inspect`) come with the expert.

mod render_command;
mod thumbnail_command;

use clap::{Parser, Subcommand};

/// dribble: end-to-end imitation learning for RoboCup SPL soccer on the Nao.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Turns a raw YUYV camera frame (a dump from the robot's camera driver) into the
    /// thumbnail the policy would see, written as a PGM image, and prints its 5-bin histogram.
    Thumbnail(thumbnail_command::ThumbnailArgs),
    /// Renders both simulated cameras at the start of an episode (or after walking a while),
    /// and writes PNGs: each camera image, the thumbnails the policy sees, and a top-down view
    /// of the field with the robot, its cameras' view and the ball.
    Render(render_command::RenderArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Thumbnail(args) => thumbnail_command::run(&args),
        Command::Render(args) => render_command::run(&args),
    }
}
