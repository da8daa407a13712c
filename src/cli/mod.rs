//! The `vidslam` command line: one subcommand per module here.

pub mod camera;
pub mod config;
pub mod dataset;
pub mod demo;
pub mod eval;
pub mod imu;

use clap::{Parser, Subcommand};

pub mod mavlink;
pub mod replay;
pub mod sim;

/// Visual-inertial direct SLAM for drones: replay, evaluation, simulation and drivers.
#[derive(Parser, Debug)]
#[command(name = "vidslam", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Simulate a flight (the built-in one unless --trajectory), run the full odometry over it,
    /// print accuracy and timing.
    Demo(demo::DemoArgs),
    /// Inspect ASL/EuRoC dataset folders.
    Dataset(dataset::DatasetArgs),
    /// Render a camera + IMU sequence with ground truth and depth (simulator).
    Sim(sim::SimArgs),
    /// Compare an estimated trajectory with ground truth (ATE, RPE, scale error).
    Eval(eval::EvalArgs),
    /// Microstrain 3DM-GX4-25 IMU: decode and record MIP streams.
    Imu(imu::ImuArgs),
    /// MAVLink output to a flight controller (trajectory playback to test an FC setup).
    Mavlink(mavlink::MavlinkArgs),
    /// Camera drivers: list devices, show one, record frames (`camera --help`).
    Camera(camera::CameraArgs),
    /// Run the odometry over a recorded dataset; write the trajectory and an accuracy report.
    Replay(replay::ReplayArgs),
    /// Print the effective configuration (defaults, or a file completed with them).
    Config(config::ConfigArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Dataset(a) => dataset::run(a),
        Command::Sim(a) => sim::run(a),
        Command::Eval(args) => eval::run(&args),
        Command::Imu(args) => imu::run(args),
        Command::Mavlink(a) => mavlink::run(a),
        Command::Camera(args) => camera::run(args),
        Command::Replay(a) => replay::run(a),
        Command::Config(a) => config::run(a),
    }
}
