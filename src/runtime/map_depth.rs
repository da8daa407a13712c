//! Closed-loop map quality against the simulator's depth: every keyframe's final semidense map
//! (triangulated from *estimated* poses) compared with the rendered depth at its pixels. The depth
//! test of the mapper uses true poses; this is what the odometry actually tracks against, and the
//! signed error shows scale drift (all points short or long) and broken keyframes.

use crate::dataset::{AslDataset, DatasetError};
use crate::image::Image;
use crate::mapping::semidense::SemidenseMap;
use crate::time::TimeNs;
use nalgebra::{Matrix3, Vector3};

/// Depth errors of one keyframe map (relative errors `(1/ρ − z) / z`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyframeDepthError {
    pub t: TimeNs,
    /// Points with a ground-truth depth at their pixel.
    pub points: usize,
    /// Median signed relative error, % (negative: the map is too short / too near).
    pub signed_median_pct: f64,
    /// Median absolute relative error, %.
    pub abs_median_pct: f64,
    /// Points within 10 % of the true depth, %.
    pub within_10pct: f64,
    /// The inverse-depth error `δρ = ρ − 1/z` fitted over the image as `a + b·x + c·y`, with `x`,
    /// `y` the pixel coordinates scaled to [−1, 1] across the width and height: `[a, b, c]`,
    /// 1/m (NaN with fewer than three points or a degenerate spread). A map tilted against the
    /// truth shows here: under motion along the image's vertical, for one, an error growing
    /// across the image (`b`) is the same image motion as a roll about the optical axis.
    pub inv_depth_error_fit_m_inv: [f64; 3],
}

/// `map`'s points that have a ground-truth depth at their pixel: `(x_px, y_px, ρ, z)` with
/// `ρ > 0` the map's inverse depth (1/m) and `z > 0` the rendered depth (m).
fn points_with_depth<'a>(
    map: &'a SemidenseMap,
    depth: &'a Image<f32>,
) -> impl Iterator<Item = (usize, usize, f64, f64)> + 'a {
    map.points.iter().filter_map(|p| {
        let (x, y) = (p.u_px.round() as usize, p.v_px.round() as usize);
        if x >= depth.width() || y >= depth.height() || p.inv_depth_m_inv <= 0.0 {
            return None;
        }
        let z = depth.get(x, y) as f64;
        (z > 0.0).then_some((x, y, p.inv_depth_m_inv as f64, z))
    })
}

/// Signed relative depth errors of `map`'s points against `depth` (pixels without depth skipped).
pub fn relative_errors(map: &SemidenseMap, depth: &Image<f32>) -> Vec<f64> {
    points_with_depth(map, depth)
        .map(|(_, _, rho, z)| (1.0 / rho - z) / z)
        .collect()
}

/// The least-squares plane `[a, b, c]` of `δρ = ρ − 1/z` over the normalised image coordinates
/// (see [`KeyframeDepthError::inv_depth_error_fit_m_inv`]) of `map`'s points with a depth in
/// `depth`; NaN if it is not determined.
pub fn inverse_depth_error_fit(map: &SemidenseMap, depth: &Image<f32>) -> [f64; 3] {
    let (w, h) = (depth.width() as f64, depth.height() as f64);
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for (x, y, rho, z) in points_with_depth(map, depth) {
        let row = Vector3::new(1.0, 2.0 * x as f64 / w - 1.0, 2.0 * y as f64 / h - 1.0);
        ata += row * row.transpose();
        atb += row * (rho - 1.0 / z);
    }
    // The squared pivots over the point count are the variances of x and y left after the
    // offset (and x) are fitted: less than a pixel's worth leaves that slope undetermined.
    let n = ata[(0, 0)];
    match ata.cholesky() {
        Some(c)
            if n >= 3.0
                && c.l()[(1, 1)].powi(2) / n >= (1.0 / w).powi(2)
                && c.l()[(2, 2)].powi(2) / n >= (1.0 / h).powi(2) =>
        {
            let f = c.solve(&atb);
            [f[0], f[1], f[2]]
        }
        _ => [f64::NAN; 3],
    }
}

/// The upper median (element `len / 2` in order); NaN if `v` is empty. Reorders `v`.
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// Summary of the signed relative errors `rel` of one keyframe, with its inverse-depth error fit.
pub fn summarise(t: TimeNs, mut rel: Vec<f64>, fit_m_inv: [f64; 3]) -> KeyframeDepthError {
    let n = rel.len();
    let within = rel.iter().filter(|e| e.abs() <= 0.10).count();
    let signed = median(&mut rel);
    let mut abs: Vec<f64> = rel.iter().map(|e| e.abs()).collect();
    KeyframeDepthError {
        t,
        points: n,
        signed_median_pct: 100.0 * signed,
        abs_median_pct: 100.0 * median(&mut abs),
        within_10pct: if n == 0 {
            f64::NAN
        } else {
            100.0 * within as f64 / n as f64
        },
        inv_depth_error_fit_m_inv: fit_m_inv,
    }
}

