//! `vidslam dataset info DIR`: what an ASL/EuRoC folder holds; `vidslam dataset imu-check DIR`:
//! how far its IMU agrees with its ground truth; `vidslam dataset adjust-check DIR`: how far the
//! keyframe adjustment started at the truth moves the map; `vidslam dataset imu-rewrite DIR --out
//! OUT`: a copy with its IMU turned and de-biased by hand, or with a band of another IMU mixed in.

use crate::dataset::{AslDataset, Event};
use crate::time::TimeNs;
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct DatasetArgs {
    #[command(subcommand)]
    pub command: DatasetCommand,
}

#[derive(Subcommand, Debug)]
pub enum DatasetCommand {
    /// Counts, time spans and rates of the camera, IMU and ground truth of an ASL/EuRoC folder;
    /// streams every row, so it also validates the files (errors name file and line).
    Info {
        /// Dataset folder (containing `mav0/`, or `mav0/` itself).
        dir: PathBuf,
    },
    /// How far the IMU agrees with the ground truth (needs both): the rotation and gyro bias
    /// between the ground truth's body rate and the gyro, and the scale the IMU gives the ground
    /// truth over windows of each horizon (p10/p50/p90; 1 for a consistent IMU) — the best any
    /// odometry can learn about the scale from this IMU, and the gyro's integrated rotation
    /// against the ground truth's over windows of each rotation horizon (p50/p90, and the white
    /// gyro noise density that would explain it) (see `src/eval/imu_consistency.rs`).
    ImuCheck {
        /// Dataset folder (containing `mav0/`, or `mav0/` itself).
        dir: PathBuf,
        /// Window lengths, s (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "4,8,16,32")]
        horizons_s: Vec<f64>,
        /// Ground-truth poses used per second in each window, as tracked frames would be.
        #[arg(long, default_value_t = 20.0)]
        frame_rate_hz: f64,
        /// Span over which the full gyro model compares rates, s (several ground-truth intervals:
        /// one interval's rate is too noisy and shrinks the fitted scale factors).
        #[arg(long, default_value_t = 0.05)]
        gyro_span_s: f64,
        /// Window over which the accelerometer bias implied by the ground truth is solved, s.
        #[arg(long, default_value_t = 2.0)]
        bias_window_s: f64,
        /// Window lengths over which the integrated gyro is compared with the ground truth's
        /// rotation, s (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "0.2,1,4")]
        rotation_horizons_s: Vec<f64>,
    },
    /// The in-flight keyframe adjustment started at the truth (needs ground-truth states and
    /// depth maps: a `vidslam sim` dataset): every N-th frame a keyframe with its points at the
    /// rendered depth, the next frames its views at their true states, depths free. Prints how
    /// far each adjustment moves the map's scale (median inverse depth and last baseline, adjusted
    /// / true; 1 for an unbiased adjustment) — see `src/runtime/adjust_check.rs`.
    AdjustCheck {
        /// Dataset folder (containing `mav0/`, or `mav0/` itself).
        dir: PathBuf,
        /// Settings (TOML, as `vidslam replay --config`): the tracker's and `[keyframe_bundle]`.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Views per keyframe (the frames right after it).
        #[arg(long, default_value_t = 4)]
        views: usize,
        /// A keyframe every this many frames.
        #[arg(long, default_value_t = 10)]
        every_frames: usize,
    },
    /// A copy of the dataset with its IMU put right by hand, to replay the same images with it:
    /// each sample `ω' = Exp(r_g) ω − b_g`, `a' = Exp(r_a) a − b_a` (rotations taking the sensor's
    /// axes to the body frame, as `[gyro_alignment] initial_rotation_deg`; biases in the body
    /// frame). Before that, another dataset's gyro or accelerometer may be mixed in, whole or in
    /// a frequency band of its difference (`--gyro-from`, `--accel-from`, `--mix-band-hz`; see
    /// `src/dataset/imu_mix.rs`). Everything else in `mav0/` is linked, not copied; OUT must be
    /// new or empty (see `src/dataset/imu_rewrite.rs`).
    ImuRewrite {
        /// Dataset folder (containing `mav0/`, or `mav0/` itself).
        dir: PathBuf,
        /// Folder to write (`OUT/mav0/`); must not exist or be empty.
        #[arg(long)]
        out: PathBuf,
        /// Rotation vector turning the gyro's axes onto the body frame, degrees `X,Y,Z`.
        #[arg(long, value_parser = parse_xyz, allow_hyphen_values = true, default_value = "0,0,0")]
        gyro_rotation_deg: Xyz,
        /// Rotation vector turning the accelerometer's axes onto the body frame, degrees `X,Y,Z`.
        #[arg(long, value_parser = parse_xyz, allow_hyphen_values = true, default_value = "0,0,0")]
        accel_rotation_deg: Xyz,
        /// Subtracted from the (turned) angular rate, rad/s `X,Y,Z`.
        #[arg(long, value_parser = parse_xyz, allow_hyphen_values = true, default_value = "0,0,0")]
        gyro_bias_rad_s: Xyz,
        /// Subtracted from the (turned) specific force, m/s² `X,Y,Z`.
        #[arg(long, value_parser = parse_xyz, allow_hyphen_values = true, default_value = "0,0,0")]
        accel_bias_m_s2: Xyz,
        /// Dataset whose gyro is mixed in (each row the donor's nearest in time, within half a
        /// sample period).
        #[arg(long)]
        gyro_from: Option<PathBuf>,
        /// Dataset whose accelerometer is mixed in.
        #[arg(long)]
        accel_from: Option<PathBuf>,
        /// Band of the donor's difference from this dataset that is mixed in, Hz `LO,HI` (`0,inf`:
        /// the donor's readings whole; `0.1,1`: only what differs at 0.1–1 Hz).
        #[arg(long, value_parser = parse_band, default_value = "0,inf")]
        mix_band_hz: [f64; 2],
    },
}

