//! Closed-loop map quality against the simulator's depth: every keyframe's final semidense map
//! (triangulated from *estimated* poses) compared with the rendered depth at its pixels. The depth
//! test of the mapper uses true poses; this is what the odometry actually tracks against, and the
//! signed error shows scale drift (all points short or long) and broken keyframes.

use crate::dataset::{AslDataset, DatasetError};
use crate::image::Image;
use crate::mapping::semidense::SemidenseMap;
use crate::time::TimeNs;

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
}

/// Signed relative depth errors of `map`'s points against `depth` (pixels without depth skipped).
pub fn relative_errors(map: &SemidenseMap, depth: &Image<f32>) -> Vec<f64> {
    map.points
        .iter()
        .filter_map(|p| {
            let (x, y) = (p.u_px.round() as usize, p.v_px.round() as usize);
            if x >= depth.width() || y >= depth.height() || p.inv_depth_m_inv <= 0.0 {
                return None;
            }
            let z = depth.get(x, y) as f64;
            (z > 0.0).then(|| (1.0 / p.inv_depth_m_inv as f64 - z) / z)
        })
        .collect()
}

/// The upper median (element `len / 2` in order); NaN if `v` is empty. Reorders `v`.
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// Summary of the signed relative errors of one keyframe.
pub fn summarise(t: TimeNs, mut rel: Vec<f64>) -> KeyframeDepthError {
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
            out.push(summarise(t, relative_errors(m, &depth)));
        }
    }
    Ok(out)
}

/// `keyframes.csv`: one row per keyframe.
pub fn keyframes_csv(rows: &[KeyframeDepthError]) -> String {
    let mut s = String::from("t_ns,points,signed_median_pct,abs_median_pct,within_10pct\n");
    for r in rows {
        s.push_str(&format!(
            "{},{},{:.3},{:.3},{:.1}\n",
            r.t.0, r.points, r.signed_median_pct, r.abs_median_pct, r.within_10pct
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
        let s = summarise(TimeNs(5), rel);
        assert_eq!(s.points, 4);
        assert!((s.signed_median_pct - 1.0).abs() < 1e-4, "{s:?}");
        assert!((s.abs_median_pct - 5.0).abs() < 1e-4, "{s:?}");
        assert_eq!(s.within_10pct, 75.0);
        let csv = keyframes_csv(&[s]);
        assert!(csv.starts_with("t_ns,points,") && csv.contains("\n5,4,1.000,5.000,75.0\n"));
    }
}
