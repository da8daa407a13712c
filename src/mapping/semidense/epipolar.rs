//! Epipolar geometry of one keyframe pixel seen from one view, in normalised coordinates.
//!
//! A keyframe pixel with normalised ray `r = (x, y, 1)` at inverse depth `ρ` (1/z) is the point
//! `r / ρ` of the keyframe camera; in the view it is `R r / ρ + t`, i.e. up to the positive scale
//! `ρ`, `X(ρ) = a + ρ b` with `a = R r`, `b = t` and `(R, t) = t_view_kf`. Its normalised
//! coordinates `X_xy / X_z` run along a straight line as `ρ` varies (the epipolar line).

use crate::camera::CameraModel;
use nalgebra::{Isometry3, Matrix2, Matrix3, Vector2, Vector3};

/// Smallest accepted homogeneous depth `a_z + ρ b_z` (= ρ·z_view): the point must be in front of
/// the view. Relative to `|a| = |r| ≥ 1`.
const MIN_HOMOGENEOUS_Z: f64 = 1e-6;

/// Relative pose of a view with respect to the keyframe.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ViewGeometry {
    pub r_view_kf: Matrix3<f64>,
    pub t_view_kf: Vector3<f64>,
}

impl ViewGeometry {
    /// `t_view_kf = t_world_view⁻¹ · t_world_kf`.
    pub fn new(t_world_kf: &Isometry3<f64>, t_world_view: &Isometry3<f64>) -> Self {
        let t = t_world_view.inverse() * t_world_kf;
        ViewGeometry {
            r_view_kf: *t.rotation.to_rotation_matrix().matrix(),
            t_view_kf: t.translation.vector,
        }
    }

    /// The epipolar line of the keyframe ray through normalised point `ray` (z = 1).
    #[inline]
    pub fn line(&self, ray: &Vector2<f64>) -> EpipolarLine {
        EpipolarLine {
            a: self.r_view_kf * Vector3::new(ray.x, ray.y, 1.0),
            b: self.t_view_kf,
        }
    }

    /// `d n_view / d n_kf` at constant inverse depth `rho` (the keyframe neighbourhood of `ray` is
    /// taken as a fronto-parallel patch); `None` if the point is not in front of the view.
    pub fn warp_normalised(&self, ray: &Vector2<f64>, rho: f64) -> Option<Matrix2<f64>> {
        let x = self.r_view_kf * Vector3::new(ray.x, ray.y, 1.0) + self.t_view_kf * rho;
        if !(x.z > MIN_HOMOGENEOUS_Z) {
            return None;
        }
        let (iz, nx, ny) = (1.0 / x.z, x.x / x.z, x.y / x.z);
        let r = &self.r_view_kf;
        // (1/z) [1 0 -nx; 0 1 -ny] · R[:, 0..2]
        Some(Matrix2::new(
            iz * (r[(0, 0)] - nx * r[(2, 0)]),
            iz * (r[(0, 1)] - nx * r[(2, 1)]),
            iz * (r[(1, 0)] - ny * r[(2, 0)]),
            iz * (r[(1, 1)] - ny * r[(2, 1)]),
        ))
    }
}

/// `X(ρ) = a + ρ b` (see the module doc).
#[derive(Clone, Copy, Debug)]
pub(crate) struct EpipolarLine {
    pub a: Vector3<f64>,
    pub b: Vector3<f64>,
}

impl EpipolarLine {
    /// Normalised view coordinates of inverse depth `rho`; `None` behind the view.
    #[inline]
    pub fn normalised(&self, rho: f64) -> Option<Vector2<f64>> {
        let x = self.a + self.b * rho;
        (x.z > MIN_HOMOGENEOUS_Z).then(|| Vector2::new(x.x / x.z, x.y / x.z))
    }

    /// Inverse depth whose projection is `n` (least squares over both coordinates, exact on the
    /// line); `None` where `n` is at the epipole.
    #[inline]
    pub fn inv_depth_at(&self, n: &Vector2<f64>) -> Option<f64> {
        // n (a_z + ρ b_z) = a_xy + ρ b_xy  ⇒  ρ (n b_z − b_xy) = a_xy − n a_z
        let c = Vector2::new(n.x * self.b.z - self.b.x, n.y * self.b.z - self.b.y);
        let d = Vector2::new(self.a.x - n.x * self.a.z, self.a.y - n.y * self.a.z);
        let cc = c.norm_squared();
        (cc > 1e-24)
            .then(|| c.dot(&d) / cc)
            .filter(|r| r.is_finite())
    }

