//! Visual-inertial alignment of the first map's scale after a static start.
//!
//! The paper's bootstrap takes the first map's metric scale from an IMU-measured baseline (section
//! IV): the frames of the take-off are posed by integrating the IMU from the rest state (eq. 1–3
//! with `v = 0`), and the first keyframe's depths are triangulated from them. That dead reckoning
//! is only as good as the rest state: a vehicle shaking on its pad is not at rest to 1 cm/s, and
//! the rest tilt is only as good as the attitude averaged over the rest (0.1–0.3° on the EuRoC
//! V1_01 pad, 0.02–0.05 m/s² of horizontal acceleration). On a take-off that covers 5–20 cm
//! before the first map is tracked, 1–2 cm of dead-reckoning error is a 6–16 % scale error.
//!
//! Once the first map is tracked, the frames' positions are known up to that map's scale `s`,
//! and the IMU integrated from rest tells the same displacements up to the unknown initial
//! velocity `v₀` and a constant world-frame acceleration error `δa` (the rest tilt and the
//! accelerometer bias along gravity, which cannot be told apart while the attitude stays near the
//! rest attitude). For every tracked frame `k`, `Δt_k` after the rest state,
//!
//! ```text
//! s · (p̂_k − p₀)  =  d_k + v₀ Δt_k + ½ δa Δt_k²
//! ```
//!
//! where `p̂_k` is the tracked position and `d_k` the displacement integrated from rest with
//! `v₀ = 0` (eq. 3's `Δp` rotated into the world plus `½ g Δt²`). The unknowns `x = [s, v₀, δa]`
//! enter linearly; zero-mean priors on `v₀` and `δa` keep them bounded when the motion is too
//! short to separate them from the scale. This is the linear alignment of VINS-Mono and ORB-SLAM3
//! specialised to a start from rest: the initial velocity is *nearly* known, so a fraction of a
//! second of tracking suffices.

use nalgebra::{SMatrix, SVector, Vector3};

/// One tracked frame of the take-off.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlignmentSample {
    /// Time since the rest state, s.
    pub dt_s: f64,
    /// Tracked body position minus the rest position, in the first map's scale, m.
    pub tracked_m: Vector3<f64>,
    /// The same displacement integrated from rest with zero initial velocity, m.
    pub dead_reckoned_m: Vector3<f64>,
}

/// Standard deviations of the alignment's priors and measurements.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlignmentPrior {
    /// Initial velocity, m/s.
    pub velocity_std_m_s: f64,
    /// World-frame acceleration error of the dead reckoning, m/s².
    pub accel_std_m_s2: f64,
    /// Noise of one tracked position against the integrated one, m.
    pub position_std_m: f64,
}

/// The alignment's solution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleAlignment {
    /// Factor from the first map's scale to metres (`true = scale · tracked`).
    pub scale: f64,
    /// Standard deviation of `scale` from the normal equations.
    pub scale_std: f64,
    /// Velocity at the rest state, m/s (world).
    pub v0_m_s: Vector3<f64>,
    /// World-frame acceleration missing from the dead reckoning, m/s².
    pub accel_m_s2: Vector3<f64>,
    /// RMS of the position residuals at the solution, m.
    pub rms_m: f64,
}

