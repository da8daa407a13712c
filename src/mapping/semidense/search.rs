//! The per-view search of one keyframe pixel (eq. 28 for one view `o`): epipolar scan, 7x7
//! verification, sub-pixel Gauss–Newton, inverse depth and its standard deviation.

use super::epipolar::{ViewGeometry, clip_to_box, to_pixel};
use super::fusion::Estimate;
use crate::camera::CameraModel;
use crate::image::Image;
use nalgebra::{Matrix2, Vector2};

/// Template half-size: 7x7 (eq. 28).
const HALF: i32 = 3;
pub(crate) const PATCH: usize = 49;
/// The distorted epipolar curve is evaluated exactly every this many pixels, straight between.
const KNOT_PX: f64 = 16.0;
/// Longest walk, px (longer than any image diagonal the mapper is meant for).
const MAX_WALK_PX: f64 = 4000.0;
/// The second scan minimum is checked with the full template only if its 5-sample cost is below
/// this factor times the best one's (or times the noise floor, gray levels², if that is larger).
const SECOND_SCAN_RATIO: f32 = 4.0;
const SCAN_NOISE_FLOOR: f32 = 50.0;
/// Scan extension beyond the range ends, px: the 5-sample window's half-width plus 3 px, so that a
/// minimum at a range end is still an interior minimum of the scan (the refined match must then
/// lie within the range, give or take 2σ).
const SCAN_MARGIN_PX: f64 = 5.0;

/// What the search of one pixel in one view gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Outcome {
    Matched(Estimate),
    OutOfView,
    LowParallax,
    WideBaseline,
    GradientParallel,
    Photometric,
    Ambiguous,
    OutOfRange,
}

/// Everything about the view that is shared by all pixels.
pub(crate) struct ViewContext<'a> {
    pub image: &'a Image<f32>,
    pub camera: &'a CameraModel,
    pub geometry: ViewGeometry,
    /// Normalised footprint of the image (see `epipolar::normalised_footprint`).
    pub footprint: [f64; 4],
    /// Width of the global inverse-depth range, 1/m.
    pub global_width_m_inv: f64,
    pub min_parallax_px: f64,
    /// `|t_view_kf|`, m, and the largest accepted baseline / depth.
    pub baseline_m: f64,
    pub max_baseline_depth_ratio: f64,
    pub min_cos: f32,
    pub max_patch_rms: f32,
    pub min_second_best_ratio: f32,
    pub match_std_px: f32,
}

/// The keyframe side of one candidate.
pub(crate) struct KeyframePixel<'a> {
    pub image: &'a Image<f32>,
    pub x: usize,
    pub y: usize,
    /// Normalised ray (z = 1).
    pub ray: Vector2<f64>,
    /// `d normalised / d pixel` at the pixel.
    pub jinv: Matrix2<f64>,
    /// Unit image gradient.
    pub grad_dir: [f32; 2],
    /// The zero-mean 7x7 template around the pixel (see [`template`]).
    pub template: &'a [f32; PATCH],
}

/// The zero-mean 7x7 template of eq. 28 around pixel `(x, y)` of `image` (row-major; the pixel
/// must be at least 3 px inside the image). The same for every view, so computed once.
pub(crate) fn template(image: &Image<f32>, x: usize, y: usize) -> [f32; PATCH] {
    let (d, s) = (image.data(), image.stride());
    let mut t7 = [0.0f32; PATCH];
    let mut k = 0;
    for dy in -HALF..=HALF {
        let row = ((y as i32 + dy) as usize) * s;
        for dx in -HALF..=HALF {
            t7[k] = d[row + (x as i32 + dx) as usize];
            k += 1;
        }
    }
    let m7 = t7.iter().sum::<f32>() / PATCH as f32;
    t7.iter_mut().for_each(|t| *t -= m7);
    t7
}

/// Bilinear sample with the 2x2 cell known to be inside.
#[inline(always)]
fn sample(d: &[f32], stride: usize, x: f32, y: f32) -> f32 {
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let i = y0 * stride + x0;
    let (a, b, c, e) = (d[i], d[i + 1], d[i + stride], d[i + stride + 1]);
    let top = a + fx * (b - a);
    let bot = c + fx * (e - c);
    top + fy * (bot - top)
}

