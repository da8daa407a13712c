//! In-flight observer of the map scale: the tracked trajectory of the last seconds against the
//! IMU integrated along it.
//!
//! A direct odometry tracks against keyframe maps triangulated from its own poses, so the scale of
//! the tracked translation is the scale of the map, and every new map inherits it (propagation,
//! and baselines measured against the previous map). The paper takes the metric scale from the
//! IMU (section IV), but inside the joint tracking problem (eq. 16–22) and the keyframe window the
//! IMU acts over tenths of a second to a few seconds, where the photometric term outweighs it: on
//! S-V101 the window's solved keyframe baselines are within 1 % of the tracked ones while both are
//! 10–15 % off for tens of seconds. Over a longer horizon the accelerations the IMU measures tell
//! the scale directly (the linear visual-inertial alignment of VINS-Mono and ORB-SLAM3, here run
//! continuously in flight).
//!
//! For tracked frames `k = 0..n` with rotations `R_k` and positions `p̂_k`, and the IMU integrated
//! from frame 0 with zero initial velocity along those rotations (`d_k`, eq. 1–3),
//!
//! ```text
//! s · (p̂_k − p̂_0)  =  v₀ t_k + d_k + D_k δb_a + Θ_k δθ
//! ```
//!
//! where `v₀` is the (metric) velocity at frame 0, `δb_a` the error of the accelerometer bias the
//! integration used (body frame) and `δθ` a world-frame rotation error of the attitude (tilt);
//! `D_k`, `Θ_k` are their Jacobians, accumulated along the integration. The unknowns
//! `x = [s, v₀, δb_a, δθ]` enter linearly and are solved by least squares with zero-mean priors on
//! all but `s`. `s` is the factor from the tracked scale to metres.

use super::integration::{Preintegration, gravity_world};
use crate::geometry::hat;
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// One tracked frame of the horizon.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackedPose {
    /// World-from-body rotation.
    pub r_world_body: Matrix3<f64>,
    /// Tracked body position, world, m.
    pub p_world_m: Vector3<f64>,
}

/// The IMU integrated from frame 0 with zero initial velocity, and its Jacobians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeadReckoned {
    /// Time since frame 0, s.
    pub t_s: f64,
    /// Displacement since frame 0, world, m.
    pub d_m: Vector3<f64>,
    /// `∂d / ∂b_a`: how the displacement moves with the accelerometer bias the integration
    /// subtracts (body frame; the true bias is the one used plus `δb_a`), m per m/s².
    pub d_d_ba: Matrix3<f64>,
    /// `∂d / ∂δθ` (world-frame rotation error of the attitude, `R ← Exp(δθ) R`), m/rad.
    pub d_d_theta: Matrix3<f64>,
}

/// Integrates the chain: `intervals[k]` is the preintegration from frame `k` to `k + 1` and
/// `poses[k]` frame `k`'s pose (`poses.len() == intervals.len() + 1`). Returns one entry per frame,
/// starting with frame 0 (zero displacement).
pub fn dead_reckon(poses: &[TrackedPose], intervals: &[Preintegration]) -> Vec<DeadReckoned> {
    let g = gravity_world();
    let mut out = Vec::with_capacity(intervals.len() + 1);
    let mut cur = DeadReckoned {
        t_s: 0.0,
        d_m: Vector3::zeros(),
        d_d_ba: Matrix3::zeros(),
        d_d_theta: Matrix3::zeros(),
    };
    let mut v = Vector3::zeros();
    let mut v_ba = Matrix3::zeros();
    let mut v_theta = Matrix3::zeros();
    out.push(cur);
    for (pre, pose) in intervals.iter().zip(poses) {
        let dt = pre.dt_s();
        let r = pose.r_world_body;
        let rdp = r * pre.delta_p;
        let rdv = r * pre.delta_v;
        // d ← d + v dt + ½ g dt² + R Δp ;  v ← v + g dt + R Δv   (eq. 3, 2 with R_i of the frame)
        cur.d_m += v * dt + 0.5 * g * dt * dt + rdp;
        cur.d_d_ba += v_ba * dt + r * pre.d_p_d_ba;
        // Exp(δθ) R Δp ≈ R Δp − [R Δp]× δθ
        cur.d_d_theta += v_theta * dt - hat(&rdp);
        cur.t_s += dt;
        v += g * dt + rdv;
        v_ba += r * pre.d_v_d_ba;
        v_theta -= hat(&rdv);
        out.push(cur);
    }
    out
}

