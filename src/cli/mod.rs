//! The `vidslam` command line: one subcommand per module here.

use clap::{Parser, Subcommand};

pub mod mavlink;

/// Visual-inertial direct SLAM for drones: replay, evaluation, simulation and drivers.
#[derive(Parser, Debug)]
#[command(name = "vidslam", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// MAVLink output to a flight controller (trajectory playback to test an FC setup).
    Mavlink(mavlink::MavlinkArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Mavlink(a) => mavlink::run(a),
    }
}
