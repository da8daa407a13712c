//! `vidslam mavlink play`: streams a trajectory file to a flight controller as MAVLink 2
//! ODOMETRY (or the legacy VISION_* pair), with HEARTBEAT and TIMESYNC — to test an FC setup
//! without the SLAM pipeline.
//!
//! Output samples are taken on a grid `t_k = t_first + k / rate_hz` over the trajectory
//! (interpolated: linear position, SLERP rotation). Velocities are central differences over
//! `±h`, `h = 1 / (2 rate_hz)`, clamped to the trajectory's ends and gaps:
//! `v_world = (p(t_b) - p(t_a)) / (t_b - t_a)`, `omega_body = log(R(t_a)^T R(t_b)) / (t_b - t_a)`.
//! Grid points inside a gap longer than `--max-gap-s` are skipped and the first sample after
//! the gap is a discontinuity (`reset_counter` + 1). Sample k is stamped
//! `host monotonic time at start + (t_k - t_first)`.
//!
//! Testing aids (the "Testing" options): `--discontinuity-at K` marks output sample K as
//! following a discontinuity; `--inject-nan-at K` replaces sample K's x position by NaN, which
//! the sender must drop (it never reaches the wire).

use crate::dataset::{Trajectory, TrajectoryFormat};
use crate::geometry::log_so3;
use crate::output::{
    CovarianceFallback, Endpoint, FcFrames, LocalFrame, MavlinkSender, MessageConfig, MessageSet,
    OdometrySample, SenderConfig, TimeBase,
};
use crate::time::{TimeNs, host_monotonic_now};
use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use nalgebra::{Isometry3, Vector3};
use std::path::PathBuf;

/// MAVLink output to a flight controller.
#[derive(Args, Debug)]
pub struct MavlinkArgs {
    #[command(subcommand)]
    pub command: MavlinkCommand,
}

#[derive(Subcommand, Debug)]
pub enum MavlinkCommand {
    /// Stream a TUM or EuRoC trajectory as MAVLink 2 ODOMETRY (velocities from the trajectory),
    /// with HEARTBEAT (component 197) and TIMESYNC answers, then exit.
    Play(PlayArgs),
}

/// Mounting rotation `r_fcbody_imu` as "roll,pitch,yaw" in degrees (ZYX).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MountRpyDeg(pub [f64; 3]);

impl std::str::FromStr for MountRpyDeg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| {
                x.trim()
                    .parse::<f64>()
                    .map_err(|_| format!("'{x}' is not a number"))
            })
            .collect::<Result<_, _>>()?;
        match v.as_slice() {
            [r, p, y] if v.iter().all(|a| a.is_finite()) => Ok(MountRpyDeg([*r, *p, *y])),
            _ => Err(format!(
                "expected three finite numbers 'roll,pitch,yaw' in degrees, got '{s}'"
            )),
        }
    }
}

#[derive(Args, Debug)]
pub struct PlayArgs {
    /// Trajectory file, TUM (`t_s tx ty tz qx qy qz qw`) or EuRoC CSV (`t_ns,px,py,pz,qw,qx,qy,qz`):
    /// poses t_world_body with the world gravity-aligned z up and body = IMU frame.
    pub trajectory: PathBuf,
    /// Where to send: udpout:HOST:PORT (send there) or udpin:HOST:PORT (listen there, answer
    /// whoever sends to us).
    #[arg(long, default_value = "udpout:127.0.0.1:14550")]
    pub to: Endpoint,
    /// Pace the output in real time (default: as fast as the socket takes it; a receiver may then
    /// drop datagrams its socket buffer cannot hold).
    #[arg(long)]
    pub realtime: bool,
    #[command(flatten)]
    pub output: MavlinkOutputArgs,
    /// Trajectory gaps longer than this are not interpolated across; the stream resumes after
    /// them with reset_counter + 1, s.
    #[arg(long, default_value_t = 0.5)]
    pub max_gap_s: f64,
    /// Treat output sample K (0-based, on the rate_hz grid) as following a discontinuity
    /// (reset_counter + 1). Repeatable or comma-separated.
    #[arg(
        long,
        value_name = "K",
        value_delimiter = ',',
        help_heading = "Testing"
    )]
    pub discontinuity_at: Vec<usize>,
    /// Replace output sample K's x position by NaN, to check that the sender drops it.
    /// Repeatable or comma-separated.
    #[arg(
        long,
        value_name = "K",
        value_delimiter = ',',
        help_heading = "Testing"
    )]
    pub inject_nan_at: Vec<usize>,
}

