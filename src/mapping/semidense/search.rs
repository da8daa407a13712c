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
    /// Position uncertainty of the view relative to the keyframe, m (see `SemidenseConfig`).
    pub baseline_std_m: f32,
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
    let cell = &d[i..i + stride + 2]; // one bounds check for the four corners
    let (a, b, c, e) = (cell[0], cell[1], cell[stride], cell[stride + 1]);
    let top = a + fx * (b - a);
    let bot = c + fx * (e - c);
    top + fy * (bot - top)
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
    // Lane-wise sums as in `patch_cost_gn` (the same order, so the two costs compare exactly).
    let (mut sv, mut sd2) = ([0.0f32; LANES], [0.0f32; LANES]);
    for (row, dy) in (-HALF..=HALF).enumerate() {
        let c = Cells::gather(img, u, a, dy, t, row);
        for k in 0..LANES {
            let (v, _, _) = c.interpolate(k);
            let r = v - c.t[k];
            sv[k] += v;
            sd2[k] += r * r;
        }
    }
    let (sv, sd2) = (lane_sum(sv), lane_sum(sd2));
    Some(sd2 - sv * sv / PATCH as f32)
}

/// Lanes of the row-wise patch sums: the 7 columns and a zero pad (for SIMD).
const LANES: usize = 8;

#[inline(always)]
fn lane_sum(x: [f32; LANES]) -> f32 {
    ((x[0] + x[4]) + (x[1] + x[5])) + ((x[2] + x[6]) + (x[3] + x[7]))
}

/// One row of the warped 7x7 patch: the corners of each sample's bilinear cell, its weights and
/// the template values (the pad lane is all zero: it adds nothing to any sum). Gathered first, so
/// that the interpolation and the sums run lane by lane.
struct Cells {
    a: [f32; LANES],
    b: [f32; LANES],
    c: [f32; LANES],
    e: [f32; LANES],
    fx: [f32; LANES],
    fy: [f32; LANES],
    t: [f32; LANES],
}

impl Cells {
    /// Row `dy` of the patch `u + A δ` (known to be inside), with template row `row`.
    #[inline(always)]
    fn gather(
        img: &Image<f32>,
        u: [f32; 2],
        a: &[f32; 4],
        dy: i32,
        t: &[f32; PATCH],
        row: usize,
    ) -> Self {
        let (d, s) = (img.data(), img.stride());
        let (bx, by) = (u[0] + a[1] * dy as f32, u[1] + a[3] * dy as f32);
        let mut c = Cells {
            a: [0.0; LANES],
            b: [0.0; LANES],
            c: [0.0; LANES],
            e: [0.0; LANES],
            fx: [0.0; LANES],
            fy: [0.0; LANES],
            t: [0.0; LANES],
        };
        for k in 0..7 {
            let dx = k as f32 - HALF as f32;
            let (x, y) = (bx + a[0] * dx, by + a[2] * dx);
            let (x0, y0) = (x as usize, y as usize);
            c.fx[k] = x - x0 as f32;
            c.fy[k] = y - y0 as f32;
            let i = y0 * s + x0;
            let cell = &d[i..i + s + 2]; // one bounds check for the four corners
            (c.a[k], c.b[k], c.c[k], c.e[k]) = (cell[0], cell[1], cell[s], cell[s + 1]);
            c.t[k] = t[row * 7 + k];
        }
        c
    }

    /// Bilinear value and gradient of lane `k` (as [`sample`]).
    #[inline(always)]
    fn interpolate(&self, k: usize) -> (f32, f32, f32) {
        let (a, b, c, e) = (self.a[k], self.b[k], self.c[k], self.e[k]);
        let (fx, fy) = (self.fx[k], self.fy[k]);
        let top = a + fx * (b - a);
        let bot = c + fx * (e - c);
        (
            top + fy * (bot - top),
            (b - a) + fy * ((e - c) - (b - a)),
            bot - top,
        )
    }
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
    let z = [0.0f32; LANES];
    let (mut sv, mut sd2, mut sdj, mut sj, mut sjj) = (z, z, z, z, z);
    for (row, dy) in (-HALF..=HALF).enumerate() {
        let c = Cells::gather(img, u, a, dy, t, row);
        for k in 0..LANES {
            let (v, gx, gy) = c.interpolate(k);
            let r = v - c.t[k];
            let j = gx * ut[0] + gy * ut[1];
            sv[k] += v;
            sd2[k] += r * r;
            sdj[k] += r * j;
            sj[k] += j;
            sjj[k] += j * j;
        }
    }
    let (sv, sd2, sdj, sj, sjj) = (
        lane_sum(sv),
        lane_sum(sd2),
        lane_sum(sdj),
        lane_sum(sj),
        lane_sum(sjj),
    );
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

/// Samples buffered by the scan before they are scored: a chunk plus the 4 previous samples that
/// the first windows of the chunk still span.
const SCAN_BUF: usize = 64;

/// The epipolar scan's 5-sample zero-mean SSD and its two best interior minima. Samples are
/// buffered and scored a chunk at a time: the window costs of a chunk are independent of each
/// other (a loop the compiler vectorises); only the minima search runs sample by sample.
struct Scan {
    t5: [f32; 5],
    st5: f32,
    /// Samples (NaN outside the image) and their curve parameters; `n` are filled.
    w: [f32; SCAN_BUF],
    s: [f64; SCAN_BUF],
    n: usize,
    /// Costs of the two windows before the next one (∞ after a gap or at the start).
    c_prev2: f32,
    c_prev: f32,
    minima: Minima,
}

impl Scan {
    fn new(t5: [f32; 5], st5: f32) -> Self {
        Scan {
            t5,
            st5,
            w: [0.0; SCAN_BUF],
            s: [0.0; SCAN_BUF],
            n: 0,
            c_prev2: f32::INFINITY,
            c_prev: f32::INFINITY,
            minima: Minima([(f32::INFINITY, f64::NAN); 2]),
        }
    }

