//! `vidslam sim`: render a camera + IMU sequence with ground truth and depth (see [`crate::sim`]).

use crate::dataset::read_camera_yaml;
use crate::sim::{ImuSource, SimConfig, TrajectorySource, generate};
use clap::Args;
use std::path::PathBuf;

/// Writes an ASL/EuRoC dataset (cam0, imu0, ground truth with velocity and biases, depth0) plus
/// `scene.json` and `sim_report.json`, rendered along a built-in flight or a recorded path.
#[derive(Args, Debug)]
pub struct SimArgs {
    /// Output folder (created; `mav0/` inside it must not exist unless --force).
    #[arg(long)]
    pub out: PathBuf,
    /// `builtin:NAME` (available: demo, 41 s) or an EuRoC ground-truth CSV / TUM trajectory file.
    #[arg(long, default_value = "builtin:demo")]
    pub trajectory: TrajectorySource,
    /// `synth` (from the spline, noise per imu0/sensor.yaml) or a real EuRoC imu0/data.csv, whose
    /// rows inside the trajectory's span are copied byte-identically.
    #[arg(long, default_value = "synth")]
    pub imu: ImuSource,
    /// Start S seconds into the trajectory.
    #[arg(long, value_name = "S")]
    pub start_s: Option<f64>,
    /// Keep only S seconds (from the start, or from --start-s).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// Camera rate, Hz (frames fall on IMU sample times).
    #[arg(long, default_value_t = 20.0)]
    pub cam_rate_hz: f64,
    /// Synthetic IMU rate, Hz (ignored with a real IMU file).
    #[arg(long, default_value_t = 200.0)]
    pub imu_rate_hz: f64,
    /// Seed of the scene, textures and noise: the same seed gives the same bytes.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Camera intrinsics, distortion and T_BS from an EuRoC cam0 sensor.yaml (default: EuRoC cam0).
    #[arg(long, value_name = "EUROC_SENSOR_YAML")]
    pub camera: Option<PathBuf>,
    /// Ideal data: no motion blur, vignetting, auto exposure or image noise; noise-free, bias-free IMU.
    #[arg(long)]
    pub no_noise: bool,
    /// Spline knot spacing, s (0.05 follows the 200 Hz Vicon ground truth of EuRoC V1_01 to 0.05 mm RMS).
    #[arg(long, default_value_t = 0.05)]
    pub knot_spacing_s: f64,
    /// Replace an existing dataset in --out.
    #[arg(long)]
    pub force: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(a: SimArgs) -> anyhow::Result<()> {
    let mut cfg = SimConfig::new(a.out, a.trajectory, a.imu);
    if let Some(p) = &a.camera {
        cfg.camera = read_camera_yaml(p)?;
    }
    cfg.start_s = a.start_s;
    cfg.seconds = a.seconds;
    cfg.cam_rate_hz = a.cam_rate_hz;
    cfg.imu_rate_hz = a.imu_rate_hz;
    cfg.seed = a.seed;
    cfg.realism = !a.no_noise;
    cfg.knot_spacing_s = a.knot_spacing_s;
    cfg.force = a.force;
    cfg.progress = !a.quiet;
    let r = generate(&cfg)?;
    println!("dataset       {}", r.out_dir.display());
    println!(
        "frames        {} at {:.2} Hz, {} IMU rows, {:.3} s ({} .. {} ns)",
        r.frames, r.camera_rate_hz, r.imu_samples, r.duration_s, r.first_ns, r.last_ns
    );
    println!("path length   {:.2} m", r.path_length_m);
    println!(
        "spline fit    {} poses, knots {:.3} s: position RMS {:.3} mm (max {:.3} mm), rotation RMS {:.4}° (max {:.4}°)",
        r.fit.samples,
        r.fit.knot_spacing_s,
        r.fit.position_rms_m * 1e3,
        r.fit.position_max_m * 1e3,
        r.fit.rotation_rms_rad.to_degrees(),
        r.fit.rotation_max_rad.to_degrees()
    );
    println!(
        "scene         {} quads ({} boxes, {} panels/posters)",
        r.quads, r.boxes, r.panels
    );
    println!(
        "rendering     {:.1} s, {:.1} frames/s",
        r.render_wall_s, r.frames_per_s
    );
    for n in &r.notes {
        println!("note          {n}");
    }
    Ok(())
}
