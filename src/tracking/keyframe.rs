//! The tracking keyframe `I_i` (section III-D): its image pyramid, its semidense points per level
//! in the keyframe camera frame, and the inverse-compositional Jacobians of eq. 26, computed once
//! when the keyframe is made (`T_w^i`, `p_t` and `J_F^{r_ph}` are constant during tracking).

use super::config::{NUM_LEVELS, TrackerConfig};
use crate::camera::{CameraModel, PixelRays};
use crate::geometry::hat;
use crate::image::{Image, Pyramid, bilinear, bilinear_with_gradient};
use crate::time::TimeNs;
use nalgebra::{Isometry3, Matrix2x3, Matrix3x6, Vector2, Vector3};

/// A level-0 keyframe pixel with its inverse depth: what a depth source (ground truth or the
/// semidense mapper) hands the tracker.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthPoint {
    /// Pixel in the (distorted) level-0 image.
    pub u_px: f32,
    pub v_px: f32,
    /// 1/z in the keyframe camera frame, 1/m.
    pub inv_depth_m_inv: f32,
}

/// One pyramid level's points, structure-of-arrays in `f32` (the per-pixel hot path).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelPoints {
    /// Point in the keyframe camera frame, m.
    pub p_kf_m: Vec<[f32; 3]>,
    /// Keyframe intensity at the point, gray levels.
    pub intensity: Vec<f32>,
    /// `d I_i(π(exp(ε) p)) / dε` at `ε = 0` for the twist `ε = [ω, v]` (eq. 26: image gradient ·
    /// projection Jacobian · point Jacobian), gray levels per unit twist.
    pub jacobian: Vec<[f32; 6]>,
    /// Prior weight of the point: `c² / (c² + |∇I|²)` with `c = gradient_weight_gray_px`. A
    /// residual's variance grows with the gradient times the geometric error (depth and pose), so
    /// strong edges count less (as in DSO); 1 when the term is disabled.
    pub weight: Vec<f32>,
}

impl LevelPoints {
    pub fn len(&self) -> usize {
        self.p_kf_m.len()
    }
    pub fn is_empty(&self) -> bool {
        self.p_kf_m.is_empty()
    }
}

/// A keyframe ready for tracking.
#[derive(Clone, Debug)]
pub struct Keyframe {
    pub id: u32,
    pub t: TimeNs,
    /// Pose of the keyframe camera (`T_w^i` inverted).
    pub t_world_cam: Isometry3<f64>,
    /// Camera model of each level.
    pub cameras: Vec<CameraModel>,
    /// Points per level (index 0 = full resolution).
    pub levels: Vec<LevelPoints>,
    /// Median depth of the level-0 points, m.
    pub median_depth_m: f64,
}

impl Keyframe {
    /// Builds the per-level points from level-0 depth points: each level keeps, per cell of
    /// `level_cell_px`, the point of strongest gradient at that level, up to the level's cap.
    pub fn new(
        id: u32,
        t: TimeNs,
        pyramid: &Pyramid,
        camera: &CameraModel,
        t_world_cam: Isometry3<f64>,
        points: &[DepthPoint],
        cfg: &TrackerConfig,
    ) -> Self {
        let p3 = back_project(points, |u, v| camera.unproject(&Vector2::new(u, v)));
        Self::from_points_m(id, t, pyramid, camera, t_world_cam, p3, cfg)
    }

    /// [`Keyframe::new`] with the points' rays looked up in `rays` (the same keyframe, without
    /// unprojecting each point).
    pub fn from_rays(
        id: u32,
        t: TimeNs,
        pyramid: &Pyramid,
        rays: &PixelRays,
        t_world_cam: Isometry3<f64>,
        points: &[DepthPoint],
        cfg: &TrackerConfig,
    ) -> Self {
        let p3 = back_project(points, |u, v| rays.ray(u, v));
        Self::from_points_m(id, t, pyramid, rays.camera(), t_world_cam, p3, cfg)
    }