/// Solves for `[s, v₀, δa]` by least squares with the priors; `None` with fewer than two samples
/// or a degenerate system (no displacement to scale).
pub fn align_scale(samples: &[AlignmentSample], prior: &AlignmentPrior) -> Option<ScaleAlignment> {
    if samples.len() < 2 {
        return None;
    }
    let w = 1.0 / prior.position_std_m.powi(2);
    let mut h = SMatrix::<f64, 7, 7>::zeros();
    let mut b = SVector::<f64, 7>::zeros();
    for s in samples {
        // Row i of  J x = y  with J = [p̂ | −Δt I | −½Δt² I], y = d.
        for i in 0..3 {
            let mut j = SVector::<f64, 7>::zeros();
            j[0] = s.tracked_m[i];
            j[1 + i] = -s.dt_s;
            j[4 + i] = -0.5 * s.dt_s * s.dt_s;
            h += j * j.transpose() * w;
            b += j * (s.dead_reckoned_m[i] * w);
        }
    }
    for i in 0..3 {
        h[(1 + i, 1 + i)] += 1.0 / prior.velocity_std_m_s.powi(2);
        h[(4 + i, 4 + i)] += 1.0 / prior.accel_std_m_s2.powi(2);
    }
    // The scale alone must be observed: some displacement was tracked.
    if h[(0, 0)] * prior.position_std_m.powi(2) < 1e-6 {
        return None;
    }
    let chol = h.cholesky()?;
    let x = chol.solve(&b);
    let cov = chol.inverse();
    let mut sq = 0.0;
    for s in samples {
        let v0 = Vector3::new(x[1], x[2], x[3]);
        let a = Vector3::new(x[4], x[5], x[6]);
        let r = s.tracked_m * x[0] - v0 * s.dt_s - a * (0.5 * s.dt_s * s.dt_s) - s.dead_reckoned_m;
        sq += r.norm_squared();
    }
    let out = ScaleAlignment {
        scale: x[0],
        scale_std: cov[(0, 0)].max(0.0).sqrt(),
        v0_m_s: Vector3::new(x[1], x[2], x[3]),
        accel_m_s2: Vector3::new(x[4], x[5], x[6]),
        rms_m: (sq / (3 * samples.len()) as f64).sqrt(),
    };
    (out.scale.is_finite() && out.scale > 0.0).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A take-off: rest, then a smooth climb and a forward push.
    fn truth(t: f64) -> Vector3<f64> {
        Vector3::new(0.3 * t * t * t, 0.05 * t * t, 0.4 * t * t - 0.1 * t * t * t)
    }

    fn samples(scale: f64, v0: Vector3<f64>, da: Vector3<f64>, n: usize) -> Vec<AlignmentSample> {
        (1..=n)
            .map(|k| {
                let t = 0.3 + 0.05 * k as f64;
                let p = truth(t);
                AlignmentSample {
                    dt_s: t,
                    tracked_m: p / scale,
                    // Dead reckoning misses the initial velocity and the acceleration error.
                    dead_reckoned_m: p - v0 * t - da * (0.5 * t * t),
                }
            })
            .collect()
    }

    const PRIOR: AlignmentPrior = AlignmentPrior {
        velocity_std_m_s: 0.05,
        accel_std_m_s2: 0.2,
        position_std_m: 0.002,
    };

    #[test]
    fn recovers_scale_initial_velocity_and_acceleration_error() {
        let v0 = Vector3::new(0.012, -0.008, 0.005);
        let da = Vector3::new(0.03, -0.02, 0.01);
        let a = align_scale(&samples(1.12, v0, da, 14), &PRIOR).unwrap();
        assert!((a.scale - 1.12).abs() < 2e-3, "{a:?}");
        assert!((a.v0_m_s - v0).norm() < 1e-3, "{a:?}");
        assert!((a.accel_m_s2 - da).norm() < 5e-3, "{a:?}");
        assert!(a.rms_m < 1e-4 && a.scale_std > 0.0, "{a:?}");
    }

    #[test]
    fn exact_dead_reckoning_gives_unit_scale() {
        let a = align_scale(
            &samples(1.0, Vector3::zeros(), Vector3::zeros(), 10),
            &PRIOR,
        )
        .unwrap();
        assert!((a.scale - 1.0).abs() < 1e-9);
        assert!(a.v0_m_s.norm() < 1e-9 && a.accel_m_s2.norm() < 1e-9);
    }

    #[test]
    fn degenerate_input_is_refused() {
        assert!(align_scale(&[], &PRIOR).is_none());
        let still: Vec<_> = (1..5)
            .map(|k| AlignmentSample {
                dt_s: 0.1 * k as f64,
                tracked_m: Vector3::zeros(),
                dead_reckoned_m: Vector3::zeros(),
            })
            .collect();
        assert!(align_scale(&still, &PRIOR).is_none());
    }

    #[test]
    fn noise_moves_the_scale_within_its_reported_std() {
        // Deterministic ±1 mm zig-zag on the tracked positions.
        let mut s = samples(0.9, Vector3::new(0.01, 0.0, 0.0), Vector3::zeros(), 20);
        for (k, x) in s.iter_mut().enumerate() {
            let e = if k % 2 == 0 { 1e-3 } else { -1e-3 };
            x.tracked_m += Vector3::new(e, -e, e);
        }
        let a = align_scale(&s, &PRIOR).unwrap();
        assert!((a.scale - 0.9).abs() < 3.0 * a.scale_std.max(2e-3), "{a:?}");
    }
}