pub fn run(args: DatasetArgs) -> anyhow::Result<()> {
    match args.command {
        DatasetCommand::Info { dir } => info(&dir),
        DatasetCommand::ImuCheck {
            dir,
            horizons_s,
            frame_rate_hz,
            gyro_span_s,
            bias_window_s,
            rotation_horizons_s,
        } => imu_check(
            &dir,
            &horizons_s,
            frame_rate_hz,
            gyro_span_s,
            bias_window_s,
            &rotation_horizons_s,
        ),
        DatasetCommand::AdjustCheck {
            dir,
            config,
            views,
            every_frames,
        } => adjust_check(&dir, config.as_deref(), views, every_frames),
        DatasetCommand::ImuRewrite {
            dir,
            out,
            gyro_rotation_deg,
            accel_rotation_deg,
            gyro_bias_rad_s,
            accel_bias_m_s2,
            gyro_from,
            accel_from,
            mix_band_hz: [lo_hz, hi_hz],
        } => imu_rewrite(
            &dir,
            &out,
            &crate::dataset::ImuRewrite {
                gyro_rotation_rad: gyro_rotation_deg.vector().map(f64::to_radians),
                accel_rotation_rad: accel_rotation_deg.vector().map(f64::to_radians),
                gyro_bias_rad_s: gyro_bias_rad_s.vector(),
                accel_bias_m_s2: accel_bias_m_s2.vector(),
            },
            &crate::dataset::DonorMix {
                gyro_from,
                accel_from,
                lo_hz,
                hi_hz,
            },
        ),
    }
}

/// Three components `X,Y,Z` of a command-line vector.
#[derive(Clone, Copy, Debug)]
pub struct Xyz(pub [f64; 3]);

impl Xyz {
    fn vector(self) -> nalgebra::Vector3<f64> {
        self.0.into()
    }
}

/// The comma-separated numbers of a flag's value; `expected` names its form in the error.
fn parse_numbers(s: &str, expected: &str) -> Result<Vec<f64>, String> {
    s.split(',')
        .map(|c| c.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("'{s}': {e} (expected {expected})"))
}

fn parse_xyz(s: &str) -> Result<Xyz, String> {
    let v = parse_numbers(s, "three numbers X,Y,Z")?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Xyz([x, y, z])),
        _ => Err(format!("'{s}': expected three finite numbers X,Y,Z")),
    }
}

/// A frequency band `LO,HI` in Hz, `0 <= LO < HI` (`HI` may be `inf`).
fn parse_band(s: &str) -> Result<[f64; 2], String> {
    let v = parse_numbers(s, "LO,HI in Hz")?;
    match v[..] {
        [lo, hi] if lo.is_finite() && lo >= 0.0 && hi > lo => Ok([lo, hi]),
        _ => Err(format!(
            "'{s}': expected LO,HI in Hz with 0 <= LO < HI (HI may be inf)"
        )),
    }
}

