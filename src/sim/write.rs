//! The sequence generator behind `vidslam sim`: trajectory → spline → IMU, ground truth, scene,
//! rendered frames and depth → an ASL/EuRoC folder.
//!
//! Timing: in synthetic-IMU mode the IMU samples are `t0 + k·Δt` exactly and every camera
//! timestamp is an IMU timestamp (one frame every `round(imu_rate / cam_rate)` samples); with a
//! real IMU file the camera timestamps are the IMU sample times nearest to a `1/cam_rate` grid
//! that starts at the first IMU sample inside the ground-truth span. A frame's timestamp is the
//! middle of its exposure. Ground truth is written at every IMU sample time.

use super::exposure::{AutoExposure, Exposure};
use super::fit::{FitError, FitReport, fit_pose_spline};
use super::flights::{UnknownFlight, builtin_flight};
use super::imu_synth::synthesize_imu;
use super::real_imu::{
    BIAS_WINDOW_S, RealImuError, estimate_biases, estimate_gravity_tilt, read_real_imu,
};
use super::render::{FramePoses, RenderError, Renderer, SAMPLES_PER_PIXEL};
use super::scene::Scene;
use super::spline::PoseSpline;
use crate::dataset::{
    AslWriter, CameraSensor, DEPTH_PNG_UNITS_PER_M, DatasetError, GroundTruth, GroundTruthState,
    ImuSensor, Trajectory, read_imu_yaml,
};
use crate::image::Image;
use crate::imu::ImuNoise;
use crate::time::TimeNs;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Isometry3, Vector3};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Where the motion comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum TrajectorySource {
    /// `builtin:NAME`, see [`super::flights`].
    Builtin(String),
    /// An EuRoC ground-truth CSV or a TUM file.
    File(PathBuf),
}

impl std::str::FromStr for TrajectorySource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.strip_prefix("builtin:") {
            Some("") => Err("empty built-in flight name (try builtin:demo)".into()),
            Some(name) => Ok(TrajectorySource::Builtin(name.into())),
            None => Ok(TrajectorySource::File(s.into())),
        }
    }
}

/// Where the IMU comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum ImuSource {
    /// Synthesised from the spline.
    Synth,
    /// A real EuRoC `imu0/data.csv`, copied byte-identically.
    File(PathBuf),
}

impl std::str::FromStr for ImuSource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(if s == "synth" {
            ImuSource::Synth
        } else {
            ImuSource::File(s.into())
        })
    }
}

/// Everything that defines a simulated sequence.
#[derive(Clone, Debug)]
pub struct SimConfig {
    pub out_dir: PathBuf,
    pub trajectory: TrajectorySource,
    pub imu: ImuSource,
    /// Skip the first `start_s` seconds of the trajectory.
    pub start_s: Option<f64>,
    /// Limit the sequence to `seconds` (after `start_s`).
    pub seconds: Option<f64>,
    pub cam_rate_hz: f64,
    /// Synthetic IMU rate (a real IMU file keeps its own).
    pub imu_rate_hz: f64,
    pub seed: u64,
    pub camera: CameraSensor,
    /// Motion blur, vignetting, auto exposure, image noise, IMU noise/bias/vibration.
    pub realism: bool,
    /// Spline knot spacing, s.
    pub knot_spacing_s: f64,
    pub progress: bool,
    /// Replace an existing `mav0/` in `out_dir`.
    pub force: bool,
}

impl SimConfig {
    /// Defaults of the command line: EuRoC cam0, 20 Hz camera, 200 Hz IMU, seed 1, realism on.
    pub fn new(out_dir: PathBuf, trajectory: TrajectorySource, imu: ImuSource) -> Self {
        SimConfig {
            out_dir,
            trajectory,
            imu,
            start_s: None,
            seconds: None,
            cam_rate_hz: 20.0,
            imu_rate_hz: 200.0,
            seed: 1,
            camera: CameraSensor {
                model: crate::camera::CameraModel::euroc_cam0(),
                t_body_cam: euroc_cam0_t_body_cam(),
                rate_hz: 20.0,
            },
            realism: true,
            knot_spacing_s: 0.05,
            progress: false,
            force: false,
        }
    }
}

