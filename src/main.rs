//! `dribble`: the project's command-line tool: look at the simulated cameras, inspect raw
//! frames. Recording and evaluation (`record`, `eval`, `inspect`) come with the expert.

mod controller_session;
mod episodes;
mod eval_command;
mod eval_jobs;
mod eval_journal;
mod foxglove_episodes;
mod goal_rate;
mod gym_server_command;
mod inspect_command;
mod merge_command;
mod plot_command;
mod plot_image;
mod record_command;
mod render_command;
mod score_command;
mod soak_command;
mod soak_faults;
mod soak_motion_side;
mod thumbnail_command;
mod trajectory_file;
mod trajectory_plot;

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
    Thumbnail(thumbnail_command::ThumbnailArgs),
    /// Renders both simulated cameras at the start of an episode (or after walking a while),
    /// and writes PNGs: each camera image, the thumbnails the policy sees, and a top-down view
    /// of the field with the robot, its cameras' view and the ball.
    Render(render_command::RenderArgs),
    /// Plays episodes in closed loop with the expert or a learned policy and prints, per
    /// episode, the outcome, the time and the distance walked; then the goal count, the
    /// controller's latency, and writes a trajectory plot.
    Eval(eval_command::EvalArgs),
    /// Draws the trajectory figure again from the JSON `dribble eval --trajectories` wrote,
    /// without playing the episodes again.
    Plot(plot_command::PlotArgs),
    /// Records demonstrations: the cameras are rendered, every computed command is stored
    /// with the thumbnails it came from, one .npz per episode plus dataset.json. The expert
    /// drives, or a learned policy drives and the expert labels every state it visits
    /// (DAgger).
    Record(record_command::RecordArgs),
    /// Checks a recorded dataset and summarises it: counts, outcomes, phases, a histogram
    /// picture of the commands and phases, and a contact sheet of sample thumbnails.
    Inspect(inspect_command::InspectArgs),
    /// Replays a recorded dataset through a learned policy as the controller runs it (the
    /// R-CNN stepped from a zero state per episode, the H-CNN gated in Rust) and prints the
    /// paper's error, overall and per expert phase.
    Score(score_command::ScoreArgs),
    /// Runs the controller process with a learned policy against cameras published over
    /// iceoryx2 at the robot's rates (30 Hz, 100 Hz ticks, CLOCK_MONOTONIC) for minutes or
    /// hours; samples its memory, open files and command latency every second into a CSV,
    /// and fails on memory growth, missed deadlines or a lost command.
    Soak(soak_command::SoakArgs),
    /// Serves episodes step by step on standard input and output for the Gymnasium
    /// environment `dribble/NaoDribble-v0` (models/dribble_models/gym_env.py): an
    /// observation (both thumbnails) whenever the controller would compute a command, the
    /// action back as that command. Not meant to be run by hand.
    GymServer(gym_server_command::GymServerArgs),
    /// Puts the shares of one recording or one evaluation, played apart (on a Ray cluster:
    /// `python -m dribble_models.cluster`), back together as one serial run writes them.
    Merge(merge_command::MergeArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    log_output::install(cli.log_format)?;
    match cli.command {
        Command::Thumbnail(args) => thumbnail_command::run(&args),
        Command::Render(args) => render_command::run(&args),
        Command::Eval(args) => eval_command::run(&args),
        Command::Plot(args) => plot_command::run(&args),
        Command::Record(args) => record_command::run(&args),
        Command::Inspect(args) => inspect_command::run(&args),
        Command::Score(args) => score_command::run(&args),
        Command::Soak(args) => soak_command::run(&args),
        Command::GymServer(args) => gym_server_command::run(&args),
        Command::Merge(args) => merge_command::run(&args),
    }
}
