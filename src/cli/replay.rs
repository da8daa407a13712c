//! `vidslam replay`: run the odometry over a recorded ASL/EuRoC dataset and evaluate it.

use crate::cli::mavlink::{MavlinkOutputArgs, finish_sender};
use crate::dataset::{AslDataset, Trajectory, TrajectoryFormat};
use crate::eval::imu_consistency::implied_accel_bias;
use crate::eval::plot_report;
use crate::eval::{EvalOptions, evaluate};
use crate::output::{Endpoint, MavlinkSender};
use crate::runtime::fc_sample::fc_sample;
use crate::runtime::map_depth::{keyframe_depth_errors, keyframes_csv};
use crate::runtime::odometry::OdometryFrame;
use crate::runtime::odometry::{adjustments_csv, loop_edge_errors, loop_edge_summary, loops_csv};
use crate::runtime::replay::{FrameObserver, StartMode, replay_observed};
use crate::runtime::replay_files::{frames_csv, hindsight_trajectory, write_ply};
use crate::runtime::scale_observer::imu_scale_csv;
use crate::runtime::true_view_poses::TrueCameraPoses;
use crate::runtime::{Config, DepthSource, ReplayOptions, ReplayReport, trajectory};
use crate::time::{TimeNs, host_monotonic_now};
use anyhow::Context;
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

/// Windows over which report.json's `accel_bias_gt_m_s2` is solved, s.
const IMPLIED_BIAS_WINDOW_S: f64 = 2.0;

/// Runs the odometry over DIR (an ASL/EuRoC folder) and writes OUT/trajectory.tum (body pose in the
/// gravity-aligned world, every frame), OUT/frames.csv (per-frame diagnostics), OUT/report.json (frame counts, tracking time, ATE and
/// scale error against ground truth with SE3 alignment), OUT/trajectory.png, with the
/// semidense mapper OUT/semidense.ply and, with loop closure, OUT/keyframes_graph.tum and
/// OUT/trajectory_hindsight.tum (the keyframes, and the published frames relative to them,
/// where the loop closer's graph places the keyframes at the end: diagnostics of what
/// causality costs, not poses to fly on).
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The dataset folder (containing mav0/).
    pub dir: PathBuf,
    /// Keyframe depth source. `semidense`: the mapping thread (the full odometry). `gt`: the
    /// simulator's ground-truth depth (mav0/depth0) and start state, which measures tracking alone.
    #[arg(long, value_enum, default_value = "semidense")]
    pub depth: DepthArg,
    /// Poses the semidense mapper triangulates each keyframe's views from. `tracked`: the
    /// odometry's (the product). `gt`: a diagnostic — the tracked keyframe pose times the ground
    /// truth's camera motion from the keyframe to the view, so the maps' relative geometry (and
    /// baseline) is exact while tracking, the keyframe window and the adjustment stay the
    /// odometry's; measures what the triangulation poses cost (needs the ground truth).
    #[arg(long, value_enum, default_value = "tracked")]
    pub mapping_poses: MappingPosesArg,
    /// The loop closer's edges. `measured`: each loop's relative pose as PnP measured it on the
    /// old keyframe's map (the product). `gt`: a diagnostic — the loops are found and accepted as
    /// always, then go into the graph with the keyframes' true relative pose (`loops.csv`
    /// `edge_error_m` 0), so the run shows what the loop edges' errors cost (needs the ground
    /// truth and `[loop_closure] enabled`).
    #[arg(long, value_enum, default_value = "measured")]
    pub loop_edges: LoopEdgesArg,
    /// First state of the full odometry: `static` detects the vehicle at rest (the product's
    /// way); `gt` takes the ground truth at the first frame (sequences that start in motion).
    #[arg(long, value_enum, default_value = "static")]
    pub start: StartArg,
    /// Pace frames at their timestamps and never wait for the mapping thread, as on the vehicle
    /// (then not deterministic).
    #[arg(long)]
    pub realtime: bool,
    /// Output folder (created).
    #[arg(long, default_value = "out/replay")]
    pub out: PathBuf,
    /// TOML configuration (see config/vidslam.toml); defaults apply to missing keys.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Replay at most S seconds from the first tracked frame.
    #[arg(long, value_name = "S")]
    pub max_seconds: Option<f64>,
    /// IMU only: propagate with the IMU through the same solver, ignoring the images.
    #[arg(long)]
    pub no_vision: bool,
    /// Cover the lens for DURATION_S from START_S after the first replayed frame (its frames
    /// replaced by black images), to test loss and recovery; repeatable.
    #[arg(long, value_name = "START_S:DURATION_S", value_parser = parse_covered_lens)]
    pub cover_lens: Vec<(f64, f64)>,
    /// After each --cover-lens interval the lens comes free over this long, s: grey levels rise
    /// linearly from black to full (a cap being lifted, the exposure settling).
    #[arg(long, value_name = "SECONDS", default_value_t = 0.0, value_parser = parse_uncover_s)]
    pub uncover_s: f64,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Stream the odometry to a flight controller as it runs, as `vidslam mavlink play` does
    /// (udpout:HOST:PORT or udpin:HOST:PORT): every valid frame's published pose, velocity, rate
    /// and covariance as ODOMETRY #331, `reset_counter` + 1 at every re-initialisation and when
    /// the loop closer's correction has moved the pose beyond `[loop_closure] reset_min_jump_m`,
    /// quality -1 while lost. Offline the frames are
    /// stamped on the host clock from the start at the dataset's pace and sent as fast as the
    /// socket takes them; with --realtime as they come.
    #[arg(long, value_name = "ENDPOINT", help_heading = "MAVLink output")]
    pub mavlink: Option<Endpoint>,
    #[command(flatten, next_help_heading = "MAVLink output")]
    pub mavlink_output: MavlinkOutputArgs,
}