    /// `|d n / d ρ|` at inverse depth `rho`: how fast the projection moves along the line,
    /// normalised units per 1/m (pinhole; `None` behind the view). From `n = (a_xy + ρ b_xy) /
    /// (a_z + ρ b_z)`: `d n / d ρ = (b_xy a_z − a_xy b_z) / (a_z + ρ b_z)²`.
    #[inline]
    pub fn normalised_speed(&self, rho: f64) -> Option<f64> {
        let z = self.a.z + self.b.z * rho;
        if !(z > MIN_HOMOGENEOUS_Z) {
            return None;
        }
        let dx = self.b.x * self.a.z - self.a.x * self.b.z;
        let dy = self.b.y * self.a.z - self.a.y * self.b.z;
        Some((dx * dx + dy * dy).sqrt() / (z * z))
    }

    /// `[lo, hi]` shrunk to the inverse depths in front of the view; `None` if none is.
    pub fn front_range(&self, lo: f64, hi: f64) -> Option<(f64, f64)> {
        let (az, bz) = (self.a.z, self.b.z);
        let (mut lo, mut hi) = (lo, hi);
        if bz.abs() < 1e-15 {
            if !(az > MIN_HOMOGENEOUS_Z) {
                return None;
            }
        } else {
            // a_z + ρ b_z ≥ 2·MIN (margin so the ends project)
            let edge = (2.0 * MIN_HOMOGENEOUS_Z - az) / bz;
            if bz > 0.0 {
                lo = lo.max(edge);
            } else {
                hi = hi.min(edge);
            }
        }
        (lo < hi).then_some((lo, hi))
    }
}

/// Normalised coordinates → pixel, with `d pixel / d normalised`.
#[inline]
pub(crate) fn to_pixel(cam: &CameraModel, n: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
    let (xd, jd) = cam.distort(n);
    let u = Vector2::new(cam.fx * xd.x + cam.cx, cam.fy * xd.y + cam.cy);
    let k = Matrix2::new(cam.fx, 0.0, 0.0, cam.fy);
    (u, k * jd)
}

/// Axis-aligned box in normalised coordinates `[x_min, x_max, y_min, y_max]` containing the whole
/// image: segments are clipped to it so that the distortion polynomial is never evaluated far
/// outside the calibrated field of view (where it can fold back into the image). `None` if no
/// border pixel can be unprojected.
pub(crate) fn normalised_footprint(cam: &CameraModel) -> Option<[f64; 4]> {
    let (w, h) = (cam.width, cam.height);
    if w == 0 || h == 0 {
        return None;
    }
    let mut b = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    let mut any = false;
    let mut add = |u: usize, v: usize| {
        if let Some(r) = cam.unproject(&Vector2::new(u as f64, v as f64))
            && r.x.is_finite()
            && r.y.is_finite()
        {
            b = [b[0].min(r.x), b[1].max(r.x), b[2].min(r.y), b[3].max(r.y)];
            any = true;
        }
    };
    for u in 0..w {
        add(u, 0);
        add(u, h - 1);
    }
    for v in 0..h {
        add(0, v);
        add(w - 1, v);
    }
    any.then_some(b)
}