    /// The keyframe of points `p3` (keyframe camera frame, m).
    fn from_points_m(
        id: u32,
        t: TimeNs,
        pyramid: &Pyramid,
        camera: &CameraModel,
        t_world_cam: Isometry3<f64>,
        p3: Vec<Vector3<f64>>,
        cfg: &TrackerConfig,
    ) -> Self {
        // The same 3-D point projects to the right place at every level because the level
        // models are exact rescalings.
        let cameras: Vec<CameraModel> = (0..pyramid.num_levels())
            .map(|l| camera.scaled_to_level(l as u32))
            .collect();
        // Distorted once: a level's pixel is then an affine map of it (exactly `project`'s).
        let xd: Vec<Option<Vector2<f64>>> = p3.iter().map(|p| camera.distorted(p)).collect();
        let mut depths: Vec<f64> = p3.iter().map(|p| p.z).collect();
        let median_depth_m = median(&mut depths).unwrap_or(1.0);
        let mut levels = Vec::with_capacity(pyramid.num_levels());
        for (l, cam) in cameras.iter().enumerate() {
            let li = l.min(NUM_LEVELS - 1);
            levels.push(build_level(pyramid, l, cam, (&p3, &xd), cfg, li));
        }
        Keyframe {
            id,
            t,
            t_world_cam,
            cameras,
            levels,
            median_depth_m,
        }
    }

    /// Multiplies every point's depth by `factor` (> 0) about the keyframe camera: the map's
    /// scale corrected (`[window] map_scale_gain`). Rays, intensities and weights stay; of the
    /// intensity Jacobian (eq. 26) only the translation columns change, as `1/z`: it is
    /// [`Keyframe::new`] of the scaled points without re-sampling the pyramid.
    pub fn scale_depths(&mut self, factor: f64) {
        if !(factor.is_finite() && factor > 0.0) {
            return;
        }
        let (f, inv) = (factor as f32, (1.0 / factor) as f32);
        for l in &mut self.levels {
            for p in &mut l.p_kf_m {
                p.iter_mut().for_each(|c| *c *= f);
            }
            for j in &mut l.jacobian {
                j[3..].iter_mut().for_each(|c| *c *= inv);
            }
        }
        self.median_depth_m *= factor;
    }

    /// Number of level-0 points.
    pub fn num_points(&self) -> usize {
        self.levels.first().map_or(0, LevelPoints::len)
    }

    /// Fraction of the keyframe's points (level `level`, or the coarsest there is) that a
    /// camera at `t_world_cam` would see inside its image, `border_px` pixels of that level from
    /// the edge, in front of it. Occlusion is ignored. This is the tracker's `overlap` predicted
    /// from a pose, for choosing the closest keyframe.
    pub fn predicted_overlap(
        &self,
        t_world_cam: &Isometry3<f64>,
        level: usize,
        border_px: f64,
    ) -> f64 {
        let l = level.min(self.levels.len().saturating_sub(1));
        let (Some(pts), Some(cam)) = (self.levels.get(l), self.cameras.get(l)) else {
            return 0.0;
        };
        if pts.is_empty() {
            return 0.0;
        }
        let t_cur_kf = t_world_cam.inverse() * self.t_world_cam;
        let seen = pts
            .p_kf_m
            .iter()
            .filter(|p| {
                let q = t_cur_kf * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                q.z > 0.0
                    && cam
                        .project(&q.coords)
                        .is_some_and(|uv| cam.in_image(&uv, border_px))
            })
            .count();
        seen as f64 / pts.len() as f64
    }
}