/// One entry per keyframe of `maps` (keyframe times `times`, same order) whose time has a depth
/// image in `ds`; empty if the dataset has no `depth0`.
pub fn keyframe_depth_errors(
    ds: &AslDataset,
    maps: &[std::sync::Arc<SemidenseMap>],
    times: &[TimeNs],
) -> Result<Vec<KeyframeDepthError>, DatasetError> {
    let mut out = Vec::new();
    for (m, &t) in maps.iter().zip(times) {
        if let Some(depth) = ds.load_depth_m(t)? {
            let fit = inverse_depth_error_fit(m, &depth);
            out.push(summarise(t, relative_errors(m, &depth), fit));
        }
    }
    Ok(out)
}

/// `keyframes.csv`: one row per keyframe.
pub fn keyframes_csv(rows: &[KeyframeDepthError]) -> String {
    let mut s = String::from(
        "t_ns,points,signed_median_pct,abs_median_pct,within_10pct,\
         inv_depth_err_m_inv,inv_depth_err_x_slope_m_inv,inv_depth_err_y_slope_m_inv\n",
    );
    for r in rows {
        let [a, b, c] = r.inv_depth_error_fit_m_inv;
        s.push_str(&format!(
            "{},{},{:.3},{:.3},{:.1},{:.5},{:.5},{:.5}\n",
            r.t.0, r.points, r.signed_median_pct, r.abs_median_pct, r.within_10pct, a, b, c
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;
    use crate::mapping::semidense::MapPoint;
    use nalgebra::Isometry3;

    fn point(u: f32, v: f32, z: f32) -> MapPoint {
        MapPoint {
            u_px: u,
            v_px: v,
            inv_depth_m_inv: 1.0 / z,
            inv_depth_std_m_inv: 0.01,
            num_views: 3,
        }
    }

    #[test]
    fn signed_and_absolute_errors_against_a_depth_image() {
        let mut depth = Image::<f32>::new(8, 4);
        for y in 0..4 {
            for x in 0..8 {
                depth.set(x, y, 2.0);
            }
        }
        depth.set(7, 3, 0.0); // no depth there
        let map = SemidenseMap {
            t_world_cam: Isometry3::identity(),
            camera: CameraModel::euroc_cam0(),
            points: vec![
                point(0.0, 0.0, 1.9),  // −5 %
                point(1.0, 0.0, 1.96), // −2 %
                point(2.0, 1.0, 2.02), // +1 %
                point(3.0, 2.0, 2.6),  // +30 %
                point(7.0, 3.0, 1.0),  // no ground truth
                point(9.0, 1.0, 2.0),  // outside the image
            ],
        };
        let rel = relative_errors(&map, &depth);
        assert_eq!(rel.len(), 4);
        let s = summarise(TimeNs(5), rel, [0.25, -0.5, 0.125]);
        assert_eq!(s.points, 4);
        assert!((s.signed_median_pct - 1.0).abs() < 1e-4, "{s:?}");
        assert!((s.abs_median_pct - 5.0).abs() < 1e-4, "{s:?}");
        assert_eq!(s.within_10pct, 75.0);
        let csv = keyframes_csv(&[s]);
        assert!(
            csv.starts_with("t_ns,points,")
                && csv.contains("\n5,4,1.000,5.000,75.0,0.25000,-0.50000,0.12500\n"),
            "{csv}"
        );
    }

    #[test]
    fn an_inverse_depth_error_linear_across_the_image_is_recovered() {
        let (w, h) = (64, 48);
        let depth = Image::from_fn(w, h, |x, y| 1.5 + 0.01 * x as f32 + 0.02 * y as f32);
        let (a, b, c) = (0.03, -0.08, 0.05);
        let mut points = Vec::new();
        for y in (2..h).step_by(5) {
            for x in (1..w).step_by(3) {
                let (xn, yn) = (
                    2.0 * x as f64 / w as f64 - 1.0,
                    2.0 * y as f64 / h as f64 - 1.0,
                );
                let rho = 1.0 / depth.get(x, y) as f64 + a + b * xn + c * yn;
                points.push(point(x as f32, y as f32, (1.0 / rho) as f32));
            }
        }
        let mut map = SemidenseMap {
            t_world_cam: Isometry3::identity(),
            camera: CameraModel::euroc_cam0(),
            points,
        };
        let fit = inverse_depth_error_fit(&map, &depth);
        for (got, want) in fit.iter().zip([a, b, c]) {
            assert!(
                (got - want).abs() < 1e-5,
                "fit {fit:?}, want {:?}",
                [a, b, c]
            );
        }
        // Points on one image row only: the vertical slope is not determined.
        map.points.retain(|p| p.v_px == 2.0);
        assert!(
            inverse_depth_error_fit(&map, &depth)
                .iter()
                .all(|v| v.is_nan())
        );
    }
}