fn imu_rewrite(
    dir: &std::path::Path,
    out: &std::path::Path,
    rw: &crate::dataset::ImuRewrite,
    mix: &crate::dataset::DonorMix,
) -> anyhow::Result<()> {
    let max_rad = 30f64.to_radians();
    anyhow::ensure!(
        rw.gyro_rotation_rad.norm() <= max_rad && rw.accel_rotation_rad.norm() <= max_rad,
        "a rotation of more than 30° is not a mounting error (sensor axes → body frame, degrees): a frame change belongs in imu0/sensor.yaml"
    );
    anyhow::ensure!(
        mix.gyro_from.is_some()
            || mix.accel_from.is_some()
            || (mix.lo_hz == 0.0 && mix.hi_hz == f64::INFINITY),
        "--mix-band-hz needs --gyro-from or --accel-from (the band is of a donor's difference)"
    );
    let s = crate::dataset::rewrite_dataset(dir, out, rw, mix)?;
    for (sensor, m) in &s.mixed {
        let (name, unit) = match sensor {
            crate::dataset::imu_mix::ImuSensorKind::Gyro => ("gyro", "rad/s"),
            crate::dataset::imu_mix::ImuSensorKind::Accel => ("accelerometer", "m/s²"),
        };
        println!(
            "mixed in the {name} at {}–{} Hz: {} rows matched, {} without a donor row within half a period (kept); band RMS ({:.4}, {:.4}, {:.4}) {unit}",
            mix.lo_hz, mix.hi_hz, m.matched, m.unmatched, m.band_rms.x, m.band_rms.y, m.band_rms.z
        );
    }
    println!(
        "wrote {} ({} IMU rows; linked from {}: {})",
        s.imu_csv.display(),
        s.samples,
        dir.display(),
        s.linked.join(", ")
    );
    Ok(())
}

fn adjust_check(
    dir: &std::path::Path,
    config: Option<&std::path::Path>,
    views: usize,
    every_frames: usize,
) -> anyhow::Result<()> {
    use crate::runtime::adjust_check::{AdjustCheckOptions, adjust_from_truth};
    let ds = AslDataset::open(dir)?;
    let cfg = crate::runtime::Config::read_or_default(config)?;
    let opts = AdjustCheckOptions {
        views,
        every_frames,
    };
    let mut header = true;
    let rows = adjust_from_truth(&ds, &cfg, &opts, |r| {
        if std::mem::take(&mut header) {
            println!(
                "{:>20} {:>6} {:>11} {:>15} {:>14} {:>10} {:>9}",
                "keyframe t [ns]",
                "points",
                "baseline m",
                "inv depth ×",
                "baseline ×",
                "pos err m",
                "rot err °"
            );
        }
        println!(
            "{:>20} {:>6} {:>11.3} {:>15.4} {:>14.4} {:>10.4} {:>9.3}",
            r.t.0,
            r.points,
            r.baseline_m,
            r.inv_depth_ratio,
            r.baseline_ratio,
            r.position_error_m,
            r.rotation_error_rad.to_degrees()
        );
    })?;
    anyhow::ensure!(!rows.is_empty(), "no keyframe could be adjusted");
    let summary = |name: &str, v: Vec<f64>| {
        use crate::eval::stats::{percentile, sorted};
        let v = sorted(v.into_iter().filter(|x| x.is_finite()));
        if v.is_empty() {
            println!("{name:<22} -");
            return;
        }
        println!(
            "{name:<22} p10 {:.4}  p50 {:.4}  p90 {:.4}",
            percentile(&v, 10.0),
            percentile(&v, 50.0),
            percentile(&v, 90.0)
        );
    };
    println!("{} keyframes", rows.len());
    summary(
        "inverse depth ×",
        rows.iter().map(|r| r.inv_depth_ratio).collect(),
    );
    summary(
        "baseline ×",
        rows.iter().map(|r| r.baseline_ratio).collect(),
    );
    Ok(())
}

fn span_line(name: &str, n: usize, first: Option<TimeNs>, last: Option<TimeNs>) {
    match (first, last) {
        (Some(a), Some(b)) if n > 1 => {
            let dur_s = b.secs_since(a);
            println!(
                "{name:<13} {n:>8}   {:>20} .. {:>20}   {dur_s:>8.3} s   {:>8.2} Hz",
                a.0,
                b.0,
                (n - 1) as f64 / dur_s
            );
        }
        _ => println!("{name:<13} {n:>8}"),
    }
}