    #[inline(always)]
    fn push(&mut self, v: f32, s: f64) {
        self.w[self.n] = v;
        self.s[self.n] = s;
        self.n += 1;
        if self.n == SCAN_BUF {
            self.flush();
            // keep the last 4 samples: the next windows still span them
            self.w.copy_within(SCAN_BUF - 4.., 0);
            self.s.copy_within(SCAN_BUF - 4.., 0);
            self.n = 4;
        }
    }

    /// Scores the windows ending at samples `4..n` (those before were scored by the previous
    /// chunk) and updates the minima.
    fn flush(&mut self) {
        let n = self.n;
        if n < 5 {
            return;
        }
        let m = n - 4;
        let t = self.t5;
        let st5 = self.st5;
        let w = &self.w;
        let (w0, w1, w2, w3, w4) = (&w[..m], &w[1..m + 1], &w[2..m + 2], &w[3..m + 3], &w[4..n]);
        let mut c = [0.0f32; SCAN_BUF];
        for (k, ck) in c[..m].iter_mut().enumerate() {
            let (a, b, d, e, f) = (w0[k], w1[k], w2[k], w3[k], w4[k]);
            let sv = a + b + d + e + f;
            let svv = a * a + b * b + d * d + e * e + f * f;
            let svt = a * t[0] + b * t[1] + d * t[2] + e * t[3] + f * t[4];
            *ck = svv - sv * sv * 0.2 - 2.0 * svt + st5;
        }
        let (mut c_prev2, mut c_prev) = (self.c_prev2, self.c_prev);
        for (k, &ck) in c[..m].iter().enumerate() {
            if ck.is_nan() {
                // a window over a gap: the scan restarts after it
                (c_prev2, c_prev) = (f32::INFINITY, f32::INFINITY);
                continue;
            }
            // Only interior minima: one at the end of the scan (or of a gap) may continue outside
            // the range, and then the match is elsewhere. (Tested first: beating the second best,
            // rarely true once the scan is under way, so the branch predicts well.)
            if c_prev < self.minima.0[1].0
                && c_prev <= c_prev2
                && c_prev < ck
                && c_prev2 < f32::INFINITY
            {
                // sub-sample position from the parabola through the three costs; the window
                // ending at sample k + 4 is centred on sample k + 2
                let den = c_prev2 - 2.0 * c_prev + ck;
                let d = if den > 0.0 {
                    (0.5 * (c_prev2 - ck) / den).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                let s = &self.s;
                self.minima
                    .push(c_prev, s[k + 1] + d as f64 * 0.5 * (s[k + 2] - s[k]));
            }
            (c_prev2, c_prev) = (c_prev, ck);
        }
        (self.c_prev2, self.c_prev) = (c_prev2, c_prev);
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
    let mut scan = Scan::new(t5, st5);
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
            let v = if ux >= 0.0 && uy >= 0.0 && ux < x_lim && uy < y_lim {
                sample(vd, vs, ux, uy)
            } else {
                f32::NAN // a gap: no window containing it is scored
            };
            scan.push(v, s);
        }
        off -= len;
        s_k = s_k1;
        u_k = u_k1;
    }
    scan.flush();
    let minima = scan.minima;
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
    let sigma_match = (drho_ds.abs() / ut_norm) as f32 * ctx.match_std_px / cos;
    let sigma_pose = (rho / ctx.baseline_m) as f32 * ctx.baseline_std_m;
    let sigma = sigma_match.hypot(sigma_pose);
    let slack = 2.0 * sigma as f64;
    if !(rho > 0.0 && rho >= lo - slack && rho <= hi + slack && sigma.is_finite() && sigma > 0.0) {
        return Outcome::OutOfRange;
    }
    Outcome::Matched(Estimate {
        rho: rho as f32,
        sigma,
    })
}
