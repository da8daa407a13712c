//! The `vidslam` command line: one subcommand per module here.

pub mod camera;

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
    /// Camera drivers: list devices, show one, record frames (`camera --help`).
    Camera(camera::CameraArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Camera(args) => camera::run(args),
    }
}