/// The sender options shared by every command that streams to a flight controller
/// (`mavlink play`; `replay --mavlink` can `#[command(flatten)]` them too).
#[derive(Args, Debug, Clone)]
pub struct MavlinkOutputArgs {
    /// Output rate of the pose messages, Hz (PX4 asks for 30 Hz when covariances are sent).
    #[arg(long, default_value_t = 30.0)]
    pub rate_hz: f64,
    /// MAVLink system id (normally the vehicle's).
    #[arg(long, default_value_t = 1)]
    pub system_id: u8,
    /// MAVLink component id (197 = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY).
    #[arg(long, default_value_t = 197)]
    pub component_id: u8,
    /// ODOMETRY frame_id: frd = MAV_FRAME_LOCAL_FRD (arbitrary heading), ned = MAV_FRAME_LOCAL_NED
    /// (asserts the world x axis points north).
    #[arg(long, value_enum, default_value_t)]
    pub frame: LocalFrame,
    /// odometry = ODOMETRY #331; legacy = VISION_POSITION_ESTIMATE #102 + VISION_SPEED_ESTIMATE #103.
    #[arg(long, value_enum, default_value_t)]
    pub messages: MessageSet,
    /// IMU mounting: rotation from the IMU frame to the vehicle FRD body frame as
    /// "roll,pitch,yaw" degrees (Rz(yaw) Ry(pitch) Rx(roll)). 180,0,0 = IMU x forward, y left, z up.
    #[arg(long, default_value = "180,0,0", allow_hyphen_values = true)]
    pub mount_rpy_deg: MountRpyDeg,
    /// Position standard deviation sent in pose_covariance when the estimator gives none, m
    /// (with --attitude-std-rad; without both the covariance is sent as unknown).
    #[arg(long, requires = "attitude_std_rad")]
    pub position_std_m: Option<f64>,
    /// Attitude standard deviation sent in pose_covariance when the estimator gives none, rad
    /// (with --position-std-m).
    #[arg(long, requires = "position_std_m")]
    pub attitude_std_rad: Option<f64>,
    /// Linear velocity standard deviation sent in velocity_covariance when the estimator gives
    /// none, m/s (with --angular-rate-std-rad-s; without both it is sent as unknown).
    #[arg(long, requires = "angular_rate_std_rad_s")]
    pub velocity_std_m_s: Option<f64>,
    /// Angular rate standard deviation sent in velocity_covariance, rad/s (with --velocity-std-m-s).
    #[arg(long, requires = "velocity_std_m_s")]
    pub angular_rate_std_rad_s: Option<f64>,
    /// Clock of time_usec: companion = host monotonic (PX4 and ArduPilot convert it themselves);
    /// fc = the flight controller's clock from our own TIMESYNC requests, once converged.
    #[arg(long, value_enum, default_value_t)]
    pub time_base: TimeBase,
    /// TIMESYNC replies with a longer round trip are ignored, ms (--time-base fc).
    #[arg(long, default_value_t = 10.0)]
    pub timesync_max_rtt_ms: f64,
}

impl Default for MavlinkOutputArgs {
    /// The command line's defaults (one source: the `#[arg]` attributes above).
    fn default() -> Self {
        #[derive(clap::Parser)]
        struct Defaults {
            #[command(flatten)]
            output: MavlinkOutputArgs,
        }
        <Defaults as clap::Parser>::parse_from(["vidslam"]).output
    }
}

impl MavlinkOutputArgs {
    /// The sender configuration for `endpoint`; errors name the offending flag.
    pub fn sender_config(&self, endpoint: Endpoint) -> anyhow::Result<SenderConfig> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            bail!("--rate-hz must be > 0, got {}", self.rate_hz);
        }
        if !(self.timesync_max_rtt_ms.is_finite() && self.timesync_max_rtt_ms > 0.0) {
            bail!(
                "--timesync-max-rtt-ms must be > 0, got {}",
                self.timesync_max_rtt_ms
            );
        }
        for (flag, v) in [
            ("--position-std-m", self.position_std_m),
            ("--attitude-std-rad", self.attitude_std_rad),
            ("--velocity-std-m-s", self.velocity_std_m_s),
            ("--angular-rate-std-rad-s", self.angular_rate_std_rad_s),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                bail!("{flag} must be finite and >= 0, got {v}");
            }
        }
        let [r, p, y] = self.mount_rpy_deg.0.map(f64::to_radians);
        Ok(SenderConfig {
            system_id: self.system_id,
            component_id: self.component_id,
            messages: MessageConfig {
                frames: FcFrames::from_mount_rpy_rad(r, p, y),
                local_frame: self.frame,
                message_set: self.messages,
                covariance: CovarianceFallback {
                    position_std_m: self.position_std_m,
                    attitude_std_rad: self.attitude_std_rad,
                    velocity_std_m_s: self.velocity_std_m_s,
                    angular_rate_std_rad_s: self.angular_rate_std_rad_s,
                },
            },
            rate_hz: self.rate_hz,
            time_base: self.time_base,
            timesync_max_rtt_ns: (self.timesync_max_rtt_ms * 1e6).round() as i64,
            ..SenderConfig::new(endpoint)
        })
    }
}

