//! `vidslam demo`: simulate the built-in flight, run the full odometry over it, evaluate.

use super::replay::{DepthArg, ReplayArgs, StartArg, run_with};
use crate::runtime::Config;
use crate::sim::{ImuSource, SimConfig, TrajectorySource, generate};
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;

/// Renders the built-in 41 s flight (2 s on the pad with the rotors running, take-off, three
/// figure-eights, landing) with its IMU, then replays it through the full pipeline (rest
/// detection, IMU bootstrap, semidense mapping thread, joint visual-inertial tracking) and prints
/// accuracy against ground truth and timing. Exits non-zero only if the pipeline fails.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Working folder: the dataset goes to OUT/data, the replay's files to OUT/replay.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Simulator seed (scene, textures, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulate only the first S seconds of the flight.
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// TOML configuration for the odometry (see config/vidslam.toml).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    let cfg = match &a.config {
        Some(p) => Config::read(p)?,
        None => Config::default(),
    };
    let data = a.out.join("data");
    println!("1/2 simulating the built-in flight into {}", data.display());
    let mut sim = SimConfig::new(
        data.clone(),
        TrajectorySource::Builtin("demo".into()),
        ImuSource::Synth,
    );
    sim.seed = a.seed;
    sim.seconds = a.seconds;
    sim.force = true;
    sim.progress = !a.quiet;
    generate(&sim).context("simulating the demo flight")?;
    println!(
        "2/2 replaying it through the odometry into {}",
        a.out.join("replay").display()
    );
    let args = ReplayArgs {
        dir: data,
        depth: DepthArg::Semidense,
        start: StartArg::Static,
        realtime: false,
        out: a.out.join("replay"),
        config: a.config.clone(),
        max_seconds: None,
        no_vision: false,
        quiet: a.quiet,
    };
    let started = std::time::Instant::now();
    let report = run_with(&args, &cfg)?;
    let wall_s = started.elapsed().as_secs_f64();
    println!(
        "replay took {wall_s:.1} s of wall time for {:.1} s of data ({:.1}x real time)",
        report.duration_s,
        report.duration_s / wall_s.max(1e-9)
    );
    Ok(())
}
