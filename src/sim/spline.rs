//! Continuous-time trajectory: a uniform cumulative cubic B-spline on SO(3) x R^3 (the "split"
//! representation of Lovegrove et al. 2013 / Sommer et al. 2020): rotation and position have their
//! own control points and share the knots. Both parts are C2, so angular velocity, angular
//! acceleration, velocity and acceleration are continuous and mutually consistent — what an IMU
//! synthesised from the spline needs.
//!
//! With `u = (t - t0) / dt`, segment `i = floor(u)` and `s = u - i`, the pose uses control points
//! `i..=i+3`:
//!
//! * `R(t) = R_i · Π_{j=1..3} exp(B̃_j(s) · d_{i+j})`, `d_k = log(R_{k-1}ᵀ R_k)`;
//! * `p(t) = p_i + Σ_{j=1..3} B̃_j(s) (p_{i+j} - p_{i+j-1})`,
//!
//! with the cumulative basis `B̃_1 = (5 + 3s - 3s² + s³)/6`, `B̃_2 = (1 + 3s + 3s² - 2s³)/6`,
//! `B̃_3 = s³/6`. Angular velocity and acceleration in the body frame follow the recursion
//! `ω_j = A_jᵀ ω_{j-1} + B̃'_j d_j`, `ω̇_j = A_jᵀ ω̇_{j-1} + B̃''_j d_j + (A_jᵀ ω_{j-1}) × (B̃'_j d_j)`
//! with `A_j = exp(B̃_j d_j)` (Sommer et al. 2020, eq. 7–8 in our notation).
//!
//! Control point `k` is centred on time `t0 + (k - 1) dt`; the spline is defined on
//! `[t0, t0 + (n - 3) dt]` for `n` control points.

use crate::geometry::{exp_so3, log_so3};
use crate::time::TimeNs;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// The full kinematic state at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplineState {
    pub t_world_body: Isometry3<f64>,
    /// Body-origin velocity in the world frame, m/s.
    pub v_world_m_s: Vector3<f64>,
    /// Body-origin acceleration in the world frame (kinematic, without gravity), m/s².
    pub a_world_m_s2: Vector3<f64>,
    /// Angular velocity of the body w.r.t. the world, in body coordinates, rad/s.
    pub omega_body_rad_s: Vector3<f64>,
    /// Angular acceleration in body coordinates, rad/s².
    pub alpha_body_rad_s2: Vector3<f64>,
}

/// A uniform cumulative cubic B-spline pose trajectory (`t_world_body`).
#[derive(Clone, Debug, PartialEq)]
pub struct PoseSpline {
    t0: TimeNs,
    dt_ns: i64,
    rot: Vec<Matrix3<f64>>,
    pos: Vec<Vector3<f64>>,
    /// `delta[k] = log(rot[k-1]ᵀ rot[k])` for `k >= 1` (`delta[0]` unused).
    delta: Vec<Vector3<f64>>,
}

/// Cumulative basis values `B̃_1..3` and their first and second derivatives w.r.t. `s`.
#[inline]
pub(crate) fn cumulative_basis(s: f64) -> ([f64; 3], [f64; 3], [f64; 3]) {
    let (s2, s3) = (s * s, s * s * s);
    (
        [
            (5.0 + 3.0 * s - 3.0 * s2 + s3) / 6.0,
            (1.0 + 3.0 * s + 3.0 * s2 - 2.0 * s3) / 6.0,
            s3 / 6.0,
        ],
        [
            (3.0 - 6.0 * s + 3.0 * s2) / 6.0,
            (3.0 + 6.0 * s - 6.0 * s2) / 6.0,
            0.5 * s2,
        ],
        [s - 1.0, 1.0 - 2.0 * s, s],
    )
}

/// Ordinary (non-cumulative) uniform cubic basis `B_0..3(s)`: weights of control points `i..=i+3`.
#[inline]
pub(crate) fn basis(s: f64) -> [f64; 4] {
    let (c, _, _) = cumulative_basis(s);
    [1.0 - c[0], c[0] - c[1], c[1] - c[2], c[2]]
}

/// Rotation of a segment from its four control rotations (used by the fit's Jacobians too).
#[inline]
pub(crate) fn segment_rotation(r: &[Matrix3<f64>; 4], s: f64) -> Matrix3<f64> {
    let (b, _, _) = cumulative_basis(s);
    let mut out = r[0];
    for j in 1..4 {
        let d = log_so3(&(r[j - 1].transpose() * r[j]));
        out *= exp_so3(&(d * b[j - 1]));
    }
    out
}