/// One playback sample before stamping, `index` on the output grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaybackSample {
    pub index: usize,
    /// Since the first trajectory pose.
    pub t_rel_ns: i64,
    pub t_world_body: Isometry3<f64>,
    pub v_world_m_s: Vector3<f64>,
    pub omega_body_rad_s: Vector3<f64>,
    /// First sample after a gap.
    pub after_gap: bool,
}

/// The samples `mavlink play` sends: see the module docs for the grid and the differences.
pub fn playback_samples(traj: &Trajectory, rate_hz: f64, max_gap_ns: i64) -> Vec<PlaybackSample> {
    let Some((t_first, t_last)) = traj.span() else {
        return Vec::new();
    };
    let period_ns = (1e9 / rate_hz).round().max(1.0) as i64;
    let half_ns = (period_ns / 2).max(1);
    let mut out = Vec::new();
    let mut gap = false;
    let mut k = 0usize;
    loop {
        let t = t_first.add_ns(k as i64 * period_ns);
        if t > t_last {
            break;
        }
        let Some(pose) = traj.interpolate(t, max_gap_ns) else {
            gap = true;
            k += 1;
            continue;
        };
        let side = |dt_ns: i64| {
            let ts = TimeNs((t.0 + dt_ns).clamp(t_first.0, t_last.0));
            traj.interpolate(ts, max_gap_ns)
                .map_or((t, pose), |p| (ts, p))
        };
        let ((ta, pa), (tb, pb)) = (side(-half_ns), side(half_ns));
        let dt_s = tb.secs_since(ta);
        let (v, w) = if dt_s > 0.0 {
            let dr = (pa.rotation.inverse() * pb.rotation)
                .to_rotation_matrix()
                .into_inner();
            (
                (pb.translation.vector - pa.translation.vector) / dt_s,
                log_so3(&dr) / dt_s,
            )
        } else {
            (Vector3::zeros(), Vector3::zeros())
        };
        out.push(PlaybackSample {
            index: k,
            t_rel_ns: t.ns_since(t_first),
            t_world_body: pose,
            v_world_m_s: v,
            omega_body_rad_s: w,
            after_gap: std::mem::take(&mut gap) && !out.is_empty(),
        });
        k += 1;
    }
    out
}

/// Runs `vidslam mavlink ...`.
pub fn run(args: MavlinkArgs) -> anyhow::Result<()> {
    match args.command {
        MavlinkCommand::Play(a) => play(&a),
    }
}

fn play(a: &PlayArgs) -> anyhow::Result<()> {
    if !(a.max_gap_s.is_finite() && a.max_gap_s > 0.0) {
        bail!("--max-gap-s must be > 0, got {}", a.max_gap_s);
    }
    let config = a.output.sender_config(a.to.clone())?;
    let (traj, format) = Trajectory::read(&a.trajectory)?;
    let samples = playback_samples(&traj, config.rate_hz, (a.max_gap_s * 1e9).round() as i64);
    let sender = MavlinkSender::start(config)
        .with_context(|| format!("starting the MAVLink sender towards {}", a.to))?;
    let fmt = match format {
        TrajectoryFormat::Tum => "TUM",
        TrajectoryFormat::EurocCsv => "EuRoC CSV",
    };
    eprintln!(
        "mavlink play: {} ({fmt}, {} poses) -> {} samples at {} Hz to {} from {}",
        a.trajectory.display(),
        traj.len(),
        samples.len(),
        a.output.rate_hz,
        a.to,
        sender
            .local_addr()
            .map_or_else(|e| e.to_string(), |s| s.to_string()),
    );
    let t_host0 = host_monotonic_now();
    let mut epoch = 0u32;
    for ps in &samples {
        if ps.after_gap || a.discontinuity_at.contains(&ps.index) {
            epoch += 1;
        }
        let mut s = OdometrySample::new(
            t_host0.add_ns(ps.t_rel_ns),
            ps.t_world_body,
            ps.v_world_m_s,
            ps.omega_body_rad_s,
        );
        s.reset_epoch = epoch;
        if a.inject_nan_at.contains(&ps.index) {
            s.t_world_body.translation.vector.x = f64::NAN;
        }
        if a.realtime {
            let wait_ns = s.t.ns_since(host_monotonic_now());
            if wait_ns > 0 {
                std::thread::sleep(std::time::Duration::from_nanos(wait_ns as u64));
            }
            sender.push(s);
        } else {
            sender.push_blocking(s);
        }
    }
    finish_sender(sender, "mavlink play", &a.to, !samples.is_empty())
}