/// Bilinear sample and gradient with the 2x2 cell known to be inside.
#[inline(always)]
fn sample_grad(d: &[f32], stride: usize, x: f32, y: f32) -> (f32, f32, f32) {
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let i = y0 * stride + x0;
    let (a, b, c, e) = (d[i], d[i + 1], d[i + stride], d[i + stride + 1]);
    let top = a + fx * (b - a);
    let bot = c + fx * (e - c);
    (
        top + fy * (bot - top),
        (b - a) + fy * ((e - c) - (b - a)),
        bot - top,
    )
}

#[inline(always)]
fn cell_inside(img: &Image<f32>, x: f32, y: f32) -> bool {
    x >= 0.0 && y >= 0.0 && x < (img.width() - 1) as f32 && y < (img.height() - 1) as f32
}

/// The 7x7 patch `u + A δ` lies inside `img` (checked at its corners; the patch is convex).
#[inline]
fn patch_inside(img: &Image<f32>, u: [f32; 2], a: &[f32; 4]) -> bool {
    let h = HALF as f32;
    [(-h, -h), (h, -h), (-h, h), (h, h)]
        .iter()
        .all(|&(dx, dy)| {
            cell_inside(
                img,
                u[0] + a[0] * dx + a[1] * dy,
                u[1] + a[2] * dx + a[3] * dy,
            )
        })
}

/// Zero-mean SSD of the zero-mean template `t` against `img` at `u + A δ`.
fn patch_cost(img: &Image<f32>, u: [f32; 2], a: &[f32; 4], t: &[f32; PATCH]) -> Option<f32> {
    if !patch_inside(img, u, a) {
        return None;
    }
    let (d, s) = (img.data(), img.stride());
    let (mut sv, mut sd2) = (0.0f32, 0.0f32);
    let mut k = 0;
    for dy in -HALF..=HALF {
        let (bx, by) = (u[0] + a[1] * dy as f32, u[1] + a[3] * dy as f32);
        for dx in -HALF..=HALF {
            let v = sample(d, s, bx + a[0] * dx as f32, by + a[2] * dx as f32);
            let r = v - t[k];
            sv += v;
            sd2 += r * r;
            k += 1;
        }
    }
    Some(sd2 - sv * sv / PATCH as f32)
}

/// Zero-mean SSD as [`patch_cost`] plus the Gauss–Newton terms `(Σ r J, Σ J²)` for a shift of the
/// whole patch by `ut` pixels per unit curve parameter.
fn patch_cost_gn(
    img: &Image<f32>,
    u: [f32; 2],
    a: &[f32; 4],
    t: &[f32; PATCH],
    ut: [f32; 2],
) -> Option<(f32, f32, f32)> {
    if !patch_inside(img, u, a) {
        return None;
    }
    let (d, s) = (img.data(), img.stride());
    let (mut sv, mut sd2, mut sdj, mut sj, mut sjj) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    let mut k = 0;
    for dy in -HALF..=HALF {
        let (bx, by) = (u[0] + a[1] * dy as f32, u[1] + a[3] * dy as f32);
        for dx in -HALF..=HALF {
            let (v, gx, gy) = sample_grad(d, s, bx + a[0] * dx as f32, by + a[2] * dx as f32);
            let r = v - t[k];
            let j = gx * ut[0] + gy * ut[1];
            sv += v;
            sd2 += r * r;
            sdj += r * j;
            sj += j;
            sjj += j * j;
            k += 1;
        }
    }
    let n = PATCH as f32;
    // residuals r − mean(r) and Jacobians j − mean(j) (the patch mean moves with the patch)
    Some((sd2 - sv * sv / n, sdj - sv / n * sj, sjj - sj * sj / n))
}

/// Two best local minima `(cost, s)` of the scan.
#[derive(Clone, Copy)]
struct Minima([(f32, f64); 2]);