impl PoseSpline {
    /// A spline from control points (`rot.len() == pos.len() >= 4`), knot spacing `dt_ns > 0`.
    pub fn new(
        t0: TimeNs,
        dt_ns: i64,
        rot: Vec<UnitQuaternion<f64>>,
        pos: Vec<Vector3<f64>>,
    ) -> Self {
        assert!(dt_ns > 0, "knot spacing must be positive");
        assert!(
            rot.len() == pos.len() && rot.len() >= 4,
            "need >= 4 control points"
        );
        let rot: Vec<Matrix3<f64>> = rot
            .iter()
            .map(|q| *q.to_rotation_matrix().matrix())
            .collect();
        let mut s = PoseSpline {
            t0,
            dt_ns,
            rot,
            pos,
            delta: vec![],
        };
        s.update_deltas();
        s
    }

    fn update_deltas(&mut self) {
        self.delta = (0..self.rot.len())
            .map(|k| {
                if k == 0 {
                    Vector3::zeros()
                } else {
                    log_so3(&(self.rot[k - 1].transpose() * self.rot[k]))
                }
            })
            .collect();
    }

    /// First time covered.
    pub fn start(&self) -> TimeNs {
        self.t0
    }

    /// Last time covered.
    pub fn end(&self) -> TimeNs {
        self.t0.add_ns(self.dt_ns * (self.rot.len() as i64 - 3))
    }

    /// Knot spacing, ns.
    pub fn knot_spacing_ns(&self) -> i64 {
        self.dt_ns
    }

    /// Number of control points.
    pub fn num_control_points(&self) -> usize {
        self.rot.len()
    }

    /// Control point `k`: rotation and position.
    pub fn control_point(&self, k: usize) -> (Matrix3<f64>, Vector3<f64>) {
        (self.rot[k], self.pos[k])
    }

    pub(crate) fn control_points_mut(&mut self) -> (&mut [Matrix3<f64>], &mut [Vector3<f64>]) {
        (&mut self.rot, &mut self.pos)
    }

    /// Must be called after editing rotations through [`Self::control_points_mut`].
    pub(crate) fn refresh(&mut self) {
        self.update_deltas();
    }

    /// Segment index and fraction of `t`, clamped to the defined span.
    pub(crate) fn locate(&self, t: TimeNs) -> (usize, f64) {
        let n_seg = self.rot.len() - 3;
        let dt = t.ns_since(self.t0);
        if dt <= 0 {
            return (0, 0.0);
        }
        let i = (dt / self.dt_ns) as usize;
        if i >= n_seg {
            return (n_seg - 1, 1.0);
        }
        let s = (dt - i as i64 * self.dt_ns) as f64 / self.dt_ns as f64;
        (i, s)
    }

    /// Whether `t` lies in `[start, end]`.
    pub fn contains(&self, t: TimeNs) -> bool {
        t >= self.start() && t <= self.end()
    }

    /// The same motion expressed in another world frame: `t_new_world * t_world_body(t)`.
    pub fn left_transformed(&self, t_new_world: &Isometry3<f64>) -> PoseSpline {
        let r = *t_new_world.rotation.to_rotation_matrix().matrix();
        let mut out = self.clone();
        for (rk, pk) in out.rot.iter_mut().zip(out.pos.iter_mut()) {
            *rk = r * *rk;
            *pk = t_new_world.transform_point(&(*pk).into()).coords;
        }
        out.update_deltas();
        out
    }

    /// Pose `t_world_body` at `t` (clamped to the span).
    pub fn pose(&self, t: TimeNs) -> Isometry3<f64> {
        let (i, s) = self.locate(t);
        let (b, _, _) = cumulative_basis(s);
        let mut r = self.rot[i];
        let mut p = self.pos[i];
        for j in 1..4 {
            r *= exp_so3(&(self.delta[i + j] * b[j - 1]));
            p += (self.pos[i + j] - self.pos[i + j - 1]) * b[j - 1];
        }
        isometry(&r, &p)
    }

    /// The body's navigation state (pose and velocity) at `t` (clamped to the span).
    pub fn nav_state(&self, t: TimeNs) -> crate::imu::NavState {
        let s = self.state(t);
        crate::imu::NavState {
            t,
            r_world_body: s.t_world_body.rotation,
            p_world_m: s.t_world_body.translation.vector,
            v_world_m_s: s.v_world_m_s,
        }
    }

    /// Pose, velocities and accelerations at `t` (clamped to the span).
    pub fn state(&self, t: TimeNs) -> SplineState {
        let (i, s) = self.locate(t);
        let dt_s = self.dt_ns as f64 * 1e-9;
        let (b, db, ddb) = cumulative_basis(s);
        let mut r = self.rot[i];
        let mut p = self.pos[i];
        let (mut v, mut a) = (Vector3::zeros(), Vector3::zeros());
        let (mut w, mut dw) = (Vector3::zeros(), Vector3::zeros());
        for j in 1..4 {
            let d = self.delta[i + j];
            let dp = self.pos[i + j] - self.pos[i + j - 1];
            let (bj, dbj, ddbj) = (b[j - 1], db[j - 1] / dt_s, ddb[j - 1] / (dt_s * dt_s));
            p += dp * bj;
            v += dp * dbj;
            a += dp * ddbj;
            let at = exp_so3(&(d * bj));
            r *= at;
            let att = at.transpose();
            let w_prev_rot = att * w;
            w = w_prev_rot + d * dbj;
            dw = att * dw + d * ddbj + w_prev_rot.cross(&(d * dbj));
        }
        SplineState {
            t_world_body: isometry(&r, &p),
            v_world_m_s: v,
            a_world_m_s2: a,
            omega_body_rad_s: w,
            alpha_body_rad_s2: dw,
        }
    }
}

