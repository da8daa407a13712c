//! The `vidslam` command line: one subcommand per module here.

pub mod imu;

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
    /// Microstrain 3DM-GX4-25 IMU: decode and record MIP streams.
    Imu(imu::ImuArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Imu(args) => imu::run(args),
    }
}