/// Standard deviations of the priors and of the tracked positions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlightScalePrior {
    /// Velocity at frame 0, m/s (around zero: the tracked velocity is itself in the map's scale).
    pub velocity_std_m_s: f64,
    /// Accelerometer bias error, m/s².
    pub accel_bias_std_m_s2: f64,
    /// World-frame attitude error, rad.
    pub attitude_std_rad: f64,
    /// One tracked position against the integrated one, m.
    pub position_std_m: f64,
}

/// The solution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlightScale {
    /// Factor from the tracked scale to metres (`metric = scale · tracked`).
    pub scale: f64,
    /// Standard deviation of `scale` from the normal equations.
    pub scale_std: f64,
    /// Velocity at frame 0, m/s (world, metric).
    pub v0_m_s: Vector3<f64>,
    /// Accelerometer bias error, m/s² (body).
    pub accel_bias_m_s2: Vector3<f64>,
    /// RMS of the position residuals at the solution, m.
    pub rms_m: f64,
}

const N: usize = 10;

/// Solves for `[s, v₀, δb_a, δθ]`; `None` with fewer than three frames, mismatched inputs or a
/// degenerate system (nothing moved).
pub fn solve_flight_scale(
    poses: &[TrackedPose],
    reckoned: &[DeadReckoned],
    prior: &FlightScalePrior,
) -> Option<FlightScale> {
    if poses.len() < 3 || poses.len() != reckoned.len() {
        return None;
    }
    let w = 1.0 / prior.position_std_m.powi(2);
    let p0 = poses[0].p_world_m;
    let mut h = SMatrix::<f64, N, N>::zeros();
    let mut b = SVector::<f64, N>::zeros();
    let row = |k: usize, i: usize| -> (SVector<f64, N>, f64) {
        let dr = &reckoned[k];
        let mut j = SVector::<f64, N>::zeros();
        j[0] = poses[k].p_world_m[i] - p0[i];
        j[1 + i] = -dr.t_s;
        for c in 0..3 {
            j[4 + c] = -dr.d_d_ba[(i, c)];
            j[7 + c] = -dr.d_d_theta[(i, c)];
        }
        (j, dr.d_m[i])
    };
    for k in 1..poses.len() {
        for i in 0..3 {
            let (j, y) = row(k, i);
            h += w * j * j.transpose();
            b += w * j * y;
        }
    }
    let stds = [
        prior.velocity_std_m_s,
        prior.accel_bias_std_m_s2,
        prior.attitude_std_rad,
    ];
    for (g, s) in stds.iter().enumerate() {
        for c in 0..3 {
            h[(1 + 3 * g + c, 1 + 3 * g + c)] += 1.0 / (s * s);
        }
    }
    let chol = h.cholesky()?;
    let x = chol.solve(&b);
    let cov = chol.inverse();
    if !(x.iter().all(|v| v.is_finite()) && x[0] > 0.0 && cov[(0, 0)] > 0.0) {
        return None;
    }
    let mut sq = 0.0;
    let mut n = 0usize;
    for k in 1..poses.len() {
        for i in 0..3 {
            let (j, y) = row(k, i);
            let r = j.dot(&x) - y;
            sq += r * r;
            n += 1;
        }
    }
    Some(FlightScale {
        scale: x[0],
        scale_std: cov[(0, 0)].sqrt(),
        v0_m_s: Vector3::new(x[1], x[2], x[3]),
        accel_bias_m_s2: Vector3::new(x[4], x[5], x[6]),
        rms_m: (sq / n.max(1) as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::exp_so3;
    use crate::imu::{ImuBias, ImuSample};
    use crate::time::TimeNs;

    const RATE_HZ: f64 = 200.0;
    const FRAME_EVERY: usize = 10;
    const YAW_RAD_S: f64 = 0.6;

    fn tilt() -> Matrix3<f64> {
        exp_so3(&Vector3::new(0.05, -0.03, 0.0))
    }

    /// A figure of accelerations and a yawing, slightly tilted body (the truth).
    fn truth(t: f64) -> (Matrix3<f64>, Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let w = [0.9, 1.3, 0.7];
        let a = [0.8, 0.6, 0.3];
        let p = Vector3::new(
            a[0] * (1.0 - (w[0] * t).cos()),
            a[1] * (w[1] * t).sin(),
            a[2] * (1.0 - (w[2] * t).cos()),
        );
        let v = Vector3::new(
            a[0] * w[0] * (w[0] * t).sin(),
            a[1] * w[1] * (w[1] * t).cos(),
            a[2] * w[2] * (w[2] * t).sin(),
        );
        let acc = Vector3::new(
            a[0] * w[0] * w[0] * (w[0] * t).cos(),
            -a[1] * w[1] * w[1] * (w[1] * t).sin(),
            a[2] * w[2] * w[2] * (w[2] * t).cos(),
        );
        let r = exp_so3(&Vector3::new(0.0, 0.0, YAW_RAD_S * t)) * tilt();
        (r, p, v, acc)
    }

    /// IMU samples of the truth with accelerometer bias `ba` (body).
    fn samples(seconds: f64, ba: Vector3<f64>) -> Vec<ImuSample> {
        let n = (seconds * RATE_HZ) as usize + 2;
        (0..n)
            .map(|i| {
                let t = i as f64 / RATE_HZ;
                let (r, _, _, acc) = truth(t);
                let f = r.transpose() * (acc - gravity_world()) + ba;
                ImuSample {
                    t: TimeNs::from_secs_f64(t),
                    // World-frame yaw rate seen in the (constantly tilted) body frame.
                    gyro_rad_s: tilt().transpose() * Vector3::new(0.0, 0.0, YAW_RAD_S),
                    accel_m_s2: f,
                }
            })
            .collect()
    }

    /// Frames every 50 ms: true rotations, tracked positions `scale_tracked × truth`, and the
    /// preintegrations between them (zero bias estimate).
    fn horizon(
        seconds: f64,
        scale_tracked: f64,
        ba: Vector3<f64>,
    ) -> (Vec<TrackedPose>, Vec<Preintegration>) {
        let imu = samples(seconds, ba);
        let frames = (seconds * RATE_HZ) as usize / FRAME_EVERY;
        let mut poses = Vec::new();
        let mut pres = Vec::new();
        for k in 0..=frames {
            let t = (k * FRAME_EVERY) as f64 / RATE_HZ;
            let (r, p, _, _) = truth(t);
            poses.push(TrackedPose {
                r_world_body: r,
                p_world_m: p * scale_tracked,
            });
            if k < frames {
                let t1 = ((k + 1) * FRAME_EVERY) as f64 / RATE_HZ;
                let mut pre = Preintegration::new(TimeNs::from_secs_f64(t), ImuBias::default());
                pre.integrate(&imu, TimeNs::from_secs_f64(t1), None);
                pres.push(pre);
            }
        }
        (poses, pres)
    }

    fn prior() -> FlightScalePrior {
        FlightScalePrior {
            velocity_std_m_s: 1.0,
            accel_bias_std_m_s2: 0.3,
            attitude_std_rad: 0.05,
            position_std_m: 0.01,
        }
    }

    #[test]
    fn dead_reckoning_follows_the_truth_from_rest_velocity() {
        let (poses, pres) = horizon(4.0, 1.0, Vector3::zeros());
        let d = dead_reckon(&poses, &pres);
        let (_, _, v0, _) = truth(0.0);
        for (k, dr) in d.iter().enumerate() {
            let (_, p, _, _) = truth(dr.t_s);
            let expect = p - poses[0].p_world_m - v0 * dr.t_s;
            assert!(
                (dr.d_m - expect).norm() < 2e-3,
                "frame {k}: {} vs {}",
                dr.d_m,
                expect
            );
        }
    }

    #[test]
    fn jacobians_match_numeric_differentiation() {
        let (poses, pres) = horizon(3.0, 1.0, Vector3::zeros());
        let base = dead_reckon(&poses, &pres);
        let eps = 1e-6;
        for c in 0..3 {
            // Accelerometer bias: the displacement integrated with the bias estimate moved by eps
            // (first-order preintegration correction).
            let mut moved = Vec::new();
            for pre in &pres {
                let mut b = pre.bias;
                b.accel_m_s2[c] += eps;
                let (_, dv, dp) = pre.corrected(&b);
                let mut p2 = pre.clone();
                p2.delta_v = dv;
                p2.delta_p = dp;
                moved.push(p2);
            }
            let d_ba = dead_reckon(&poses, &moved);
            // Attitude: every rotation moved by Exp(eps e_c).
            let mut e = Vector3::zeros();
            e[c] = eps;
            let rot: Vec<TrackedPose> = poses
                .iter()
                .map(|p| TrackedPose {
                    r_world_body: exp_so3(&e) * p.r_world_body,
                    ..*p
                })
                .collect();
            let d_th = dead_reckon(&rot, &pres);
            for k in [5, 30, base.len() - 1] {
                let num_ba = (d_ba[k].d_m - base[k].d_m) / eps;
                let num_th = (d_th[k].d_m - base[k].d_m) / eps;
                let an_ba = base[k].d_d_ba.column(c).into_owned();
                let an_th = base[k].d_d_theta.column(c).into_owned();
                assert!(
                    (num_ba - an_ba).norm() < 1e-4 * an_ba.norm().max(1.0),
                    "bias {c} frame {k}: {num_ba} vs {an_ba}"
                );
                assert!(
                    (num_th - an_th).norm() < 1e-4 * an_th.norm().max(1.0),
                    "attitude {c} frame {k}: {num_th} vs {an_th}"
                );
            }
        }
    }

    #[test]
    fn recovers_the_scale_of_a_mis_scaled_track_with_an_unknown_bias() {
        let ba = Vector3::new(0.05, 0.2, -0.03);
        for scale_tracked in [0.85, 1.0, 1.15] {
            let (poses, pres) = horizon(8.0, scale_tracked, ba);
            let d = dead_reckon(&poses, &pres);
            let s = solve_flight_scale(&poses, &d, &prior()).expect("solvable");
            let want = 1.0 / scale_tracked;
            assert!(
                (s.scale - want).abs() < 0.01,
                "tracked ×{scale_tracked}: scale {} (σ {}), want {want}",
                s.scale,
                s.scale_std
            );
            assert!(s.scale_std < 0.01, "σ {}", s.scale_std);
            let (_, _, v0, _) = truth(0.0);
            assert!((s.v0_m_s - v0).norm() < 0.02, "v0 {} vs {v0}", s.v0_m_s);
        }
    }

    #[test]
    fn a_still_track_gives_no_scale() {
        let poses = vec![
            TrackedPose {
                r_world_body: Matrix3::identity(),
                p_world_m: Vector3::zeros(),
            };
            5
        ];
        let d: Vec<DeadReckoned> = (0..5)
            .map(|k| DeadReckoned {
                t_s: k as f64 * 0.05,
                d_m: Vector3::zeros(),
                d_d_ba: Matrix3::zeros(),
                d_d_theta: Matrix3::zeros(),
            })
            .collect();
        // Singular in s: nothing moved (Cholesky fails or the scale is meaningless, never NaN).
        if let Some(s) = solve_flight_scale(&poses, &d, &prior()) {
            assert!(s.scale.is_finite() && s.scale_std.is_finite());
        }
        assert!(solve_flight_scale(&poses[..2], &d[..2], &prior()).is_none());
    }
}