pub(crate) fn isometry(r: &Matrix3<f64>, p: &Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(*p),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::rng::SimRng;

    fn random_spline(seed: u64) -> PoseSpline {
        let mut rng = SimRng::new(seed);
        let n = 9;
        let mut rot = vec![];
        let mut pos = vec![];
        let mut q = UnitQuaternion::identity();
        for _ in 0..n {
            let d = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.4;
            q *= UnitQuaternion::from_scaled_axis(d);
            rot.push(q);
            pos.push(Vector3::new(rng.normal(), rng.normal(), rng.normal()));
        }
        PoseSpline::new(TimeNs(1_700_000_000_000_000_000), 100_000_000, rot, pos)
    }

    #[test]
    fn basis_sums_to_one_and_cumulative_matches() {
        for s in [0.0, 0.3, 0.77, 1.0] {
            let b = basis(s);
            assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            assert!(b.iter().all(|&x| x >= 0.0));
        }
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let sp = random_spline(1);
        let h_ns = 10_000; // 10 us
        let h = h_ns as f64 * 1e-9;
        for k in 0..40 {
            let t = sp.start().add_ns(k * 14_999_991 + 3_000_000);
            let st = sp.state(t);
            let (sm, sp_) = (sp.state(t.add_ns(-h_ns)), sp.state(t.add_ns(h_ns)));
            let pose = sp.pose(t);
            assert!((pose.translation.vector - st.t_world_body.translation.vector).norm() < 1e-12);
            assert!(pose.rotation.angle_to(&st.t_world_body.rotation) < 1e-12);
            let v_num = (sp_.t_world_body.translation.vector - sm.t_world_body.translation.vector)
                / (2.0 * h);
            assert!((v_num - st.v_world_m_s).norm() < 1e-6, "v at {k}");
            let a_num = (sp_.v_world_m_s - sm.v_world_m_s) / (2.0 * h);
            assert!((a_num - st.a_world_m_s2).norm() < 1e-5, "a at {k}");
            // omega: log(R(t)^T R(t+h)) / h (body frame), central version.
            let rm = sm.t_world_body.rotation.to_rotation_matrix();
            let rp = sp_.t_world_body.rotation.to_rotation_matrix();
            let w_num = log_so3(&(rm.matrix().transpose() * rp.matrix())) / (2.0 * h);
            assert!(
                (w_num - st.omega_body_rad_s).norm() < 1e-5,
                "omega at {k}: {w_num:?} vs {:?}",
                st.omega_body_rad_s
            );
            let dw_num = (sp_.omega_body_rad_s - sm.omega_body_rad_s) / (2.0 * h);
            assert!(
                (dw_num - st.alpha_body_rad_s2).norm() < 1e-4,
                "alpha at {k}: {dw_num:?} vs {:?}",
                st.alpha_body_rad_s2
            );
        }
    }

    #[test]
    fn left_transform_moves_the_whole_trajectory() {
        let sp = random_spline(3);
        let t_nw = Isometry3::new(Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.02, -0.03, 1.0));
        let moved = sp.left_transformed(&t_nw);
        for k in 0..10 {
            let t = sp.start().add_ns(k * 55_000_000);
            let (a, b) = (t_nw * sp.pose(t), moved.pose(t));
            assert!((a.translation.vector - b.translation.vector).norm() < 1e-12);
            assert!(a.rotation.angle_to(&b.rotation) < 1e-12);
            // Body-frame rates do not change.
            let (sa, sb) = (sp.state(t), moved.state(t));
            assert!((sa.omega_body_rad_s - sb.omega_body_rad_s).norm() < 1e-9);
        }
    }

    #[test]
    fn spline_is_c2_across_knots() {
        let sp = random_spline(2);
        for k in 1..5 {
            let t = sp.start().add_ns(k * 100_000_000);
            let (a, b) = (sp.state(t.add_ns(-1)), sp.state(t));
            assert!((a.a_world_m_s2 - b.a_world_m_s2).norm() < 1e-4);
            assert!((a.alpha_body_rad_s2 - b.alpha_body_rad_s2).norm() < 1e-4);
        }
        assert_eq!(sp.end().ns_since(sp.start()), 6 * 100_000_000);
    }
}
