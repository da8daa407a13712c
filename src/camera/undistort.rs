//! Precomputed undistortion: for each pixel of a target (undistorted) camera, the source pixel in
//! the distorted image.

use super::CameraModel;
use crate::image::{Image, bilinear};
use nalgebra::{Vector2, Vector3};

/// Lookup table from target pixels to source (distorted) pixel coordinates. Pixels whose ray does
/// not land inside the source image map to NaN and come out as `fill` when applied.
#[derive(Clone, Debug)]
pub struct UndistortMap {
    map_x: Image<f32>,
    map_y: Image<f32>,
}

impl UndistortMap {
    /// Builds the map from `target` (usually distortion-free) to `source`.
    pub fn new(source: &CameraModel, target: &CameraModel) -> Self {
        let (w, h) = (target.width, target.height);
        let mut map_x = Image::new(w, h);
        let mut map_y = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let ray: Option<Vector3<f64>> = target.unproject(&Vector2::new(x as f64, y as f64));
                let src = ray
                    .and_then(|r| source.project(&r))
                    .filter(|s| source.in_image(s, 0.0));
                let (sx, sy) = src.map_or((f32::NAN, f32::NAN), |s| (s.x as f32, s.y as f32));
                map_x.set(x, y, sx);
                map_y.set(x, y, sy);
            }
        }
        UndistortMap { map_x, map_y }
    }

    /// Resamples `src` through the map (bilinear), writing `fill` where the map has no source.
    pub fn apply_into(&self, src: &Image<f32>, fill: f32, out: &mut Image<f32>) {
        out.resize(self.map_x.width(), self.map_x.height());
        for y in 0..self.map_x.height() {
            let (mx, my) = (self.map_x.row(y), self.map_y.row(y));
            for (x, o) in out.row_mut(y).iter_mut().enumerate() {
                *o = bilinear(src, mx[x], my[x]).unwrap_or(fill);
            }
        }
    }

    /// Source coordinates of target pixel `(x, y)`, if any.
    pub fn source_of(&self, x: usize, y: usize) -> Option<(f32, f32)> {
        let (sx, sy) = (self.map_x.get(x, y), self.map_y.get(x, y));
        (sx.is_finite() && sy.is_finite()).then_some((sx, sy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistorting_a_rendered_pattern_matches_the_pinhole_render() {
        // A plane at z = 2 m with intensity a smooth function of its (X, Y).
        let src_cam = CameraModel::euroc_cam0();
        let dst_cam = src_cam.without_distortion();
        let f = |p: Vector3<f64>| (128.0 + 60.0 * (p.x * 3.0).sin() * (p.y * 2.0).cos()) as f32;
        let render = |cam: &CameraModel| {
            Image::from_fn(cam.width, cam.height, |x, y| {
                cam.unproject(&Vector2::new(x as f64, y as f64))
                    .map_or(0.0, |r| f(r * 2.0))
            })
        };
        let distorted = render(&src_cam);
        let ideal = render(&dst_cam);
        let map = UndistortMap::new(&src_cam, &dst_cam);
        let mut out = Image::new(1, 1);
        map.apply_into(&distorted, -1.0, &mut out);
        let (mut sum, mut n) = (0.0f64, 0usize);
        for y in 40..440 {
            for x in 60..690 {
                if out.get(x, y) >= 0.0 {
                    sum += (out.get(x, y) - ideal.get(x, y)).abs() as f64;
                    n += 1;
                }
            }
        }
        assert!(n > 200_000, "{n} pixels mapped");
        assert!(sum / (n as f64) < 0.2, "mean abs error {}", sum / n as f64);
        assert!(map.source_of(376, 240).is_some());
    }
}