/// EuRoC cam0 `T_BS` (V1_01 `cam0/sensor.yaml`).
pub fn euroc_cam0_t_body_cam() -> Isometry3<f64> {
    let m = nalgebra::Matrix4::from_row_slice(&[
        0.0148655429818,
        -0.999880929698,
        0.00414029679422,
        -0.0216401454975, //
        0.999557249008,
        0.0149672133247,
        0.025715529948,
        -0.064676986768, //
        -0.0257744366974,
        0.00375618835797,
        0.999660727178,
        0.00981073058949, //
        0.0,
        0.0,
        0.0,
        1.0,
    ]);
    crate::dataset::isometry_from_matrix(&m).expect("EuRoC T_BS is a rigid transform")
}

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("sim: {0}")]
    Config(String),
    #[error(transparent)]
    Flight(#[from] UnknownFlight),
    #[error(transparent)]
    Fit(#[from] FitError),
    #[error(transparent)]
    RealImu(#[from] RealImuError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> SimError + '_ {
    move |source| SimError::Io {
        path: path.into(),
        source,
    }
}

/// What was written.
#[derive(Clone, Debug, Serialize)]
pub struct SimReport {
    pub out_dir: PathBuf,
    pub frames: usize,
    pub imu_samples: usize,
    pub first_ns: i64,
    pub last_ns: i64,
    pub duration_s: f64,
    pub path_length_m: f64,
    pub camera_rate_hz: f64,
    pub fit: FitReport,
    /// Rotation (about world x, y; rad) applied to level a real-IMU sequence's world frame.
    pub level_tilt_rad: [f64; 2],
    pub quads: usize,
    pub boxes: usize,
    pub panels: usize,
    /// Sub-pixel rays that hit no surface (0 in a closed room).
    pub missed_rays: usize,
    pub render_wall_s: f64,
    pub frames_per_s: f64,
    pub notes: Vec<String>,
}

/// Generates the sequence described by `cfg`.
pub fn generate(cfg: &SimConfig) -> Result<SimReport, SimError> {
    let positive = |x: f64| x.is_finite() && x > 0.0;
    if !positive(cfg.cam_rate_hz) || !positive(cfg.imu_rate_hz) {
        return Err(SimError::Config(format!(
            "rates must be positive (camera {} Hz, IMU {} Hz)",
            cfg.cam_rate_hz, cfg.imu_rate_hz
        )));
    }
    if let Some(s) = cfg.seconds
        && !positive(s)
    {
        return Err(SimError::Config(format!(
            "--seconds must be positive, got {s}"
        )));
    }
    let knot_ns = (cfg.knot_spacing_s * 1e9).round() as i64;
    let mut notes = vec![];

    // --- motion
    let poses = match &cfg.trajectory {
        TrajectorySource::Builtin(name) => builtin_flight(name, &cfg.camera.t_body_cam)?,
        TrajectorySource::File(p) => Trajectory::read(p)?.0,
    };
    let (mut spline, fit) = fit_pose_spline(&poses.poses, knot_ns)?;

    // --- IMU timeline
    let real_rows = match &cfg.imu {
        ImuSource::File(p) => Some(read_real_imu(p)?),
        ImuSource::Synth => None,
    };
    // The spline's last segment may end up to one knot past the last pose: stay within the data.
    let (mut start, mut end) = (
        poses.poses[0].t,
        poses.poses[poses.poses.len() - 1].t.min(spline.end()),
    );
    if let Some(rows) = &real_rows {
        start = start.max(rows[0].sample.t);
        end = end.min(rows[rows.len() - 1].sample.t);
        if end <= start {
            return Err(SimError::Config(format!(
                "the IMU file and the trajectory do not overlap in time (IMU {} .. {}, trajectory {} .. {})",
                rows[0].sample.t,
                rows[rows.len() - 1].sample.t,
                spline.start(),
                spline.end()
            )));
        }
    }
    if let Some(s) = cfg.start_s {
        start = start.add_ns((s * 1e9).round() as i64);
        if start >= end {
            return Err(SimError::Config(format!(
                "--start-s {s} is past the end of the trajectory ({:.3} s long)",
                end.secs_since(spline.start())
            )));
        }
    }
    if let Some(s) = cfg.seconds {
        end = end.min(start.add_ns((s * 1e9).round() as i64));
    }
    let cam_period_ns;
    let imu_times: Vec<TimeNs>;
    let cam_times: Vec<TimeNs>;
    let imu_sensor;
    match &real_rows {
        None => {
            let period_ns = (1e9 / cfg.imu_rate_hz).round() as i64;
            let ratio = (cfg.imu_rate_hz / cfg.cam_rate_hz).round() as i64;
            if ratio < 1 {
                return Err(SimError::Config(format!(
                    "camera rate {} Hz exceeds the IMU rate {} Hz",
                    cfg.cam_rate_hz, cfg.imu_rate_hz
                )));
            }
            cam_period_ns = period_ns * ratio;
            let n = end.ns_since(start) / period_ns;
            imu_times = (0..=n).map(|k| start.add_ns(k * period_ns)).collect();
            cam_times = imu_times.iter().step_by(ratio as usize).copied().collect();
            imu_sensor = ImuSensor {
                noise: ImuNoise::euroc_adis16448(),
                t_body_imu: Isometry3::identity(),
                rate_hz: 1e9 / period_ns as f64,
            };
        }
        Some(rows) => {
            imu_times = rows
                .iter()
                .map(|r| r.sample.t)
                .filter(|t| *t >= start && *t <= end)
                .collect();
            if imu_times.is_empty() {
                return Err(SimError::Config(
                    "no IMU sample inside the ground-truth span".into(),
                ));
            }
            cam_period_ns = (1e9 / cfg.cam_rate_hz).round() as i64;
            let mut cams: Vec<TimeNs> = vec![];
            let mut target = imu_times[0];
            while target <= imu_times[imu_times.len() - 1] {
                let i = imu_times.partition_point(|t| *t < target);
                let cand = [i.checked_sub(1), Some(i)]
                    .into_iter()
                    .flatten()
                    .filter_map(|k| imu_times.get(k))
                    .min_by_key(|t| (t.0 - target.0).abs())
                    .copied()
                    .expect("non-empty");
                if cams.last().is_none_or(|l| cand > *l) {
                    cams.push(cand);
                }
                target = target.add_ns(cam_period_ns);
            }
            cam_times = cams;
            let ImuSource::File(p) = &cfg.imu else {
                unreachable!()
            };
            let yaml = p.with_file_name("sensor.yaml");
            imu_sensor = match read_imu_yaml(&yaml) {
                Ok(s) => s,
                Err(e) => {
                    notes.push(format!("IMU noise model defaults to EuRoC ADIS16448 ({e})"));
                    ImuSensor {
                        noise: ImuNoise::euroc_adis16448(),
                        t_body_imu: Isometry3::identity(),
                        rate_hz: 200.0,
                    }
                }
            };
        }
    }
    if cfg.knot_spacing_s > 0.1 {
        notes.push(format!(
            "knot spacing {} s is coarse: motion faster than ~{:.0} Hz is smoothed",
            cfg.knot_spacing_s,
            0.5 / cfg.knot_spacing_s
        ));
    }

    // --- a real IMU measures the true gravity: level the world frame to it (z up exactly).
    let mut level_tilt_rad = [0.0, 0.0];
    if let Some(rows) = &real_rows {
        let samples: Vec<_> = rows
            .iter()
            .filter(|r| r.sample.t >= start && r.sample.t <= end)
            .map(|r| r.sample)
            .collect();
        for _ in 0..2 {
            match estimate_gravity_tilt(&spline, &samples) {
                Some([tx, ty]) => {
                    let level = Isometry3::rotation(Vector3::new(-tx, -ty, 0.0));
                    spline = spline.left_transformed(&level);
                    level_tilt_rad[0] += tx;
                    level_tilt_rad[1] += ty;
                }
                None => {
                    notes.push(
                        "gravity tilt of the trajectory frame not observable (heading barely \
                         varies): frame left as given"
                            .into(),
                    );
                    break;
                }
            }
        }
        let deg = (level_tilt_rad[0].hypot(level_tilt_rad[1])).to_degrees();
        notes.push(format!(
            "world frame levelled to the real IMU's gravity: the input frame's z axis was {deg:.3}° \
             off vertical (about x {:.4}°, y {:.4}°); ground truth and scene.json are in the \
             levelled frame",
            level_tilt_rad[0].to_degrees(),
            level_tilt_rad[1].to_degrees()
        ));
    }

    // --- output folder
    let mav0 = cfg.out_dir.join("mav0");
    if mav0.exists() {
        if !cfg.force {
            return Err(SimError::Config(format!(
                "{} already exists; use --force to replace it",
                mav0.display()
            )));
        }
        std::fs::remove_dir_all(&mav0).map_err(io_err(&mav0))?;
    }
    std::fs::create_dir_all(&cfg.out_dir).map_err(io_err(&cfg.out_dir))?;

    // --- scene
    let path_pts: Vec<Vector3<f64>> = {
        let n = (end.ns_since(start) / 50_000_000).max(1);
        (0..=n)
            .map(|k| {
                let t = start.add_ns(end.ns_since(start) * k / n);
                (spline.pose(t) * cfg.camera.t_body_cam).translation.vector
            })
            .chain(std::iter::once(spline.pose(start).translation.vector))
            .collect()
    };
    let scene = Scene::build(&path_pts, cfg.seed);
    let scene_path = cfg.out_dir.join("scene.json");
    scene.write_json(&scene_path).map_err(io_err(&scene_path))?;

    // --- IMU and ground truth
    let camera_sensor = CameraSensor {
        rate_hz: 1e9 / cam_period_ns as f64,
        ..cfg.camera.clone()
    };
    let comment = format!(
        "vidslam sim (seed {}, {})",
        cfg.seed,
        if cfg.realism { "realistic" } else { "ideal" }
    );
    let mut writer = AslWriter::create(&cfg.out_dir, &camera_sensor, &imu_sensor, true, &comment)?;
    if cfg.realism {
        // The photometric calibration of the rendered vignetting (a real camera's would come
        // from a calibration sequence).
        let p = cfg.out_dir.join("mav0/cam0/vignette.yaml");
        let v = super::exposure::vignette_model(&camera_sensor.model);
        crate::dataset::write_vignette_yaml(&p, &v, &comment)
            .map_err(|source| DatasetError::Io { path: p, source })?;
    }
    let mut gt = GroundTruth::default();
    let biases: Vec<(Vector3<f64>, Vector3<f64>)> = match &real_rows {
        None => {
            let realism = cfg.realism.then_some((&imu_sensor.noise, cfg.seed));
            let synth = synthesize_imu(&spline, &imu_times, realism);
            for s in &synth {
                writer.write_imu(&s.measured)?;
            }
            synth
                .iter()
                .map(|s| (s.gyro_bias_rad_s, s.accel_bias_m_s2))
                .collect()
        }
        Some(rows) => {
            let in_span: Vec<_> = rows
                .iter()
                .filter(|r| r.sample.t >= start && r.sample.t <= end)
                .collect();
            for r in &in_span {
                writer.write_imu_raw_line(&r.line)?;
            }
            let samples: Vec<_> = in_span.iter().map(|r| r.sample).collect();
            estimate_biases(&spline, &samples, BIAS_WINDOW_S)
        }
    };
    let mut path_length_m = 0.0;
    let mut prev: Option<Vector3<f64>> = None;
    for (t, (bg, ba)) in imu_times.iter().zip(&biases) {
        let st = spline.state(*t);
        let p = st.t_world_body.translation.vector;
        if let Some(q) = prev {
            path_length_m += (p - q).norm();
        }
        prev = Some(p);
        gt.states.push(GroundTruthState {
            t: *t,
            t_world_body: st.t_world_body,
            v_world_m_s: Some(st.v_world_m_s),
            gyro_bias_rad_s: Some(*bg),
            accel_bias_m_s2: Some(*ba),
        });
    }
    writer.write_groundtruth(&gt)?;

    // --- frames
    let renderer = Renderer::new(&scene, &cfg.camera.model)?;
    let bar = if cfg.progress {
        let b = ProgressBar::new(cam_times.len() as u64);
        b.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:40}] {pos}/{len} frames ({per_sec}, eta {eta})",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let exposure_path = mav0.join("cam0/exposure.csv");
    let (tx, rx) = std::sync::mpsc::sync_channel::<(TimeNs, Image<u8>, Image<f32>, Exposure)>(3);
    let writer_thread = std::thread::spawn(move || -> Result<(), SimError> {
        let mut exp_csv = std::io::BufWriter::new(
            std::fs::File::create(&exposure_path).map_err(io_err(&exposure_path))?,
        );
        writeln!(exp_csv, "#timestamp [ns],exposure [s],gain []")
            .map_err(io_err(&exposure_path))?;
        let max_depth = (u16::MAX as f64 / DEPTH_PNG_UNITS_PER_M) as f32;
        for (t, img, mut depth, exp) in rx {
            for d in depth.data_mut() {
                if !(*d > 0.0 && *d <= max_depth) {
                    *d = f32::NAN;
                }
            }
            writer.write_frame(t, &img)?;
            writer.write_depth(t, &depth)?;
            writeln!(exp_csv, "{},{:.9},{:.6}", t.0, exp.exposure_s, exp.gain)
                .map_err(io_err(&exposure_path))?;
        }
        exp_csv.flush().map_err(io_err(&exposure_path))?;
        writer.finish()?;
        Ok(())
    });
    let started = std::time::Instant::now();
    let mut ae = AutoExposure::default();
    let mut missed = 0usize;
    for (k, &t) in cam_times.iter().enumerate() {
        let exposure = if cfg.realism {
            ae.current()
        } else {
            Exposure::ideal()
        };
        let poses = frame_poses(
            &spline,
            &cfg.camera.t_body_cam,
            t,
            cfg.realism.then_some(exposure.exposure_s),
        );
        let f = renderer.render(k as u64, &poses, &exposure, cfg.realism, cfg.seed);
        missed += f.missed_rays;
        if cfg.realism {
            ae.update(f.mean_radiance);
        }
        if tx.send((t, f.image, f.depth_m, exposure)).is_err() {
            break; // the writer failed; its error is reported below
        }
        bar.inc(1);
    }
    drop(tx);
    writer_thread
        .join()
        .map_err(|_| SimError::Config("frame writer thread panicked".into()))??;
    bar.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();
    if missed > 0 {
        notes.push(format!(
            "{missed} rays hit no surface (rendered black, depth none)"
        ));
    }
    let report = SimReport {
        out_dir: cfg.out_dir.clone(),
        frames: cam_times.len(),
        imu_samples: imu_times.len(),
        first_ns: imu_times[0].0,
        last_ns: imu_times[imu_times.len() - 1].0,
        duration_s: imu_times[imu_times.len() - 1].secs_since(imu_times[0]),
        path_length_m,
        camera_rate_hz: camera_sensor.rate_hz,
        fit,
        level_tilt_rad,
        quads: scene.quads.len(),
        boxes: scene.boxes.len(),
        panels: scene.panels.len(),
        missed_rays: missed,
        render_wall_s: wall,
        frames_per_s: cam_times.len() as f64 / wall.max(1e-9),
        notes,
    };
    let rp = cfg.out_dir.join("sim_report.json");
    std::fs::write(
        &rp,
        serde_json::to_string_pretty(&report).expect("serialisable"),
    )
    .map_err(io_err(&rp))?;
    Ok(report)
}

/// Camera poses of the frame at `t`: with an exposure time, the [`SAMPLES_PER_PIXEL`] stratified
/// times `t + ((j + ½)/S - ½)·exposure`; without, all at `t`.
pub fn frame_poses(
    spline: &PoseSpline,
    t_body_cam: &Isometry3<f64>,
    t: TimeNs,
    exposure_s: Option<f64>,
) -> FramePoses {
    let centre = spline.pose(t) * t_body_cam;
    let slots = std::array::from_fn(|j| match exposure_s {
        Some(e) => {
            let off = ((j as f64 + 0.5) / SAMPLES_PER_PIXEL as f64 - 0.5) * e;
            spline.pose(t.add_ns((off * 1e9).round() as i64)) * t_body_cam
        }
        None => centre,
    });
    FramePoses { slots, centre }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sources_parse() {
        assert_eq!(
            "builtin:demo".parse::<TrajectorySource>().unwrap(),
            TrajectorySource::Builtin("demo".into())
        );
        assert!("builtin:".parse::<TrajectorySource>().is_err());
        assert_eq!(
            "a/b.csv".parse::<TrajectorySource>().unwrap(),
            TrajectorySource::File("a/b.csv".into())
        );
        assert_eq!("synth".parse::<ImuSource>().unwrap(), ImuSource::Synth);
    }
}
