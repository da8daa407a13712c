//! Helpers shared by the `vidslam eval` integration tests: seeded noise, perturbation, running the
//! binary.

#![allow(dead_code)] // each test crate uses a subset

use nalgebra::{UnitQuaternion, Vector3};
use std::path::Path;
use std::process::{Command, Output};
use vidslam::dataset::{StampedPose, Trajectory};
use vidslam::eval::Sim3;

/// SplitMix64 with Box-Muller: deterministic Gaussian noise without a dependency.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    }

    /// Standard normal sample.
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    pub fn normal3(&mut self, sigma: f64) -> Vector3<f64> {
        Vector3::new(self.normal(), self.normal(), self.normal()) * sigma
    }
}

/// What [`perturb`] injected, for the checks.
pub struct Injected {
    /// RMS of the position noise vectors actually drawn, m (ground-truth units).
    pub pos_noise_rms_m: f64,
    /// RMS of the rotation noise angles actually drawn, degrees.
    pub rot_noise_rms_deg: f64,
}

/// Estimate = `t_est_gt` applied to (ground truth + noise): each position gets isotropic Gaussian
/// noise of `pos_sigma_m` per axis, each orientation a rotation by a Gaussian rotation vector of
/// `rot_sigma_rad` per axis, then the whole trajectory is mapped by the similarity `t_est_gt`
/// (so the Sim3 taking the estimate back onto the ground truth has scale `1 / t_est_gt.scale`).
pub fn perturb(
    gt: &Trajectory,
    t_est_gt: &Sim3,
    pos_sigma_m: f64,
    rot_sigma_rad: f64,
    seed: u64,
) -> (Trajectory, Injected) {
    let mut rng = Rng::new(seed);
    let (mut sum_p2, mut sum_a2) = (0.0, 0.0);
    let poses = gt
        .poses
        .iter()
        .map(|p| {
            let dp = rng.normal3(pos_sigma_m);
            let dr = UnitQuaternion::from_scaled_axis(rng.normal3(rot_sigma_rad));
            sum_p2 += dp.norm_squared();
            sum_a2 += dr.angle().powi(2);
            let mut noisy = p.t_world_body;
            noisy.translation.vector += dp;
            noisy.rotation *= dr;
            StampedPose {
                t: p.t,
                t_world_body: t_est_gt.transform_pose(&noisy),
            }
        })
        .collect();
    let n = gt.len() as f64;
    let injected = Injected {
        pos_noise_rms_m: (sum_p2 / n).sqrt(),
        rot_noise_rms_deg: (sum_a2 / n).sqrt().to_degrees(),
    };
    (Trajectory::new(poses), injected)
}

/// Runs the `vidslam` binary; panics with its stderr if it fails.
pub fn run_vidslam(args: &[&std::ffi::OsStr]) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_vidslam"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "vidslam {:?} failed: {}",
        args,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Reads a `--json` report as a JSON object.
pub fn read_json(path: &Path) -> serde_json::Map<String, serde_json::Value> {
    let text = std::fs::read_to_string(path).unwrap();
    match serde_json::from_str(&text).unwrap() {
        serde_json::Value::Object(m) => m,
        other => panic!("{}: not a JSON object: {other}", path.display()),
    }
}

/// `key` of a report as a number.
pub fn num(report: &serde_json::Map<String, serde_json::Value>, key: &str) -> f64 {
    report
        .get(key)
        .and_then(serde_json::Value::as_f64)
        .unwrap_or_else(|| panic!("report has no number `{key}`: {report:?}"))
}