/// Liang–Barsky: the part `[s0, s1]` of `p + s d` inside `bx = [x_min, x_max, y_min, y_max]`.
pub(crate) fn clip_to_box(
    p: &Vector2<f64>,
    d: &Vector2<f64>,
    s0: f64,
    s1: f64,
    bx: &[f64; 4],
) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (s0, s1);
    for (pi, di, mn, mx) in [(p.x, d.x, bx[0], bx[1]), (p.y, d.y, bx[2], bx[3])] {
        if di.abs() < 1e-300 {
            if pi < mn || pi > mx {
                return None;
            }
            continue;
        }
        let (a, b) = ((mn - pi) / di, (mx - pi) / di);
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        lo = lo.max(a);
        hi = hi.min(b);
    }
    (lo < hi).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn pose() -> (Isometry3<f64>, Isometry3<f64>) {
        let kf = Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 1.0),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        );
        let view = Isometry3::from_parts(
            Translation3::new(0.5, -0.1, 0.9),
            UnitQuaternion::from_euler_angles(0.12, -0.15, 0.25),
        );
        (kf, view)
    }

    #[test]
    fn line_matches_projection_and_inverts() {
        let (kf, view) = pose();
        let g = ViewGeometry::new(&kf, &view);
        let ray = Vector2::new(0.2, -0.1);
        let line = g.line(&ray);
        for rho in [0.05, 0.3, 1.0, 2.5] {
            let p_kf = Vector3::new(ray.x, ray.y, 1.0) / rho;
            let p_w = kf * nalgebra::Point3::from(p_kf);
            let p_v = view.inverse_transform_point(&p_w);
            let want = Vector2::new(p_v.x / p_v.z, p_v.y / p_v.z);
            let n = line.normalised(rho).unwrap();
            assert!((n - want).norm() < 1e-12, "{n:?} vs {want:?}");
            let back = line.inv_depth_at(&n).unwrap();
            assert!((back - rho).abs() < 1e-9 * rho.max(1.0), "{back} vs {rho}");
        }
    }

    #[test]
    fn warp_matches_numeric_pixel_mapping() {
        let (kf, view) = pose();
        let g = ViewGeometry::new(&kf, &view);
        let cam = CameraModel::euroc_cam0();
        let rho = 0.6;
        // keyframe pixel -> view pixel at constant inverse depth
        let map = |u: Vector2<f64>| {
            let r = cam.unproject(&u).unwrap();
            let n = g.line(&Vector2::new(r.x, r.y)).normalised(rho).unwrap();
            to_pixel(&cam, &n).0
        };
        let u0 = Vector2::new(300.0, 200.0);
        let r0 = cam.unproject(&u0).unwrap();
        let ray = Vector2::new(r0.x, r0.y);
        let (_, jk) = to_pixel(&cam, &ray);
        let n = g.line(&ray).normalised(rho).unwrap();
        let (_, jv) = to_pixel(&cam, &n);
        let a = jv * g.warp_normalised(&ray, rho).unwrap() * jk.try_inverse().unwrap();
        let h = 1e-3;
        for k in 0..2 {
            let mut d = Vector2::zeros();
            d[k] = h;
            let num = (map(u0 + d) - map(u0 - d)) / (2.0 * h);
            assert!(
                (num - a.column(k)).norm() < 1e-5,
                "{num:?} vs {:?}",
                a.column(k)
            );
        }
    }

    #[test]
    fn front_range_and_clipping() {
        // View 1 m in front of the keyframe looking the same way: points nearer than 1 m behind it.
        let kf = Isometry3::identity();
        let view = Isometry3::translation(0.0, 0.0, 1.0);
        let g = ViewGeometry::new(&kf, &view);
        let line = g.line(&Vector2::new(0.1, 0.0));
        let (lo, hi) = line.front_range(0.1, 5.0).unwrap();
        assert_eq!(lo, 0.1);
        assert!((hi - 1.0).abs() < 1e-5, "{hi}");
        assert!(line.front_range(2.0, 5.0).is_none());
        let bx = [-1.0, 1.0, -0.5, 0.5];
        let (a, b) = clip_to_box(
            &Vector2::new(-2.0, 0.0),
            &Vector2::new(4.0, 0.0),
            0.0,
            1.0,
            &bx,
        )
        .unwrap();
        assert!((a - 0.25).abs() < 1e-12 && (b - 0.75).abs() < 1e-12);
        assert!(
            clip_to_box(
                &Vector2::new(-2.0, 0.6),
                &Vector2::new(4.0, 0.0),
                0.0,
                1.0,
                &bx
            )
            .is_none()
        );
        let fp = normalised_footprint(&CameraModel::euroc_cam0()).unwrap();
        assert!(
            fp[0] < -0.8 && fp[1] > 0.8 && fp[2] < -0.5 && fp[3] > 0.5,
            "{fp:?}"
        );
    }
}
