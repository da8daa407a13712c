//! The `vidslam` command line: one subcommand per module here.

pub mod dataset;
pub mod sim;

use clap::{Parser, Subcommand};

/// Visual-inertial direct SLAM for drones: replay, evaluation, simulation and drivers.
#[derive(Parser, Debug)]
#[command(name = "vidslam", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Inspect ASL/EuRoC dataset folders.
    Dataset(dataset::DatasetArgs),
    /// Render a camera + IMU sequence with ground truth and depth (simulator).
    Sim(sim::SimArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Dataset(a) => dataset::run(a),
        Command::Sim(a) => sim::run(a),
    }
}
