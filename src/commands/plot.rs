//! `dribble plot`: the trajectory figure drawn again from the JSON that `dribble eval
//! --trajectories` wrote, without playing the episodes again (a closed-loop evaluation of
//! twenty episodes takes minutes to an hour; a figure takes a second). The file's format:
//! [`crate::trajectories::file`].

use std::path::PathBuf;

use clap::Args;
use dribble_sim::dataset::Outcome;

use crate::trajectories::file::read_trajectories;
use crate::trajectories::plot::{plot_trajectories, title};

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The JSON written by `dribble eval --trajectories`.
    #[arg(long)]
    trajectories: PathBuf,
    /// Where to write the figure (PNG).
    #[arg(long, default_value = "eval_trajectories.png")]
    plot: PathBuf,
    /// Who drove, for the title: the driver given to `dribble eval` (`expert`, or the
    /// policy's `policy.toml`). The JSON does not record it.
    #[arg(long)]
    driver: String,
}

pub fn run(args: &PlotArgs) -> anyhow::Result<()> {
    let results = read_trajectories(&args.trajectories)?;
    let goals = results
        .iter()
        .filter(|r| r.outcome == Outcome::Goal)
        .count();
    plot_trajectories(&results, &title(&args.driver, &results), &args.plot)?;
    println!(
        "{goals} of {} goals; trajectory plot: {}",
        results.len(),
        args.plot.display()
    );
    Ok(())
}