fn info(dir: &std::path::Path) -> anyhow::Result<()> {
    let ds = AslDataset::open(dir)?;
    let m = &ds.camera.model;
    println!("dataset       {}", ds.mav0().display());
    println!(
        "camera        {}x{} px, fx {:.3} fy {:.3} cx {:.3} cy {:.3}, {:?}, {} Hz nominal",
        m.width, m.height, m.fx, m.fy, m.cx, m.cy, m.distortion, ds.camera.rate_hz
    );
    let n = &ds.imu.noise;
    println!(
        "imu noise     gyro {:.3e} rad/s/√Hz (walk {:.3e}), accel {:.3e} m/s²/√Hz (walk {:.3e}), {} Hz nominal",
        n.gyro_noise_density,
        n.gyro_random_walk,
        n.accel_noise_density,
        n.accel_random_walk,
        ds.imu.rate_hz
    );
    println!(
        "{:<13} {:>8}   {:>20}    {:>20}   {:>10}   {:>11}",
        "stream", "count", "first [ns]", "last [ns]", "span", "rate"
    );
    let (mut nf, mut ni) = (0usize, 0usize);
    let (mut f0, mut f1, mut i0, mut i1) = (None, None, None, None);
    for ev in ds.events()? {
        match ev? {
            Event::Imu(s) => {
                ni += 1;
                i0.get_or_insert(s.t);
                i1 = Some(s.t);
            }
            Event::Frame(f) => {
                nf += 1;
                f0.get_or_insert(f.t);
                f1 = Some(f.t);
            }
        }
    }
    span_line("cam0", nf, f0, f1);
    span_line("imu0", ni, i0, i1);
    match ds.ground_truth()? {
        Some(gt) => {
            let full = gt.states.first().is_some_and(|s| s.v_world_m_s.is_some());
            let name = if full { "groundtruth+" } else { "groundtruth" };
            span_line(
                name,
                gt.states.len(),
                gt.states.first().map(|s| s.t),
                gt.states.last().map(|s| s.t),
            );
            let path_m: f64 = gt
                .states
                .windows(2)
                .map(|w| {
                    (w[1].t_world_body.translation.vector - w[0].t_world_body.translation.vector)
                        .norm()
                })
                .sum();
            println!("path length   {path_m:.2} m (ground truth)");
        }
        None => println!("groundtruth   none"),
    }
    let depth = ds.mav0().join("depth0/data.csv");
    if depth.exists() {
        println!(
            "depth0        present (16-bit PNG, {} units per m)",
            crate::dataset::DEPTH_PNG_UNITS_PER_M
        );
    }
    Ok(())
}