/// Level `level`'s points; `li` indexes the per-level settings of `cfg`.
fn build_level(
    pyr: &Pyramid,
    level: usize,
    cam: &CameraModel,
    (points, distorted): (&[Vector3<f64>], &[Option<Vector2<f64>>]),
    cfg: &TrackerConfig,
    li: usize,
) -> LevelPoints {
    let (cell_px, max_points, border_px) = (
        cfg.level_cell_px[li],
        cfg.max_points_per_level[li],
        cfg.border_px,
    );
    let gradient_weight_c = cfg.gradient_weight_gray_px;
    let img = pyr.level(level);
    let (gx, gy) = pyr.gradients(level);
    let cell = cell_px.max(1);
    let (cw, ch) = (img.width().div_ceil(cell), img.height().div_ceil(cell));
    // Per point its pixel and gradient² at this level; per cell the index of its strongest point
    // (the first of equals), `NONE` for an empty cell.
    const NONE: u32 = u32::MAX;
    let mut best = vec![NONE; cw * ch];
    let mut at: Vec<(f32, f32, f32)> = Vec::with_capacity(distorted.len());
    for (i, xd) in distorted.iter().enumerate() {
        at.push((f32::NAN, 0.0, 0.0));
        let Some(uv) = xd.map(|xd| cam.pixel_of_distorted(&xd)) else {
            continue;
        };
        if !cam.in_image(&uv, border_px.max(1.0)) {
            continue;
        }
        let (u, v) = (uv.x as f32, uv.y as f32);
        let (Some(dx), Some(dy)) = (bilinear(gx, u, v), bilinear(gy, u, v)) else {
            continue;
        };
        let g2 = dx * dx + dy * dy;
        at[i] = (g2, u, v);
        let c = (v as usize / cell) * cw + u as usize / cell;
        if best[c] == NONE || g2 > at[best[c] as usize].0 {
            best[c] = i as u32;
        }
    }
    // (gradient², index, u, v) of each cell's point, in cell order.
    let mut chosen: Vec<(f32, usize, f32, f32)> = best
        .iter()
        .filter(|&&i| i != NONE)
        .map(|&i| {
            let (g2, u, v) = at[i as usize];
            (g2, i as usize, u, v)
        })
        .collect();
    if chosen.len() > max_points {
        // Keep the strongest, deterministically: under this total order (ties broken by index)
        // the `max_points` strongest are one set, which a partition finds without sorting all
        // candidates (a semidense map has several times more than a level keeps).
        let stronger = |a: &(f32, usize, f32, f32), b: &(f32, usize, f32, f32)| {
            b.0.total_cmp(&a.0).then(a.1.cmp(&b.1))
        };
        chosen.select_nth_unstable_by(max_points - 1, stronger);
        chosen.truncate(max_points);
        chosen.sort_unstable_by_key(|c| c.1); // (indices are unique)
    }
    let mut out = LevelPoints {
        p_kf_m: Vec::with_capacity(chosen.len()),
        intensity: Vec::with_capacity(chosen.len()),
        jacobian: Vec::with_capacity(chosen.len()),
        weight: Vec::with_capacity(chosen.len()),
    };
    for (_, i, u, v) in chosen {
        let p = points[i];
        let Some((_, jproj)) = cam.project_with_jacobian(&p) else {
            continue;
        };
        let Some((val, _, _)) = bilinear_with_gradient(img, u, v) else {
            continue;
        };
        let (Some(dx), Some(dy)) = (bilinear(gx, u, v), bilinear(gy, u, v)) else {
            continue;
        };
        let j = intensity_jacobian(&Vector2::new(dx as f64, dy as f64), &jproj, &p);
        out.p_kf_m.push([p.x as f32, p.y as f32, p.z as f32]);
        out.intensity.push(val);
        out.jacobian
            .push([j[0], j[1], j[2], j[3], j[4], j[5]].map(|x| x as f32));
        let c2 = gradient_weight_c * gradient_weight_c;
        out.weight.push(if c2 > 0.0 {
            c2 / (c2 + dx * dx + dy * dy)
        } else {
            1.0
        });
    }
    out
}

/// The points with a positive finite inverse depth whose pixel has a ray (`ray`), in the
/// keyframe camera frame, m.
fn back_project(
    points: &[DepthPoint],
    ray: impl Fn(f64, f64) -> Option<Vector3<f64>>,
) -> Vec<Vector3<f64>> {
    let mut p3 = Vec::with_capacity(points.len());
    for p in points {
        if !(p.inv_depth_m_inv.is_finite() && p.inv_depth_m_inv > 0.0) {
            continue;
        }
        let Some(r) = ray(p.u_px as f64, p.v_px as f64) else {
            continue;
        };
        p3.push(r / p.inv_depth_m_inv as f64);
    }
    p3
}

