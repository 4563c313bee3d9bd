//! `dribble`: the project's command-line tool. `commands/` has one file a subcommand (its
//! arguments and a thin `run`); the folders beside it hold what those commands share:
//! `evaluation/` (parallel and resumable closed loops, goal intervals), `trajectories/` (the
//! trajectories file and its figure), `soak/` (faults and the motion module's side), and
//! `controller_session` (finding, starting and reading the controller process).

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

mod commands;
mod controller_session;
mod dataset_pictures;
mod episodes;
mod evaluation;
mod foxglove_episodes;
mod gym_exchange;
mod picture;
mod recording;
mod soak;
mod trajectories;

use clap::{Parser, Subcommand};
use dribble_controller::log_output::{self, LogFormat};

/// dribble: end-to-end imitation learning for RoboCup SPL soccer on the Nao.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    /// How events (a controller started or joined, a refused real-time setting, a network
    /// the compiled engine cannot run) are logged on standard error: `logfmt` or `json`.
    /// `RUST_LOG` filters them (default `info`). Results go to standard output.
    #[arg(long, default_value = "logfmt", global = true)]
    log_format: LogFormat,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Turns a raw YUYV camera frame (a dump from the robot's camera driver) into the
    /// thumbnail the policy would see, written as a PGM image, and prints its 5-bin histogram.
    Thumbnail(commands::thumbnail::ThumbnailArgs),
    /// Renders both simulated cameras at the start of an episode (or after walking a while),
    /// and writes PNGs: each camera image, the thumbnails the policy sees, and a top-down view
    /// of the field with the robot, its cameras' view and the ball.
    Render(commands::render::RenderArgs),
    /// Plays episodes in closed loop with the expert or a learned policy and prints, per
    /// episode, the outcome, the time and the distance walked; then the goal count, the
    /// controller's latency, and writes a trajectory plot.
    Eval(commands::eval::EvalArgs),
    /// Draws the trajectory figure again from the JSON `dribble eval --trajectories` wrote,
    /// without playing the episodes again.
    Plot(commands::plot::PlotArgs),
    /// Records demonstrations: the cameras are rendered, every computed command is stored
    /// with the thumbnails it came from, one .npz per episode plus dataset.json. The expert
    /// drives, or a learned policy drives and the expert labels every state it visits
    /// (DAgger).
    Record(commands::record::RecordArgs),
    /// Checks a recorded dataset and summarises it: counts, outcomes, phases, a histogram
    /// picture of the commands and phases, and a contact sheet of sample thumbnails.
    Inspect(commands::inspect::InspectArgs),
    /// Replays a recorded dataset through a learned policy as the controller runs it (the
    /// R-CNN stepped from a zero state per episode, the H-CNN gated in Rust) and prints the
    /// paper's error, overall and per expert phase.
    Score(commands::score::ScoreArgs),
    /// Runs the controller process with a learned policy against cameras published over
    /// iceoryx2 at the robot's rates (30 Hz, 100 Hz ticks, CLOCK_MONOTONIC) for minutes or
    /// hours; samples its memory, open files and command latency every second into a CSV,
    /// and fails on memory growth, missed deadlines or a lost command.
    Soak(commands::soak::SoakArgs),
    /// Serves episodes step by step on standard input and output for the Gymnasium
    /// environment `dribble/NaoDribble-v0` (models/dribble_models/gym_env.py): an
    /// observation (both thumbnails) whenever the controller would compute a command, the
    /// action back as that command. Not meant to be run by hand.
    GymServer(commands::gym_server::GymServerArgs),
    /// Puts the shares of one recording or one evaluation, played apart (on a Ray cluster:
    /// `python -m dribble_models.cluster`), back together as one serial run writes them.
    Merge(commands::merge::MergeArgs),
}

fn main() -> anyhow::Result<()> {
    restore_default_sigpipe();
    let cli = Cli::parse();
    log_output::install(cli.log_format)?;
    match cli.command {
        Command::Thumbnail(args) => commands::thumbnail::run(&args),
        Command::Render(args) => commands::render::run(&args),
        Command::Eval(args) => commands::eval::run(&args),
        Command::Plot(args) => commands::plot::run(&args),
        Command::Record(args) => commands::record::run(&args),
        Command::Inspect(args) => commands::inspect::run(&args),
        Command::Score(args) => commands::score::run(&args),
        Command::Soak(args) => commands::soak::run(&args),
        Command::GymServer(args) => commands::gym_server::run(&args),
        Command::Merge(args) => commands::merge::run(&args),
    }
}

/// Lets a closed pipe end this program quietly, as it ends `cat` or `grep` (`dribble score ...
/// | head -2`): Rust ignores SIGPIPE, which turns the next write into a panic.
fn restore_default_sigpipe() {
    // SAFETY: called first thing in main, before any thread starts; SIG_DFL is a valid
    // disposition for SIGPIPE.
    #[allow(unsafe_code)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