impl Minima {
    fn push(&mut self, c: f32, s: f64) {
        if c < self.0[0].0 {
            self.0[1] = self.0[0];
            self.0[0] = (c, s);
        } else if c < self.0[1].0 {
            self.0[1] = (c, s);
        }
    }
}

/// Searches keyframe pixel `kp` in the view along the inverse-depth range `[lo, hi]` (1/m).
pub(crate) fn search_pixel(ctx: &ViewContext, kp: &KeyframePixel, lo: f64, hi: f64) -> Outcome {
    let cam = ctx.camera;
    let line = ctx.geometry.line(&kp.ray);
    if ctx.baseline_m * lo > ctx.max_baseline_depth_ratio {
        return Outcome::WideBaseline;
    }
    let Some((lo, hi)) = line.front_range(lo, hi) else {
        return Outcome::OutOfView;
    };
    let (Some(n_lo), Some(n_hi)) = (line.normalised(lo), line.normalised(hi)) else {
        return Outcome::OutOfView;
    };
    let dn = n_hi - n_lo;
    let len_n = dn.norm();
    // Parallax: pixels per unit inverse depth (at the range's scale) over the whole global range.
    let f_px = 0.5 * (cam.fx + cam.fy);
    let px_per_rho = f_px * len_n / (hi - lo);
    if !(px_per_rho * ctx.global_width_m_inv >= ctx.min_parallax_px) {
        return Outcome::LowParallax;
    }
    // Clip to the image footprint, extended at both ends so the scan window covers the range ends.
    let ext = SCAN_MARGIN_PX / (f_px * len_n);
    let Some((s_a, s_b)) = clip_to_box(&n_lo, &dn, -ext, 1.0 + ext, &ctx.footprint) else {
        return Outcome::OutOfView;
    };
    let n_at = |s: f64| n_lo + dn * s;

    // Affine warp of the template (linearised G of eq. 28) at the middle of the clipped range.
    let s_mid = (0.5 * (s_a + s_b)).clamp(0.0, 1.0);
    let rho_mid = line
        .inv_depth_at(&n_at(s_mid))
        .unwrap_or(0.5 * (lo + hi))
        .clamp(lo, hi);
    let Some(jn) = ctx.geometry.warp_normalised(&kp.ray, rho_mid) else {
        return Outcome::OutOfView;
    };
    let Some(n_mid) = line.normalised(rho_mid) else {
        return Outcome::OutOfView;
    };
    let (_, jpix_mid) = to_pixel(cam, &n_mid);
    let a = jpix_mid * jn * kp.jinv;
    let tangent = jpix_mid * dn;
    let tangent_px = tangent.norm();
    let Some(a_inv) = a.try_inverse() else {
        return Outcome::GradientParallel;
    };
    if !(tangent_px > 0.0) {
        return Outcome::LowParallax;
    }
    // Keyframe step that maps onto a 1-px step along the view's curve.
    let dk = a_inv * (tangent / tangent_px);
    let dk_norm = dk.norm();
    if !(0.25..=4.0).contains(&dk_norm) {
        return Outcome::GradientParallel;
    }
    let cos =
        ((kp.grad_dir[0] as f64 * dk.x + kp.grad_dir[1] as f64 * dk.y) / dk_norm).abs() as f32;
    if !(cos >= ctx.min_cos) {
        return Outcome::GradientParallel;
    }
    let af = [
        a[(0, 0)] as f32,
        a[(0, 1)] as f32,
        a[(1, 0)] as f32,
        a[(1, 1)] as f32,
    ];

    // Templates: 5 samples along the keyframe's epipolar direction (and the 7x7 square, given);
    // zero-mean.
    let (kd, ks) = (kp.image.data(), kp.image.stride());
    let (x, y) = (kp.x as f32, kp.y as f32);
    let (dkx, dky) = (dk.x as f32, dk.y as f32);
    let mut t5 = [0.0f32; 5];
    for (k, t) in t5.iter_mut().enumerate() {
        let o = k as f32 - 2.0;
        let (sx, sy) = (x + o * dkx, y + o * dky);
        if !cell_inside(kp.image, sx, sy) {
            return Outcome::OutOfView;
        }
        *t = sample(kd, ks, sx, sy);
    }
    let m5 = t5.iter().sum::<f32>() / 5.0;
    t5.iter_mut().for_each(|t| *t -= m5);
    let st5: f32 = t5.iter().map(|t| t * t).sum();
    let t7 = kp.template;

    // Epipolar scan: 1-px steps along the curve, exact at knots, 5-sample zero-mean SSD.
    let (vd, vs) = (ctx.image.data(), ctx.image.stride());
    let (x_lim, y_lim) = (
        (ctx.image.width() - 1) as f32,
        (ctx.image.height() - 1) as f32,
    );
    let pix = |s: f64| {
        let u = to_pixel(cam, &n_at(s)).0;
        [u.x as f32, u.y as f32]
    };
    let n_seg = (((s_b - s_a) * tangent_px).min(MAX_WALK_PX) / KNOT_PX)
        .ceil()
        .max(1.0) as usize;
    let ds_seg = (s_b - s_a) / n_seg as f64;
    let mut w = [0.0f32; 5];
    let mut ws = [0.0f64; 3];
    let mut filled = 0usize; // consecutive valid samples
    let (mut c_prev2, mut c_prev) = (f32::INFINITY, f32::INFINITY);
    let (mut s_prev2, mut s_prev) = (0.0f64, 0.0f64);
    let mut minima = Minima([(f32::INFINITY, f64::NAN); 2]);
    let mut s_k = s_a;
    let mut u_k = pix(s_k);
    let mut off = 0.0f32;
    let mut steps_left = MAX_WALK_PX as usize;
    'walk: for seg in 0..n_seg {
        let s_k1 = if seg + 1 == n_seg {
            s_b
        } else {
            s_a + (seg + 1) as f64 * ds_seg
        };
        let u_k1 = pix(s_k1);
        let (ddx, ddy) = (u_k1[0] - u_k[0], u_k1[1] - u_k[1]);
        let len = (ddx * ddx + ddy * ddy).sqrt();
        let inv_len = 1.0 / len;
        let (stx, sty, sts) = (ddx * inv_len, ddy * inv_len, (s_k1 - s_k) * inv_len as f64);
        while off < len {
            if steps_left == 0 {
                break 'walk; // only a wildly distorting camera gets here
            }
            steps_left -= 1;
            let (ux, uy) = (u_k[0] + off * stx, u_k[1] + off * sty);
            let s = s_k + off as f64 * sts;
            off += 1.0;
            if !(ux >= 0.0 && uy >= 0.0 && ux < x_lim && uy < y_lim) {
                filled = 0;
                (c_prev2, c_prev) = (f32::INFINITY, f32::INFINITY);
                continue;
            }
            // the window (last 5 samples, oldest first) is shifted in registers
            w = [w[1], w[2], w[3], w[4], sample(vd, vs, ux, uy)];
            ws = [ws[1], ws[2], s];
            filled += 1;
            if filled < 5 {
                continue;
            }
            let sv = w[0] + w[1] + w[2] + w[3] + w[4];
            let svv = w[0] * w[0] + w[1] * w[1] + w[2] * w[2] + w[3] * w[3] + w[4] * w[4];
            let svt = w[0] * t5[0] + w[1] * t5[1] + w[2] * t5[2] + w[3] * t5[3] + w[4] * t5[4];
            let c = svv - sv * sv * 0.2 - 2.0 * svt + st5;
            // Only interior minima: one at the end of the scan (or of a gap) may continue outside
            // the range, and then the match is elsewhere. (Tested first: beating the second best,
            // rarely true once the scan is under way, so the branch predicts well.)
            if c_prev < minima.0[1].0 && c_prev <= c_prev2 && c_prev < c && c_prev2 < f32::INFINITY
            {
                // sub-sample position from the parabola through the three costs
                let den = c_prev2 - 2.0 * c_prev + c;
                let d = if den > 0.0 {
                    (0.5 * (c_prev2 - c) / den).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                minima.push(c_prev, s_prev + d as f64 * 0.5 * (ws[0] - s_prev2));
            }
            // the window's centre sample was taken 2 steps ago
            (c_prev2, c_prev) = (c_prev, c);
            (s_prev2, s_prev) = (s_prev, ws[0]);
        }
        off -= len;
        s_k = s_k1;
        u_k = u_k1;
    }
    if !minima.0[0].0.is_finite() {
        return Outcome::OutOfRange;
    }

    // Full 7x7 check (eq. 28) of the best minimum, with the Gauss–Newton terms of the refinement;
    // the second minimum is checked too unless its scan cost is far worse.
    let gn_at = |s: f64| {
        let (u, jp) = to_pixel(cam, &n_at(s));
        let ut = jp * dn;
        patch_cost_gn(
            ctx.image,
            [u.x as f32, u.y as f32],
            &af,
            t7,
            [ut.x as f32, ut.y as f32],
        )
        .map(|(c, g, h)| (c, g, h, ut.norm()))
    };
    let [(_, s1), (c2_scan, s2)] = minima.0;
    let check_second = c2_scan <= SECOND_SCAN_RATIO * minima.0[0].0.max(SCAN_NOISE_FLOOR);
    let first = gn_at(s1);
    let second = if check_second {
        patch_cost(ctx.image, pix(s2), &af, t7)
    } else {
        None
    };
    let (s, gn, other) = match (first, second) {
        (Some(a), Some(b)) if b < a.0 => match gn_at(s2) {
            Some(g) => (s2, g, Some(a.0)),
            None => (s1, a, Some(b)),
        },
        (Some(a), b) => (s1, a, b),
        (None, Some(_)) => match gn_at(s2) {
            Some(g) => (s2, g, None),
            None => return Outcome::OutOfView,
        },
        (None, None) => return Outcome::OutOfView,
    };
    if other.is_some_and(|o| o < ctx.min_second_best_ratio * gn.0) {
        return Outcome::Ambiguous;
    }

    // Sub-pixel: one Gauss–Newton step on the curve parameter (the scan's parabola already starts
    // it within a fraction of a pixel), at most 1 px; the cost after it is the quadratic model's
    // `c + 2 g δ + h δ²`, which saves a patch evaluation per match.
    let (mut best_c, mut best_s) = (gn.0, s);
    let (c0, g, h, ut_norm) = gn;
    if h > 0.0 && ut_norm > 0.0 {
        let step_px = (-(g / h) as f64 * ut_norm).clamp(-1.0, 1.0);
        let d = (step_px / ut_norm) as f32;
        let predicted = c0 + 2.0 * g * d + h * d * d;
        if predicted < c0 {
            (best_c, best_s) = (predicted, s + step_px / ut_norm);
        }
    }
    let rms = (best_c.max(0.0) / PATCH as f32).sqrt();
    if !(rms <= ctx.max_patch_rms) {
        return Outcome::Photometric;
    }

    // Inverse depth and its standard deviation for a `match_std_px` shift along the curve.
    let s = best_s;
    let (Some(rho), Some(r_plus), Some(r_minus)) = (
        line.inv_depth_at(&n_at(s)),
        line.inv_depth_at(&n_at(s + 1e-4)),
        line.inv_depth_at(&n_at(s - 1e-4)),
    ) else {
        return Outcome::OutOfRange;
    };
    let drho_ds = (r_plus - r_minus) / 2e-4;
    let ut_norm = (to_pixel(cam, &n_at(s)).1 * dn).norm();
    let sigma = (drho_ds.abs() / ut_norm) as f32 * ctx.match_std_px / cos;
    let slack = 2.0 * sigma as f64;
    if !(rho > 0.0 && rho >= lo - slack && rho <= hi + slack && sigma.is_finite() && sigma > 0.0) {
        return Outcome::OutOfRange;
    }
    Outcome::Matched(Estimate {
        rho: rho as f32,
        sigma,
    })
}