fn imu_check(
    dir: &std::path::Path,
    horizons_s: &[f64],
    frame_rate_hz: f64,
    gyro_span_s: f64,
    bias_window_s: f64,
    rotation_horizons_s: &[f64],
) -> anyhow::Result<()> {
    use crate::eval::imu_consistency::{
        align_gyro, fit_gyro_model, gyro_rotation_spread, implied_accel_bias, imu_scale_spread,
    };
    use crate::runtime::scale_observer::ScaleObserverConfig;
    let ds = AslDataset::open(dir)?;
    let gt = ds.ground_truth()?.ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no ground truth (state_groundtruth_estimate0/data.csv)",
            ds.mav0().display()
        )
    })?;
    let imu: Vec<_> = ds.imu_samples()?.collect::<Result<_, _>>()?;
    println!("dataset       {}", ds.mav0().display());
    let g = align_gyro(&gt.states, &imu).ok_or_else(|| {
        anyhow::anyhow!(
            "too little rotation (or overlap of IMU and ground truth) to align the gyro"
        )
    })?;
    let axis = g.rotation_rad.try_normalize(1e-12).unwrap_or_default();
    println!(
        "gyro vs gt    rotation {:.3} deg about ({:+.3}, {:+.3}, {:+.3}) body, bias ({:+.5}, {:+.5}, {:+.5}) rad/s, residual RMS {:.4} rad/s over {} intervals",
        g.rotation_rad.norm().to_degrees(),
        axis.x,
        axis.y,
        axis.z,
        g.gyro_bias_rad_s.x,
        g.gyro_bias_rad_s.y,
        g.gyro_bias_rad_s.z,
        g.residual_rms_rad_s,
        g.samples
    );
    let model = fit_gyro_model(&gt.states, &imu, gyro_span_s);
    match &model {
        Some(m) => {
            let (e, r, k) = (m.scale_error(), m.rotation_rad(), m.skew_rad());
            println!(
                "gyro model    scale error ({:+.2}, {:+.2}, {:+.2}) %, rotation ({:+.3}, {:+.3}, {:+.3}) deg, non-orthogonality xy/xz/yz ({:+.3}, {:+.3}, {:+.3}) deg, residual RMS {:.4} rad/s over {} spans of {} s",
                100.0 * e.x,
                100.0 * e.y,
                100.0 * e.z,
                r.x.to_degrees(),
                r.y.to_degrees(),
                r.z.to_degrees(),
                k.x.to_degrees(),
                k.y.to_degrees(),
                k.z.to_degrees(),
                m.residual_rms_rad_s,
                m.samples,
                m.span_s
            );
        }
        None => println!(
            "gyro model    not fitted (an axis hardly rotates, or too few spans of {gyro_span_s} s)"
        ),
    }
    match implied_accel_bias(&gt.states, &imu, bias_window_s) {
        Some(b) => println!(
            "accel bias    implied by gt (body, {} windows of {} s): p50 ({:+.3}, {:+.3}, {:+.3}), p10 ({:+.3}, {:+.3}, {:+.3}), p90 ({:+.3}, {:+.3}, {:+.3}) m/s²",
            b.windows,
            b.window_s,
            b.p50_m_s2.x,
            b.p50_m_s2.y,
            b.p50_m_s2.z,
            b.p10_m_s2.x,
            b.p10_m_s2.y,
            b.p10_m_s2.z,
            b.p90_m_s2.x,
            b.p90_m_s2.y,
            b.p90_m_s2.z
        ),
        None => println!("accel bias    no window of {bias_window_s} s"),
    }
    // The in-flight scale observer's alignment, on ground-truth poses.
    let prior = ScaleObserverConfig::default().prior();
    println!(
        "{:<13} {:>8} {:>8} {:>8} {:>8}   accel bias (median, body) m/s²",
        "scale", "windows", "p10", "p50", "p90"
    );
    for &h in horizons_s {
        match imu_scale_spread(
            &gt.states,
            &imu,
            g.gyro_bias_rad_s,
            frame_rate_hz,
            h,
            &prior,
        ) {
            Some(s) => println!(
                "{:<13} {:>8} {:>8.3} {:>8.3} {:>8.3}   ({:+.3}, {:+.3}, {:+.3})",
                format!("{h} s"),
                s.windows,
                s.p10,
                s.p50,
                s.p90,
                s.accel_bias_m_s2.x,
                s.accel_bias_m_s2.y,
                s.accel_bias_m_s2.z
            ),
            None => println!("{:<13} no window of this length", format!("{h} s")),
        }
    }
    // The gyro's rotation against the ground truth's, as the white noise it amounts to: through
    // the rotation fit (what an estimator of a turned gyro can correct) and through the full model.
    let datasheet = ds.imu.noise.gyro_noise_density;
    println!(
        "{:<13} {:>8} {:>8} {:>8} {:>10}   white gyro noise that explains it, rad/s/√Hz (× sensor.yaml)",
        "rotation", "windows", "p50 deg", "p90 deg", "(model)"
    );
    for &h in rotation_horizons_s {
        let turned = gyro_rotation_spread(&gt.states, &imu, &g.r_imu_gt, &g.gyro_bias_rad_s, h);
        let full = model
            .as_ref()
            .and_then(|m| gyro_rotation_spread(&gt.states, &imu, &m.m, &m.gyro_bias_rad_s, h));
        match turned {
            Some(s) => println!(
                "{:<13} {:>8} {:>8.3} {:>8.3} {:>10}   {:.2e} (× {:.1}){}",
                format!("{h} s"),
                s.windows,
                s.p50_deg,
                s.p90_deg,
                full.map_or("-".to_string(), |f| format!("{:.3}", f.p50_deg)),
                s.equivalent_density_rad_s_sqrt_hz,
                s.equivalent_density_rad_s_sqrt_hz / datasheet,
                full.map_or(String::new(), |f| format!(
                    "; through the gyro model {:.2e} (× {:.1})",
                    f.equivalent_density_rad_s_sqrt_hz,
                    f.equivalent_density_rad_s_sqrt_hz / datasheet
                ))
            ),
            None => println!("{:<13} no window of this length", format!("{h} s")),
        }
    }
    Ok(())
}
