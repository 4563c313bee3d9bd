//! `dribble`: the project's command-line tool. The simulator commands (`render`, `record`,
//! `eval`, `inspect`) arrive with the simulator; today it inspects raw camera frames.

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
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Thumbnail(args) => thumbnail_command::run(&args),
    }
}
