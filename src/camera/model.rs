//! The camera model and its Jacobians.

use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};

/// Lens distortion applied to normalised coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Distortion {
    /// Ideal pinhole.
    None,
    /// Radial-tangential (OpenCV plumb bob, 4 parameters), as in EuRoC `radial-tangential`.
    RadTan { k1: f64, k2: f64, p1: f64, p2: f64 },
    /// Equidistant / Kannala-Brandt: `theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)`.
    Equidistant { k1: f64, k2: f64, k3: f64, k4: f64 },
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraModelError {
    #[error("camera model: {0}")]
    Invalid(String),
}

/// Intrinsics + distortion + image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraModel {
    pub width: usize,
    pub height: usize,
    /// Focal lengths, pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point, pixels.
    pub cx: f64,
    pub cy: f64,
    pub distortion: Distortion,
}

/// Points closer than this to the camera plane (m, along z) do not project.
pub const MIN_DEPTH_M: f64 = 1e-6;

impl CameraModel {
    /// Checks that the parameters are usable (finite, positive focal lengths and size).
    pub fn new(
        width: usize,
        height: usize,
        [fx, fy, cx, cy]: [f64; 4],
        distortion: Distortion,
    ) -> Result<Self, CameraModelError> {
        let all = [fx, fy, cx, cy];
        if !all.iter().all(|v| v.is_finite()) || fx <= 0.0 || fy <= 0.0 {
            return Err(CameraModelError::Invalid(format!("bad intrinsics {all:?}")));
        }
        if width == 0 || height == 0 {
            return Err(CameraModelError::Invalid(format!(
                "bad resolution {width}x{height}"
            )));
        }
        let coeffs = match distortion {
            Distortion::None => vec![],
            Distortion::RadTan { k1, k2, p1, p2 } => vec![k1, k2, p1, p2],
            Distortion::Equidistant { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
        };
        if !coeffs.iter().all(|v| v.is_finite()) {
            return Err(CameraModelError::Invalid(format!(
                "bad distortion {coeffs:?}"
            )));
        }
        Ok(CameraModel {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion,
        })
    }

    /// EuRoC cam0 (V1_01 `sensor.yaml`): 752x480, radial-tangential.
    pub fn euroc_cam0() -> Self {
        CameraModel {
            width: 752,
            height: 480,
            fx: 458.654,
            fy: 457.296,
            cx: 367.215,
            cy: 248.375,
            distortion: Distortion::RadTan {
                k1: -0.28340811,
                k2: 0.07395907,
                p1: 0.00019359,
                p2: 1.76187114e-05,
            },
        }
    }

    /// The same camera with distortion removed (for undistorted pipelines and tests).
    pub fn without_distortion(&self) -> Self {
        CameraModel {
            distortion: Distortion::None,
            ..*self
        }
    }

    /// Model for an image pyramid level `level` (each level halves the resolution by 2x2 block
    /// averaging, so the centre of level-l pixel `i` sits at level-0 coordinate `2^l (i + 0.5) - 0.5`).
    pub fn scaled_to_level(&self, level: u32) -> Self {
        let s = 0.5f64.powi(level as i32);
        CameraModel {
            width: self.width >> level,
            height: self.height >> level,
            fx: self.fx * s,
            fy: self.fy * s,
            cx: (self.cx + 0.5) * s - 0.5,
            cy: (self.cy + 0.5) * s - 0.5,
            distortion: self.distortion,
        }
    }

    /// Distorts normalised coordinates, returning the distorted point and d(distorted)/d(normalised).
    pub fn distort(&self, xn: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let (x, y) = (xn.x, xn.y);
        match self.distortion {
            Distortion::None => (*xn, Matrix2::identity()),
            Distortion::RadTan { k1, k2, p1, p2 } => {
                let r2 = x * x + y * y;
                let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
                let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
                let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
                let drad = k1 + 2.0 * k2 * r2; // d radial / d r2
                let dxd_dx = radial + x * drad * 2.0 * x + 2.0 * p1 * y + p2 * 6.0 * x;
                let dxd_dy = x * drad * 2.0 * y + 2.0 * p1 * x + p2 * 2.0 * y;
                let dyd_dx = y * drad * 2.0 * x + p1 * 2.0 * x + 2.0 * p2 * y;
                let dyd_dy = radial + y * drad * 2.0 * y + p1 * 6.0 * y + 2.0 * p2 * x;
                (
                    Vector2::new(xd, yd),
                    Matrix2::new(dxd_dx, dxd_dy, dyd_dx, dyd_dy),
                )
            }
            Distortion::Equidistant { k1, k2, k3, k4 } => {
                let r2 = x * x + y * y;
                if r2 < 1e-16 {
                    return (*xn, Matrix2::identity());
                }
                let r = r2.sqrt();
                let th = r.atan();
                let t2 = th * th;
                let poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)));
                let thd = th * poly;
                let s = thd / r;
                // d thd / d th and d th / d r
                let dthd_dth =
                    1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
                let dth_dr = 1.0 / (1.0 + r2);
                let ds_dr = (dthd_dth * dth_dr * r - thd) / r2;
                // d(s x)/dx = s + x ds/dr * x/r
                let (ux, uy) = (x / r, y / r);
                let j = Matrix2::new(
                    s + x * ds_dr * ux,
                    x * ds_dr * uy,
                    y * ds_dr * ux,
                    s + y * ds_dr * uy,
                );
                (Vector2::new(s * x, s * y), j)
            }
        }
    }

    /// Inverse of [`distort`](Self::distort) by Gauss-Newton from the distorted point; `None` if it
    /// does not converge (far outside the calibrated field of view).
    pub fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>> {
        if self.distortion == Distortion::None {
            return Some(*xd);
        }
        let mut xn = *xd;
        for _ in 0..30 {
            let (d, j) = self.distort(&xn);
            let err = d - xd;
            if err.norm_squared() < 1e-24 {
                return Some(xn);
            }
            let step = j.try_inverse()? * err;
            xn -= step;
            if !xn.iter().all(|v| v.is_finite()) {
                return None;
            }
        }
        let (d, _) = self.distort(&xn);
        ((d - xd).norm() < 1e-9).then_some(xn)
    }

    /// Projects a point in the camera frame to pixels; `None` behind or on the camera plane.
    #[inline]
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.distorted(p_cam).map(|xd| self.pixel_of_distorted(&xd))
    }

    /// The distorted normalised coordinates of a point in the camera frame (the first half of
    /// [`Self::project`]); `None` behind or on the camera plane. They are the same at every
    /// pyramid level ([`Self::scaled_to_level`] keeps the distortion).
    #[inline]
    pub fn distorted(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_cam.z <= MIN_DEPTH_M {
            return None;
        }
        let xn = Vector2::new(p_cam.x / p_cam.z, p_cam.y / p_cam.z);
        Some(self.distort(&xn).0)
    }

    /// The pixel of distorted normalised coordinates `xd` (the second half of [`Self::project`]).
    #[inline]
    pub fn pixel_of_distorted(&self, xd: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * xd.x + self.cx, self.fy * xd.y + self.cy)
    }

    /// Projection and its Jacobian d(pixel)/d(p_cam) (2x3).
    pub fn project_with_jacobian(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        if p_cam.z <= MIN_DEPTH_M {
            return None;
        }
        let iz = 1.0 / p_cam.z;
        let xn = Vector2::new(p_cam.x * iz, p_cam.y * iz);
        let (xd, jd) = self.distort(&xn);
        let jn = Matrix2x3::new(iz, 0.0, -xn.x * iz, 0.0, iz, -xn.y * iz);
        let jk = Matrix2::new(self.fx, 0.0, 0.0, self.fy);
        Some((
            Vector2::new(self.fx * xd.x + self.cx, self.fy * xd.y + self.cy),
            jk * jd * jn,
        ))
    }

    /// The ray through pixel `uv` as a point on the plane z = 1 (normalised coordinates, 1).
    pub fn unproject(&self, uv: &Vector2<f64>) -> Option<Vector3<f64>> {
        let xd = Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy);
        let xn = self.undistort(&xd)?;
        Some(Vector3::new(xn.x, xn.y, 1.0))
    }

    /// Whether `uv` lies inside the image with at least `border_px` pixels margin.
    #[inline]
    pub fn in_image(&self, uv: &Vector2<f64>, border_px: f64) -> bool {
        uv.x >= border_px
            && uv.y >= border_px
            && uv.x <= self.width as f64 - 1.0 - border_px
            && uv.y <= self.height as f64 - 1.0 - border_px
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn models() -> Vec<CameraModel> {
        let e = CameraModel::euroc_cam0();
        vec![
            e,
            e.without_distortion(),
            CameraModel {
                distortion: Distortion::Equidistant {
                    k1: -0.01,
                    k2: 0.02,
                    k3: -0.003,
                    k4: 0.001,
                },
                ..e
            },
        ]
    }

    #[test]
    fn projection_jacobian_matches_numeric() {
        let h = 1e-6;
        for cam in models() {
            for p in [
                Vector3::new(0.3, -0.2, 2.0),
                Vector3::new(-1.0, 0.6, 1.5),
                Vector3::new(0.0, 0.0, 0.7),
            ] {
                let (uv, j) = cam.project_with_jacobian(&p).unwrap();
                assert!((uv - cam.project(&p).unwrap()).norm() < 1e-12);
                for k in 0..3 {
                    let mut d = Vector3::zeros();
                    d[k] = h;
                    let num = (cam.project(&(p + d)).unwrap() - cam.project(&(p - d)).unwrap())
                        / (2.0 * h);
                    assert!(
                        (num - j.column(k)).norm() < 1e-4,
                        "{:?} col {k}: {num:?} vs {:?}",
                        cam.distortion,
                        j.column(k)
                    );
                }
            }
        }
    }

    #[test]
    fn a_level_pixel_from_the_distorted_coordinates_is_its_projection() {
        for cam in models() {
            let p = Vector3::new(0.4, -0.25, 1.7);
            let xd = cam.distorted(&p).unwrap();
            for level in 0..4 {
                let c = cam.scaled_to_level(level);
                assert_eq!(c.pixel_of_distorted(&xd), c.project(&p).unwrap());
            }
            assert!(cam.distorted(&Vector3::new(0.1, 0.1, -1.0)).is_none());
        }
    }

    #[test]
    fn distortion_jacobian_matches_numeric() {
        let h = 1e-7;
        for cam in models() {
            let xn = Vector2::new(0.4, -0.3);
            let (_, j) = cam.distort(&xn);
            for k in 0..2 {
                let mut d = Vector2::zeros();
                d[k] = h;
                let num = (cam.distort(&(xn + d)).0 - cam.distort(&(xn - d)).0) / (2.0 * h);
                assert!((num - j.column(k)).norm() < 1e-6, "{:?}", cam.distortion);
            }
        }
    }

    #[test]
    fn unproject_inverts_project_over_the_whole_image() {
        for cam in models() {
            for v in (0..cam.height).step_by(37) {
                for u in (0..cam.width).step_by(41) {
                    let uv = Vector2::new(u as f64, v as f64);
                    let ray = cam.unproject(&uv).expect("unproject");
                    let back = cam.project(&(ray * 2.5)).unwrap();
                    assert!((back - uv).norm() < 1e-6, "{:?} at {uv:?}", cam.distortion);
                }
            }
        }
    }

    #[test]
    fn behind_camera_does_not_project() {
        let cam = CameraModel::euroc_cam0();
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(
            cam.project_with_jacobian(&Vector3::new(0.0, 0.0, 0.0))
                .is_none()
        );
    }

    #[test]
    fn pyramid_scaling_keeps_pixel_centres() {
        let cam = CameraModel::euroc_cam0().without_distortion();
        let p = Vector3::new(0.2, 0.1, 1.0);
        let u0 = cam.project(&p).unwrap();
        let u2 = cam.scaled_to_level(2).project(&p).unwrap();
        // level-0 coordinate of a level-2 coordinate: 4 (u + 0.5) - 0.5
        assert!(((u2 * 4.0).add_scalar(1.5) - u0).norm() < 1e-9);
        assert_eq!(cam.scaled_to_level(2).width, 188);
    }

    #[test]
    fn invalid_parameters_are_rejected() {
        assert!(CameraModel::new(752, 480, [0.0, 1.0, 1.0, 1.0], Distortion::None).is_err());
        assert!(CameraModel::new(0, 480, [1.0, 1.0, 1.0, 1.0], Distortion::None).is_err());
        let nan = Distortion::RadTan {
            k1: f64::NAN,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
        };
        assert!(CameraModel::new(752, 480, [1.0, 1.0, 1.0, 1.0], nan).is_err());
    }
}
