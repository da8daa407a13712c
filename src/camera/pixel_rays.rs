//! Precomputed rays of a camera's integer pixels.
//!
//! Unprojecting a distorted pixel is a Newton iteration ([`CameraModel::undistort`]); a keyframe
//! back-projects every map point it is built from (~13k on a 752x480 semidense map, ~2 ms), and
//! the map's points sit on integer pixels. The table holds exactly what [`CameraModel::unproject`]
//! returns for each of them, so a lookup changes no result; a non-integer pixel is unprojected.

use super::CameraModel;
use nalgebra::{Vector2, Vector3};

/// The normalised coordinates `(X/Z, Y/Z)` of every integer pixel's ray (NaN where the
/// distortion cannot be inverted).
#[derive(Clone, Debug)]
pub struct PixelRays {
    camera: CameraModel,
    normalised: Vec<[f64; 2]>,
}

impl PixelRays {
    /// Unprojects every pixel of `camera` (`width x height` Newton iterations: ~50 ms at
    /// 752x480).
    pub fn new(camera: &CameraModel) -> Self {
        let mut normalised = Vec::with_capacity(camera.width * camera.height);
        for y in 0..camera.height {
            for x in 0..camera.width {
                normalised.push(
                    camera
                        .unproject(&Vector2::new(x as f64, y as f64))
                        .map_or([f64::NAN; 2], |r| [r.x, r.y]),
                );
            }
        }
        PixelRays {
            camera: *camera,
            normalised,
        }
    }

    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The ray `(X/Z, Y/Z, 1)` of pixel `(u_px, v_px)`: [`CameraModel::unproject`], from the table
    /// on an integer pixel inside the image.
    #[inline]
    pub fn ray(&self, u_px: f64, v_px: f64) -> Option<Vector3<f64>> {
        let (w, h) = (self.camera.width, self.camera.height);
        let integer = u_px.fract() == 0.0 && v_px.fract() == 0.0;
        if integer && u_px >= 0.0 && v_px >= 0.0 && (u_px as usize) < w && (v_px as usize) < h {
            let [x, y] = self.normalised[v_px as usize * w + u_px as usize];
            return (x.is_finite() && y.is_finite()).then(|| Vector3::new(x, y, 1.0));
        }
        self.camera.unproject(&Vector2::new(u_px, v_px))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn euroc_like() -> CameraModel {
        CameraModel::euroc_cam0()
    }

    #[test]
    fn a_table_ray_is_exactly_the_unprojected_one() {
        let cam = euroc_like();
        let rays = PixelRays::new(&cam);
        for &(u, v) in &[(0.0, 0.0), (751.0, 479.0), (367.0, 248.0), (12.0, 400.0)] {
            let want = cam.unproject(&Vector2::new(u, v));
            assert_eq!(rays.ray(u, v), want, "pixel ({u}, {v})");
        }
    }

    #[test]
    fn off_the_grid_and_outside_it_is_unprojected() {
        let cam = euroc_like();
        let rays = PixelRays::new(&cam);
        for &(u, v) in &[(10.25, 20.5), (-3.0, 5.0), (752.0, 10.0), (100.0, 480.0)] {
            assert_eq!(
                rays.ray(u, v),
                cam.unproject(&Vector2::new(u, v)),
                "pixel ({u}, {v})"
            );
        }
        let r = rays.ray(10.25, 20.5).unwrap();
        let back = cam.project(&r).unwrap();
        assert!((back - Vector2::new(10.25, 20.5)).norm() < 1e-6, "{back}");
    }
}