/// `START_S:DURATION_S`, both non-negative seconds.
fn parse_covered_lens(s: &str) -> Result<(f64, f64), String> {
    let (a, d) = s
        .split_once(':')
        .ok_or_else(|| format!("expected START_S:DURATION_S, got {s:?}"))?;
    Ok((seconds(a, "START_S")?, seconds(d, "DURATION_S")?))
}

/// `--uncover-s`: a non-negative number of seconds.
fn parse_uncover_s(s: &str) -> Result<f64, String> {
    seconds(s, "--uncover-s")
}

/// `v` as a non-negative, finite number of seconds; the error names `what`.
fn seconds(v: &str, what: &str) -> Result<f64, String> {
    v.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite() && *x >= 0.0)
        .ok_or_else(|| format!("{what} must be a non-negative number of seconds, got {v:?}"))
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DepthArg {
    /// The semidense mapping thread.
    Semidense,
    /// Ground-truth depth maps of the simulator (mav0/depth0).
    Gt,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MappingPosesArg {
    /// The views' tracked poses.
    Tracked,
    /// The ground truth's motion from the keyframe (diagnostic).
    Gt,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LoopEdgesArg {
    /// Measured by PnP on the old keyframe's map.
    Measured,
    /// The keyframes' true relative pose (diagnostic).
    Gt,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum StartArg {
    Static,
    Gt,
}

pub fn run(a: ReplayArgs) -> anyhow::Result<()> {
    let cfg = Config::read_or_default(a.config.as_deref())?;
    run_with(&a, &cfg).map(|_| ())
}

/// Replays with an already loaded configuration; returns the report.
pub fn run_with(a: &ReplayArgs, cfg: &Config) -> anyhow::Result<ReplayReport> {
    if let Some(s) = a.max_seconds
        && !(s.is_finite() && s > 0.0)
    {
        anyhow::bail!("--max-seconds must be a positive number of seconds, got {s}");
    }
    let mut opts = ReplayOptions {
        tracker: cfg.tracking.clone(),
        mapping: cfg.mapping.clone(),
        static_detector: cfg.static_detector,
        bootstrap: cfg.bootstrap.clone(),
        window: cfg.window.clone(),
        reuse: cfg.reuse.clone(),
        keyframe_bundle: cfg.keyframe_bundle.clone(),
        scale_observer: cfg.scale_observer,
        gyro_alignment: cfg.gyro_alignment.clone(),
        loop_closure: cfg.loop_closure.clone(),
        depth: match a.depth {
            DepthArg::Gt => DepthSource::GroundTruth,
            DepthArg::Semidense => DepthSource::Semidense,
        },
        mapping_true_view_poses: a.mapping_poses == MappingPosesArg::Gt,
        loop_edges_true: a.loop_edges == LoopEdgesArg::Gt,
        start: match a.start {
            StartArg::Static => StartMode::Static,
            StartArg::Gt => StartMode::GroundTruth,
        },
        realtime: a.realtime,
        max_seconds: a.max_seconds,
        covered_lens_s: a.cover_lens.clone(),
        uncover_s: a.uncover_s,
        ..Default::default()
    };
    if a.no_vision {
        opts.tracker.use_vision = false;
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("creating the output folder {}", a.out.display()))?;
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(0);
        b.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:40}] {pos}/{len} frames ({per_sec}, eta {eta})",
            )?
            .progress_chars("=> "),
        );
        b
    };
    let mut fc = a
        .mavlink
        .as_ref()
        .map(|to| FcOutput::start(&a.mavlink_output, to, a.realtime))
        .transpose()?;
    let mut send = |f: &OdometryFrame| {
        if let Some(fc) = fc.as_mut() {
            fc.push(f);
        }
    };
    let out = replay_observed(
        &a.dir,
        &opts,
        &mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
        a.mavlink.is_some().then_some(&mut send as FrameObserver),
    )
    .with_context(|| format!("replaying {}", a.dir.display()))?;
    bar.finish_and_clear();
    if let Some(fc) = fc {
        fc.finish()?;
    }

    let est = trajectory(&out);
    if !out.mapping.keyframe_maps.is_empty() {
        let ply = a.out.join("semidense.ply");
        write_ply(&ply, &out.mapping.world_points())
            .with_context(|| format!("writing {}", ply.display()))?;
    }
    let traj_path = a.out.join("trajectory.tum");
    est.write(&traj_path, TrajectoryFormat::Tum)?;
    let mut report = ReplayReport::new(
        &out,
        opts.tracker.use_vision,
        depth_name(a.depth),
        a.realtime,
    );
    if a.mapping_poses == MappingPosesArg::Gt {
        report.mapping_poses = "gt".into();
    }
    if a.loop_edges == LoopEdgesArg::Gt {
        report.loop_edge_source = "gt".into();
    }
    let ds = AslDataset::open(&a.dir)?;
    let gt = ds.ground_truth()?;
    // The ground truth's poses, built once: for the evaluation and the loops' errors.
    let gt_poses = gt.as_ref().map(|g| g.trajectory());
    if let (Some(gt), Some(gt_poses)) = (&gt, &gt_poses) {
        report.evaluate_against(gt_poses, &est);
        report.set_velocity_errors(gt, &est, &out);
        let imu: Vec<_> = ds.imu_samples()?.collect::<Result<_, _>>()?;
        if let Some(b) = implied_accel_bias(&gt.states, &imu, IMPLIED_BIAS_WINDOW_S) {
            report.set_implied_accel_bias(b.p50_m_s2);
        }
    }
    let depth_rows =
        keyframe_depth_errors(&ds, &out.mapping.keyframe_maps, &out.mapping.keyframe_times)?;
    if !depth_rows.is_empty() {
        report.set_map_depth(&depth_rows);
        let p = a.out.join("keyframes.csv");
        std::fs::write(&p, keyframes_csv(&depth_rows))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if !out.odometry.imu_scale.is_empty() {
        let p = a.out.join("imu_scale.csv");
        std::fs::write(&p, imu_scale_csv(&out.odometry.imu_scale))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if !out.odometry.loop_keyframe_poses.is_empty() {
        let graph = Trajectory::new(out.odometry.loop_keyframe_poses.clone());
        graph.write(&a.out.join("keyframes_graph.tum"), TrajectoryFormat::Tum)?;
        if let Some(gt_poses) = &gt_poses {
            report.graph_keyframe_ate_m = evaluate(gt_poses, &graph, &EvalOptions::default())
                .ok()
                .map(|e| e.ate_rmse_m);
        }
    }
    if let Some(hindsight) = hindsight_trajectory(&out) {
        hindsight.write(
            &a.out.join("trajectory_hindsight.tum"),
            TrajectoryFormat::Tum,
        )?;
        if let Some(gt_poses) = &gt_poses {
            report.hindsight_ate_m = evaluate(gt_poses, &hindsight, &EvalOptions::default())
                .ok()
                .map(|e| e.ate_rmse_m);
        }
    }
    if !out.odometry.loop_closures.is_empty() {
        let loops = &out.odometry.loop_closures;
        let truth = gt_poses.map(|poses| TrueCameraPoses::new(poses, ds.camera.t_body_cam));
        let errors = loop_edge_errors(loops, truth.as_ref());
        report.loop_edges = loop_edge_summary(loops, &errors);
        let p = a.out.join("loops.csv");
        std::fs::write(&p, loops_csv(loops, &errors))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if !out.odometry.adjustments.is_empty() {
        let p = a.out.join("adjustments.csv");
        std::fs::write(&p, adjustments_csv(&out.odometry.adjustments))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if !out.odometry.window_map_log_scales.is_empty() {
        let p = a.out.join("window_scale.csv");
        let mut csv = String::from("t_ns,log_scale\n");
        for (t, l) in &out.odometry.window_map_log_scales {
            csv.push_str(&format!("{},{:.5}\n", t.0, l));
        }
        std::fs::write(&p, csv).with_context(|| format!("writing {}", p.display()))?;
    }
    // Rotation vectors per solve, in degrees (the gyro's turn) and milliradians (the mount's).
    let rotation_histories = [
        (
            "window_gyro_turn.csv",
            &out.odometry.window_gyro_misalignment_history,
            "deg",
            180.0 / std::f64::consts::PI,
            4,
        ),
        (
            "window_mount_rotation.csv",
            &out.odometry.window_mount_rotation_history,
            "mrad",
            1e3,
            3,
        ),
    ];
    for (name, rows, unit, per_rad, decimals) in rotation_histories {
        if !rows.is_empty() {
            let p = a.out.join(name);
            std::fs::write(&p, rotation_history_csv(rows, unit, per_rad, decimals))
                .with_context(|| format!("writing {}", p.display()))?;
        }
    }
    let csv_path = a.out.join("frames.csv");
    std::fs::write(&csv_path, frames_csv(&out))
        .with_context(|| format!("writing {}", csv_path.display()))?;
    let json_path = a.out.join("report.json");
    std::fs::write(&json_path, report.to_json())
        .with_context(|| format!("writing {}", json_path.display()))?;
    if let Some(e) = &report.eval {
        plot_report(e, &a.out.join("trajectory.png")).context("writing trajectory.png")?;
    }
    print!("{}", report.to_table());
    println!("wrote {}, {}", traj_path.display(), json_path.display());
    Ok(report)
}

/// The flight controller's side of a replay (`--mavlink`): the sender, and the host time the
/// first frame is stamped at.
struct FcOutput {
    sender: MavlinkSender,
    realtime: bool,
    /// (first frame's dataset time, host time it is stamped at).
    origin: Option<(TimeNs, TimeNs)>,
    to: Endpoint,
}

impl FcOutput {
    fn start(args: &MavlinkOutputArgs, to: &Endpoint, realtime: bool) -> anyhow::Result<Self> {
        let config = args.sender_config(to.clone())?;
        let sender = MavlinkSender::start(config)
            .with_context(|| format!("starting the MAVLink sender towards {to}"))?;
        Ok(FcOutput {
            sender,
            realtime,
            origin: None,
            to: to.clone(),
        })
    }

    fn push(&mut self, f: &OdometryFrame) {
        let t = f.result.t;
        let (t0, host0) = *self.origin.get_or_insert((t, host_monotonic_now()));
        if let Some(s) = fc_sample(f, host0.add_ns(t.ns_since(t0))) {
            if self.realtime {
                self.sender.push(s);
            } else {
                self.sender.push_blocking(s);
            }
        }
    }

    /// Stops the sender; prints what it sent, and fails if frames were sent to nobody.
    fn finish(self) -> anyhow::Result<()> {
        finish_sender(self.sender, "mavlink", &self.to, self.origin.is_some())
    }
}

/// `t_ns,x_<unit>,y_<unit>,z_<unit>` rows of rotation vectors (rad) times `per_rad`, `decimals`
/// places.
fn rotation_history_csv(
    rows: &[(TimeNs, nalgebra::Vector3<f64>)],
    unit: &str,
    per_rad: f64,
    decimals: usize,
) -> String {
    let mut csv = format!("t_ns,x_{unit},y_{unit},z_{unit}\n");
    for (t, v) in rows {
        let v = v * per_rad;
        csv.push_str(&format!(
            "{},{:.*},{:.*},{:.*}\n",
            t.0, decimals, v.x, decimals, v.y, decimals, v.z
        ));
    }
    csv
}

fn depth_name(d: DepthArg) -> &'static str {
    match d {
        DepthArg::Gt => "gt",
        DepthArg::Semidense => "semidense",
    }
}

#[cfg(test)]
mod tests {
    use super::{parse_covered_lens, parse_uncover_s};

    #[test]
    fn cover_lens_takes_start_and_duration_and_names_what_is_wrong() {
        assert_eq!(parse_covered_lens("15:0.5"), Ok((15.0, 0.5)));
        assert_eq!(parse_covered_lens(" 0 : 2 "), Ok((0.0, 2.0)));
        assert!(
            parse_covered_lens("15")
                .unwrap_err()
                .contains("START_S:DURATION_S")
        );
        assert!(parse_covered_lens("x:1").unwrap_err().contains("START_S"));
        assert!(
            parse_covered_lens("1:-2")
                .unwrap_err()
                .contains("DURATION_S")
        );
        assert!(
            parse_covered_lens("1:nan")
                .unwrap_err()
                .contains("DURATION_S")
        );
        assert_eq!(parse_uncover_s("0.25"), Ok(0.25));
        assert!(parse_uncover_s("-0.1").unwrap_err().contains("--uncover-s"));
    }
}