/// Eq. 26: `J = ∇I · ∂π/∂p · ∂(exp(ε) p)/∂ε`, with `∂(exp(ε) p)/∂ε = [−[p]×, I]` for `ε = [ω, v]`.
pub fn intensity_jacobian(
    grad: &Vector2<f64>,
    jproj: &Matrix2x3<f64>,
    p: &Vector3<f64>,
) -> nalgebra::RowVector6<f64> {
    let mut jp = Matrix3x6::zeros();
    jp.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-hat(p)));
    jp.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&nalgebra::Matrix3::identity());
    grad.transpose() * jproj * jp
}

/// Selects level-0 tracking candidates from an image pyramid: per `cfg.select_cell_px` cell the
/// pixel of largest gradient magnitude, if above `cfg.min_gradient_gray_px`.
pub fn select_gradient_pixels(pyr: &Pyramid, cfg: &TrackerConfig) -> Vec<(u32, u32)> {
    let (gx, gy) = pyr.gradients(0);
    let (w, h) = (gx.width(), gx.height());
    let cell = cfg.select_cell_px.max(1);
    let border = (cfg.border_px.ceil() as usize).max(2);
    let thr2 = cfg.min_gradient_gray_px * cfg.min_gradient_gray_px;
    let mut out = Vec::new();
    for cy in (border..h.saturating_sub(border)).step_by(cell) {
        for cx in (border..w.saturating_sub(border)).step_by(cell) {
            let mut best: Option<(f32, u32, u32)> = None;
            for y in cy..(cy + cell).min(h - border) {
                let (rx, ry) = (gx.row(y), gy.row(y));
                for x in cx..(cx + cell).min(w - border) {
                    let g2 = rx[x] * rx[x] + ry[x] * ry[x];
                    if g2 > thr2 && best.is_none_or(|b| g2 > b.0) {
                        best = Some((g2, x as u32, y as u32));
                    }
                }
            }
            if let Some((_, x, y)) = best {
                out.push((x, y));
            }
        }
    }
    out
}