/// Stops `sender` and prints what it sent (and its last send error) after `label`; an error if
/// samples were pushed (`pushed_any`) but no pose message reached `to`.
pub fn finish_sender(
    sender: MavlinkSender,
    label: &str,
    to: &Endpoint,
    pushed_any: bool,
) -> anyhow::Result<()> {
    let last_error = sender.last_send_error();
    let stats = sender.finish();
    eprintln!("{label}: {}", stats.summary());
    if let Some(e) = last_error {
        eprintln!("{label}: last send error: {e}");
    }
    if pushed_any && stats.pose_samples_sent == 0 {
        bail!(
            "no pose message could be sent to {to} ({} without a peer, {} send errors)",
            stats.not_sent_no_peer,
            stats.send_errors
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::StampedPose;
    use nalgebra::UnitQuaternion;

    #[test]
    fn the_output_defaults_are_the_command_lines() {
        let d = MavlinkOutputArgs::default();
        assert_eq!((d.rate_hz, d.system_id, d.component_id), (30.0, 1, 197));
        assert_eq!(d.mount_rpy_deg, MountRpyDeg([180.0, 0.0, 0.0]));
        assert!(d.position_std_m.is_none());
        assert!(
            d.sender_config("udpout:127.0.0.1:14550".parse().unwrap())
                .is_ok()
        );
    }

    /// Constant velocity (1, 2, 0) m/s and constant yaw rate 0.5 rad/s, 100 Hz, 1 s.
    fn constant_twist(gap_after: Option<usize>) -> Trajectory {
        let poses = (0..=100)
            .filter(|&i| gap_after.is_none_or(|g| i <= g || i > g + 60))
            .map(|i| {
                let t_s = i as f64 * 0.01;
                StampedPose {
                    t: TimeNs(1_000_000_000 + i as i64 * 10_000_000),
                    t_world_body: Isometry3::from_parts(
                        Vector3::new(t_s, 2.0 * t_s, 1.0).into(),
                        UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.5 * t_s)),
                    ),
                }
            })
            .collect();
        Trajectory::new(poses)
    }

    #[test]
    fn grid_and_finite_differences_recover_a_constant_twist() {
        let s = playback_samples(&constant_twist(None), 25.0, 500_000_000);
        assert_eq!(s.len(), 26); // 0, 40, ..., 1000 ms
        assert_eq!(s[25].t_rel_ns, 1_000_000_000);
        for p in &s {
            assert!(
                (p.v_world_m_s - Vector3::new(1.0, 2.0, 0.0)).norm() < 1e-9,
                "{p:?}"
            );
            assert!(
                (p.omega_body_rad_s - Vector3::new(0.0, 0.0, 0.5)).norm() < 1e-9,
                "{p:?}"
            );
            assert!(!p.after_gap);
        }
    }

    #[test]
    fn gaps_are_skipped_and_flagged() {
        // Poses 31..=90 missing: a 0.61 s gap from 0.30 s to 0.91 s.
        let s = playback_samples(&constant_twist(Some(30)), 25.0, 500_000_000);
        let idx: Vec<usize> = s.iter().map(|p| p.index).collect();
        assert!(idx.contains(&7) && !idx.contains(&8) && !idx.contains(&22) && idx.contains(&23));
        let flagged: Vec<usize> = s.iter().filter(|p| p.after_gap).map(|p| p.index).collect();
        assert_eq!(flagged, vec![23]);
        // Differences never straddle the gap.
        for p in &s {
            assert!(
                (p.v_world_m_s - Vector3::new(1.0, 2.0, 0.0)).norm() < 1e-9,
                "{p:?}"
            );
        }
    }

    #[test]
    fn mount_parses_degrees_and_rejects_garbage() {
        assert_eq!(
            "180,0,-90".parse::<MountRpyDeg>().unwrap(),
            MountRpyDeg([180.0, 0.0, -90.0])
        );
        assert!("1,2".parse::<MountRpyDeg>().unwrap_err().contains("three"));
        assert!("a,2,3".parse::<MountRpyDeg>().unwrap_err().contains("'a'"));
    }
}