/// Depth points from a dense depth map (z, m; 0 = none) at the selected pixels, dropping pixels
/// on depth discontinuities (their 3x3 neighbourhood spans more than `max_rel_spread` of the
/// depth), where a blurred edge pixel has no single depth.
pub fn depth_points_from_map(
    pixels: &[(u32, u32)],
    depth_m: &Image<f32>,
    max_rel_spread: f32,
) -> Vec<DepthPoint> {
    let (w, h) = (depth_m.width(), depth_m.height());
    let mut out = Vec::with_capacity(pixels.len());
    for &(x, y) in pixels {
        let (x, y) = (x as usize, y as usize);
        if x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
            continue;
        }
        let d = depth_m.get(x, y);
        if !(d.is_finite() && d > 0.0) {
            continue;
        }
        let (mut lo, mut hi) = (d, d);
        for yy in y - 1..=y + 1 {
            for xx in x - 1..=x + 1 {
                let n = depth_m.get(xx, yy);
                lo = lo.min(n);
                hi = hi.max(n);
            }
        }
        if lo <= 0.0 || (hi - lo) > max_rel_spread * d {
            continue;
        }
        out.push(DepthPoint {
            u_px: x as f32,
            v_px: y as f32,
            inv_depth_m_inv: 1.0 / d,
        });
    }
    out
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let m = v.len() / 2;
    v.select_nth_unstable_by(m, f64::total_cmp);
    Some(v[m])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::boxplus_se3;
    use nalgebra::Vector6;

    /// A smooth image (so bilinear gradients equal the analytic ones to first order).
    fn smooth(w: usize, h: usize) -> Image<f32> {
        Image::from_fn(w, h, |x, y| {
            let (x, y) = (x as f32, y as f32);
            120.0 + 60.0 * (x * 0.11).sin() * (y * 0.07).cos() + 30.0 * (0.05 * (x + 2.0 * y)).sin()
        })
    }

    #[test]
    fn a_keyframe_from_looked_up_rays_is_the_one_unprojected() {
        let cam = CameraModel::euroc_cam0();
        let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        pyr.fill_from_f32(&smooth(cam.width, cam.height));
        // Integer pixels (looked up), a few off the grid (unprojected), one without depth.
        let mut points: Vec<DepthPoint> = (0..2000)
            .map(|i| DepthPoint {
                u_px: (13 + (i * 37) % 720) as f32,
                v_px: (11 + (i * 53) % 450) as f32,
                inv_depth_m_inv: 0.2 + 0.001 * (i % 500) as f32,
            })
            .collect();
        points.push(DepthPoint {
            u_px: 100.25,
            v_px: 200.5,
            inv_depth_m_inv: 0.5,
        });
        points.push(DepthPoint {
            u_px: 300.0,
            v_px: 200.0,
            inv_depth_m_inv: f32::NAN,
        });
        let cfg = TrackerConfig::default();
        let pose = Isometry3::translation(0.1, 0.2, 0.3);
        let a = Keyframe::new(4, TimeNs(5), &pyr, &cam, pose, &points, &cfg);
        let b = Keyframe::from_rays(
            4,
            TimeNs(5),
            &pyr,
            &PixelRays::new(&cam),
            pose,
            &points,
            &cfg,
        );
        assert!(a.num_points() > 1000, "{}", a.num_points());
        assert_eq!(a.median_depth_m, b.median_depth_m);
        assert_eq!(a.levels, b.levels);
    }

    #[test]
    fn intensity_jacobian_matches_numeric_differentiation() {
        let cam = CameraModel::euroc_cam0();
        let img = smooth(cam.width, cam.height);
        let mut pyr = Pyramid::new(cam.width, cam.height, 1);
        pyr.fill_from_f32(&img);
        let (gx, gy) = pyr.gradients(0);
        let p = Vector3::new(0.35, -0.2, 2.3);
        let (uv, jproj) = cam.project_with_jacobian(&p).unwrap();
        let (u, v) = (uv.x as f32, uv.y as f32);
        let grad = Vector2::new(
            bilinear(gx, u, v).unwrap() as f64,
            bilinear(gy, u, v).unwrap() as f64,
        );
        let j = intensity_jacobian(&grad, &jproj, &p);
        let f = |eps: &Vector6<f64>| {
            let q = boxplus_se3(&Isometry3::identity(), eps) * nalgebra::Point3::from(p);
            let uv = cam.project(&q.coords).unwrap();
            bilinear(&img, uv.x as f32, uv.y as f32).unwrap() as f64
        };
        for k in 0..6 {
            let h = if k < 3 { 2e-3 } else { 4e-3 };
            let mut e = Vector6::zeros();
            e[k] = h;
            let num = (f(&e) - f(&-e)) / (2.0 * h);
            // Central-difference image gradients vs the smooth function: a few percent.
            assert!(
                (num - j[k]).abs() < 0.05 * j.norm(),
                "k={k} numeric {num} analytic {}",
                j[k]
            );
        }
    }

    /// The smooth image's pyramid, a tracker configuration that selects most of its pixels, and
    /// those pixels.
    fn smooth_gradient_pixels(cam: &CameraModel) -> (Pyramid, TrackerConfig, Vec<(u32, u32)>) {
        let img = smooth(cam.width, cam.height);
        let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        pyr.fill_from_f32(&img);
        let cfg = TrackerConfig {
            min_gradient_gray_px: 1.0,
            ..TrackerConfig::default()
        };
        let px = select_gradient_pixels(&pyr, &cfg);
        (pyr, cfg, px)
    }

    #[test]
    fn levels_are_thinned_capped_and_consistent() {
        let cam = CameraModel::euroc_cam0();
        let (pyr, cfg, px) = smooth_gradient_pixels(&cam);
        assert!(px.len() > 5000, "{}", px.len());
        let depth = Image::from_fn(cam.width, cam.height, |_, _| 2.0f32);
        let pts = depth_points_from_map(&px, &depth, 0.05);
        assert_eq!(pts.len(), px.len());
        let kf = Keyframe::new(0, TimeNs(0), &pyr, &cam, Isometry3::identity(), &pts, &cfg);
        for (l, lv) in kf.levels.iter().enumerate() {
            assert!(!lv.is_empty() && lv.len() <= cfg.max_points_per_level[l]);
            // Every point projects where its stored intensity was sampled.
            for (p, i) in lv.p_kf_m.iter().zip(&lv.intensity).take(50) {
                let q = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                let uv = kf.cameras[l].project(&q).unwrap();
                let s = bilinear(pyr.level(l), uv.x as f32, uv.y as f32).unwrap();
                assert!((s - i).abs() < 0.05, "level {l}: {s} vs {i}");
            }
        }
        assert!((kf.median_depth_m - 2.0).abs() < 1e-4);
    }

    #[test]
    fn a_keyframe_with_scaled_depths_has_the_jacobians_of_the_scaled_points() {
        let cam = CameraModel::euroc_cam0();
        let (pyr, cfg, px) = smooth_gradient_pixels(&cam);
        // Depths varying over the image, so each point's Jacobian is its own.
        let depth = Image::from_fn(cam.width, cam.height, |x, y| {
            1.5 + (x + 2 * y) as f32 / 400.0
        });
        let pts = depth_points_from_map(&px, &depth, 0.05);
        let kf = Keyframe::new(0, TimeNs(0), &pyr, &cam, Isometry3::identity(), &pts, &cfg);
        let mut scaled = kf.clone();
        scaled.scale_depths(0.9);
        assert!((scaled.median_depth_m - 0.9 * kf.median_depth_m).abs() < 1e-9);
        let mut changed = 0;
        for (l, (a, b)) in scaled.levels.iter().zip(&kf.levels).enumerate() {
            assert_eq!(a.len(), b.len());
            assert!(a.len() > 10);
            let (gx, gy) = pyr.gradients(l);
            for k in 0..a.len().min(300) {
                let p = Vector3::from(a.p_kf_m[k].map(|c| c as f64));
                let q = Vector3::from(b.p_kf_m[k].map(|c| c as f64));
                assert!((p - 0.9 * q).norm() < 1e-5);
                // Eq. 26 evaluated afresh at the scaled point.
                let (uv, jproj) = kf.cameras[l].project_with_jacobian(&p).unwrap();
                let (u, v) = (uv.x as f32, uv.y as f32);
                let g = Vector2::new(
                    bilinear(gx, u, v).unwrap() as f64,
                    bilinear(gy, u, v).unwrap() as f64,
                );
                let want = intensity_jacobian(&g, &jproj, &p);
                for c in 0..6 {
                    let tol = 1e-3 * want[c].abs().max(1.0);
                    assert!(
                        (a.jacobian[k][c] as f64 - want[c]).abs() < tol,
                        "{l} {k} {c}"
                    );
                }
                changed += usize::from(a.jacobian[k][3] != b.jacobian[k][3]);
                assert_eq!(a.intensity[k], b.intensity[k]);
            }
        }
        assert!(
            changed > 100,
            "the translation columns must change ({changed})"
        );
    }

    #[test]
    fn depth_edges_are_dropped() {
        let depth = Image::from_fn(10, 10, |x, _| if x < 5 { 1.0f32 } else { 3.0 });
        let pts = depth_points_from_map(&[(2, 5), (5, 5), (7, 5), (0, 0)], &depth, 0.05);
        let us: Vec<f32> = pts.iter().map(|p| p.u_px).collect();
        assert_eq!(us, vec![2.0, 7.0]);
    }
}
