//! Corners and binary descriptors on a keyframe's image, and guided matching between two images of
//! the same place.
//!
//! Loop closure has to tie a new keyframe to an old one seen from about the same place. The
//! direct odometry's photometric alignment cannot do it: its basin is a few pixels, and after a
//! lap the drift (a few degrees of heading, decimetres of position) moves the image by tens of
//! pixels, the exposure has changed, and one of the two images may be motion-blurred. So the two
//! images are matched with features, as VINS-Mono and ORB-SLAM do for their loops:
//!
//! * **Corners**: the Shi–Tomasi score (Shi & Tomasi, *Good Features to Track*, CVPR 1994), the
//!   smaller eigenvalue of the structure tensor (gradient products summed over a small window),
//!   large only where the image varies in two directions, i.e. where a position is defined in both
//!   axes. At most one corner per grid cell (spread over the image, which PnP wants), the
//!   strongest ones kept.
//! * **Descriptors**: BRIEF (Calonder et al., *BRIEF: Binary Robust Independent Elementary
//!   Features*, ECCV 2010): 256 comparisons of the smoothed intensity at pairs of points of a fixed
//!   random pattern in a 31×31 patch around the corner. A comparison only depends on the order of
//!   two intensities, so the descriptor is unchanged by an affine brightness change `a·I + b`
//!   (`a > 0`) — the exposure and gain changes between the two visits. Smoothing (a 5×5 box, read
//!   from an integral image) makes the comparisons robust to noise and mild blur. The descriptor is
//!   **not rotation-invariant**: the pattern is not steered by an orientation, because a drone
//!   flies upright and the two images of a loop differ by a few degrees of roll at most; leaving
//!   the orientation out makes the descriptor more discriminative and cheaper. Nor is it
//!   scale-invariant (one image level): the loop's candidates are keyframes seen from about the
//!   same place.
//! * **Guided matching** (ORB-SLAM's "search by projection", VINS-Mono's loop matching with a
//!   prior): since the relative pose is roughly known, each reference feature's pixel in the query
//!   image is predicted by the caller, and only query features within `radius_px` of the
//!   prediction are candidates. The best one by Hamming distance is kept if it is close enough
//!   and clearly better than the second best there (Lowe's ratio test), then the matches are made
//!   one-to-one. The small search region is what makes the ambiguity of a repetitive scene
//!   manageable.

use crate::camera::CameraModel;
use crate::image::Image;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

/// Radius of the BRIEF patch, px: the comparisons are drawn from a 31×31 patch.
pub const PATCH_RADIUS_PX: usize = 15;

/// Radius of the box filter averaged at each comparison point, px (5×5).
const SMOOTH_RADIUS_PX: usize = 2;

/// Comparisons (bits) per descriptor.
const DESCRIPTOR_BITS: usize = 256;

/// Distance from the image border a feature keeps so that its descriptor's smoothed patch lies
/// inside the image, px.
const DESCRIPTOR_BORDER_PX: usize = PATCH_RADIUS_PX + SMOOTH_RADIUS_PX;

/// `[loop_closure]` detection settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    /// Features kept per image at most (the highest scores), count. Default 600: only the corners
    /// that fall on the old keyframe's semidense points get a depth (a fifth to a half on S-V101),
    /// and after guided matching 20–100 remain for the PnP; brute-force matching stays well under
    /// a millisecond.
    pub max_features: usize,
    /// Side of the grid cells, px: at most one corner per `cell_px × cell_px` cell, so that the
    /// features spread over the image instead of clustering on the most textured object.
    /// Default 12 (62 × 40 cells on a 752×480 image). 0 is treated as 1.
    pub cell_px: usize,
    /// A corner's score (the smaller eigenvalue of the structure tensor *averaged* over the
    /// window, with gradients in grey levels per pixel of the 0..255 image) is at least this,
    /// (grey levels / px)². Default 4: a sharp right-angled corner between areas 15 grey levels
    /// apart scores ≈ 14 (≈ 3–6 blurred over a few pixels, 25 for 20 grey levels), white noise of
    /// σ = 2 grey levels ≈ 0.5 (2 at most), so noise is not taken for corners while a dim,
    /// underexposed image (gradients scaled by the exposure, the score by its square) still has
    /// some.
    pub min_score: f32,
    /// Half side of the structure tensor's window, px: the window is `(2r+1)²`. Default 2 (5×5),
    /// the usual Shi–Tomasi/Harris block size for a 752×480 image.
    pub window_radius_px: usize,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig {
            max_features: 600,
            cell_px: 12,
            min_score: 4.0,
            window_radius_px: 2,
        }
    }
}

/// A 256-bit BRIEF descriptor: bit `i` (word `i / 64`, bit `i % 64`) is the `i`-th comparison.
pub type Descriptor = [u64; 4];

/// A corner with its descriptor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Feature {
    /// Column of the corner (an integer pixel, pixel centres at integers), px.
    pub x_px: f32,
    /// Row of the corner, px.
    pub y_px: f32,
    /// Shi–Tomasi score (see [`FeatureConfig::min_score`]), (grey levels / px)².
    pub score: f32,
    /// BRIEF descriptor of the patch around the corner.
    pub descriptor: Descriptor,
}

/// Corners of `image` with their BRIEF descriptors, strongest first (ties by row, then column).
///
/// Gradients are Sobel's (scaled to grey levels per pixel); the score is the smaller eigenvalue
/// of the structure tensor averaged over a `(2r+1)²` window. In each `cell_px` grid cell the
/// highest score is a corner if it is at least `min_score`, a local maximum of its 3×3
/// neighbourhood (so that one corner on a cell boundary does not give two features) and at least
/// [`PATCH_RADIUS_PX`]` + 2` pixels from the border (the descriptor's patch). The `max_features`
/// highest scores are kept. Deterministic; an image too small for one patch gives no feature.
pub fn detect(image: &Image<u8>, cfg: &FeatureConfig) -> Vec<Feature> {
    let (w, h) = (image.width(), image.height());
    let r = cfg.window_radius_px;
    // The local-maximum test reads scores one pixel outside the feature region, and a score reads
    // gradients r pixels further, which need one more pixel for the Sobel kernel.
    let margin = DESCRIPTOR_BORDER_PX.max(r.saturating_add(2));
    let min_side = margin.saturating_mul(2).saturating_add(1);
    if cfg.max_features == 0 || w < min_side || h < min_side {
        return Vec::new();
    }
    let score = min_eigenvalue_map(image, r, margin - 1);

    // One candidate per grid cell.
    let cell = cfg.cell_px.max(1);
    let mut candidates: Vec<(f32, usize, usize)> = Vec::new();
    for cell_y in (0..h).step_by(cell) {
        let (y_lo, y_hi) = (
            cell_y.max(margin),
            cell_y.saturating_add(cell).min(h - margin),
        );
        if y_lo >= y_hi {
            continue;
        }
        for cell_x in (0..w).step_by(cell) {
            let (x_lo, x_hi) = (
                cell_x.max(margin),
                cell_x.saturating_add(cell).min(w - margin),
            );
            if x_lo >= x_hi {
                continue;
            }
            let mut best = (f32::NEG_INFINITY, 0, 0);
            for y in y_lo..y_hi {
                let row = &score[y * w..(y + 1) * w];
                for (x, &s) in row.iter().enumerate().take(x_hi).skip(x_lo) {
                    if s > best.0 {
                        best = (s, x, y);
                    }
                }
            }
            let (s, x, y) = best;
            if s >= cfg.min_score && is_local_max(&score, w, x, y) {
                candidates.push(best);
            }
        }
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.2.cmp(&b.2)).then(a.1.cmp(&b.1)));
    candidates.truncate(cfg.max_features);
    if candidates.is_empty() {
        return Vec::new();
    }

    let integral = integral_image(image);
    let pattern = brief_pattern();
    candidates
        .into_iter()
        .map(|(s, x, y)| Feature {
            x_px: x as f32,
            y_px: y as f32,
            score: s,
            descriptor: describe(&integral, w + 1, x, y, pattern),
        })
        .collect()
}

/// Number of differing bits of two descriptors (0..=256).
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

/// Guided matching settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchConfig {
    /// Query features within this distance of a reference feature's predicted pixel are its
    /// candidates, px. Default 150: a heading error of 5° moves a 752-px-wide image (focal length
    /// ≈ 460 px) by ≈ 40 px, and a position error of 0.5 m at 2 m depth by ≈ 115 px — the drift
    /// S-V101's odometry reaches between loops (40 and 80 px closed fewer loops there; the ratio
    /// test and the PnP's RANSAC take the wrong matches a wider radius lets in).
    pub radius_px: f32,
    /// A match's Hamming distance is at most this, bits (of 256). Default 64: the same corner
    /// under noise, blur and a small viewpoint change differs by ≈ 0–40 bits; unrelated corners
    /// by 128 on average but with σ ≈ 30–40 bits (BRIEF's bits are correlated), a few per cent
    /// of them within 64 — which the ratio test and the caller's RANSAC deal with.
    pub max_distance: u32,
    /// Ratio test: the best distance is below `ratio` times the second best within the radius
    /// (dimensionless). Default 0.8 (Lowe's value); a candidate alone in the radius passes.
    pub ratio: f32,
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            radius_px: 150.0,
            max_distance: 64,
            ratio: 0.8,
        }
    }
}

/// A reference feature's predicted pixel for [`match_guided`]: its point `p_cam` (in the query
/// camera's frame, any length along its ray) projected, if that lands inside the image.
pub fn predicted_px(camera: &CameraModel, p_cam: &Vector3<f64>) -> Option<[f32; 2]> {
    camera
        .project(p_cam)
        .filter(|uv| camera.in_image(uv, 0.0))
        .map(|uv| [uv.x as f32, uv.y as f32])
}

/// Matches reference features (e.g. an old keyframe's) to `query` features (a new image) given
/// each reference feature's predicted pixel in the query image (`None`: not predicted, e.g.
/// behind the camera or without depth).
///
/// For each predicted reference feature, the query feature within `radius_px` of the prediction
/// with the smallest Hamming distance is its match if that distance is at most `max_distance`
/// and below `ratio` times the second smallest distance within the radius (equal distances fail;
/// a single candidate passes). Then the matches are made one-to-one: a query feature claimed by
/// several reference features keeps only the one at the smallest distance (the lowest reference
/// index on a tie). Returns `(reference index, query index)` pairs sorted by reference index.
///
/// `predicted_px[i]` goes with `reference[i]`; extra entries of the longer slice are ignored.
/// A non-finite prediction or a negative or NaN `radius_px` gives no candidate.
pub fn match_guided(
    predicted_px: &[Option<[f32; 2]>],
    reference: &[Descriptor],
    query: &[Feature],
    cfg: &MatchConfig,
) -> Vec<(usize, usize)> {
    if cfg.radius_px.is_nan() || cfg.radius_px < 0.0 || query.is_empty() {
        return Vec::new();
    }
    let radius_sq = cfg.radius_px * cfg.radius_px;
    // Per query feature: (distance, reference index) of the reference feature holding it.
    let mut claims: Vec<Option<(u32, usize)>> = vec![None; query.len()];
    for (i, (prediction, descriptor)) in predicted_px.iter().zip(reference).enumerate() {
        let Some([px, py]) = *prediction else {
            continue;
        };
        let mut best: Option<(u32, usize)> = None;
        let mut second = u32::MAX;
        // A NaN distance compares false: not a candidate.
        let candidates = query.iter().enumerate().filter(|(_, q)| {
            let (dx, dy) = (q.x_px - px, q.y_px - py);
            dx * dx + dy * dy <= radius_sq
        });
        for (j, q) in candidates {
            let d = hamming(descriptor, &q.descriptor);
            match best {
                Some((best_d, _)) if d >= best_d => second = second.min(d),
                _ => {
                    if let Some((best_d, _)) = best {
                        second = best_d;
                    }
                    best = Some((d, j));
                }
            }
        }
        let Some((d, j)) = best else {
            continue;
        };
        if d > cfg.max_distance {
            continue;
        }
        let distinct = second == u32::MAX || (d as f32) < cfg.ratio * second as f32;
        if !distinct {
            continue;
        }
        match claims[j] {
            Some((held, _)) if held <= d => {}
            _ => claims[j] = Some((d, i)),
        }
    }
    let mut pairs: Vec<(usize, usize)> = claims
        .iter()
        .enumerate()
        .filter_map(|(j, claim)| claim.map(|(_, i)| (i, j)))
        .collect();
    pairs.sort_unstable();
    pairs
}

/// Shi–Tomasi scores of `image`, row-major with stride = width, valid on the pixels at least `lo`
/// from the border (0 elsewhere). Needs `lo >= r + 1` and an image larger than `2 lo`.
///
/// Row by row: the gradient products of the `2r + 1` rows a scored row's windows reach are kept
/// in a ring (a few tens of kB, in cache), summed down the columns, then along the row.
fn min_eigenvalue_map(image: &Image<u8>, r: usize, lo: usize) -> Vec<f32> {
    let (w, h) = (image.width(), image.height());
    debug_assert!(lo > r && w > 2 * lo && h > 2 * lo);
    let side = 2 * r + 1;
    let inv_area = 1.0 / (side * side) as f32;
    let inner = w - 2 * lo;
    // Ring slot of image row y: the products xx, xy, yy, each `w` long.
    let mut ring = vec![0.0f32; side * 3 * w];
    let mut scratch = vec![0.0f32; 2 * w];
    let mut column_sums = vec![0.0f32; 3 * w];
    let mut row_sums = vec![0.0f32; 3 * inner];
    let mut score = vec![0.0f32; w * h];
    for y in lo - r..lo + r {
        let slot = (y % side) * 3 * w;
        gradient_products(image, y, &mut ring[slot..slot + 3 * w], &mut scratch);
    }
    for y in lo..h - lo {
        let slot = ((y + r) % side) * 3 * w;
        gradient_products(image, y + r, &mut ring[slot..slot + 3 * w], &mut scratch);

        column_sums.fill(0.0);
        for products in ring.chunks_exact(3 * w) {
            for (acc, &v) in column_sums.iter_mut().zip(products) {
                *acc += v;
            }
        }
        // Along the row: the window of column x starts at x - r.
        row_sums.fill(0.0);
        for (sums, columns) in row_sums
            .chunks_exact_mut(inner)
            .zip(column_sums.chunks_exact(w))
        {
            for start in lo - r..=lo + r {
                for (acc, &v) in sums.iter_mut().zip(&columns[start..start + inner]) {
                    *acc += v;
                }
            }
        }
        let (sum_xx, rest) = row_sums.split_at(inner);
        let (sum_xy, sum_yy) = rest.split_at(inner);
        let out = &mut score[y * w + lo..y * w + w - lo];
        for (s, ((&a, &b), &c)) in out.iter_mut().zip(sum_xx.iter().zip(sum_xy).zip(sum_yy)) {
            let (a, b, c) = (a * inv_area, b * inv_area, c * inv_area);
            let half_diff = 0.5 * (a - c);
            *s = 0.5 * (a + c) - (half_diff * half_diff + b * b).sqrt();
        }
    }
    score
}

/// Sobel gradient products of row `y` (1 ≤ y < height − 1) into `out` = `[xx | xy | yy]`, each
/// `width` long, in (grey levels / px)²; the first and last columns are 0. `scratch`: `2 width`.
fn gradient_products(image: &Image<u8>, y: usize, out: &mut [f32], scratch: &mut [f32]) {
    // Sobel's kernel gives 8 × the gradient in grey levels per pixel.
    const SOBEL_SCALE: f32 = 1.0 / 8.0;
    let w = image.width();
    let (up, mid, down) = (image.row(y - 1), image.row(y), image.row(y + 1));
    // The vertical [1 2 1] smoothing and [-1 0 1] difference of the three rows.
    let (smooth, diff) = scratch.split_at_mut(w);
    for ((((s, d), &u), &m), &b) in smooth
        .iter_mut()
        .zip(diff.iter_mut())
        .zip(up)
        .zip(mid)
        .zip(down)
    {
        let (u, m, b) = (u as f32, m as f32, b as f32);
        *s = u + 2.0 * m + b;
        *d = b - u;
    }
    let (xx, rest) = out.split_at_mut(w);
    let (xy, yy) = rest.split_at_mut(w);
    let outputs = xx[1..w - 1]
        .iter_mut()
        .zip(&mut xy[1..w - 1])
        .zip(&mut yy[1..w - 1]);
    let inputs = smooth[..w - 2]
        .iter()
        .zip(&smooth[2..])
        .zip(diff[..w - 2].iter().zip(&diff[1..w - 1]).zip(&diff[2..]));
    for (((xx, xy), yy), ((&s0, &s2), ((&d0, &d1), &d2))) in outputs.zip(inputs) {
        let gx = (s2 - s0) * SOBEL_SCALE;
        let gy = (d0 + 2.0 * d1 + d2) * SOBEL_SCALE;
        *xx = gx * gx;
        *xy = gx * gy;
        *yy = gy * gy;
    }
}

/// Whether the score at `(x, y)` is a maximum of its 3×3 neighbourhood: strictly above the
/// neighbours before it in raster order, at least the ones after it (so that a plateau gives one
/// maximum, not several). `(x, y)` is at least one pixel from the border.
fn is_local_max(score: &[f32], w: usize, x: usize, y: usize) -> bool {
    let s = score[y * w + x];
    for dy in 0..3 {
        for dx in 0..3 {
            let (nx, ny) = (x + dx - 1, y + dy - 1);
            if (nx, ny) == (x, y) {
                continue;
            }
            let n = score[ny * w + nx];
            let before = dy == 0 || (dy == 1 && dx == 0);
            if n > s || (before && n == s) {
                return false;
            }
        }
    }
    true
}

/// Integral image with a zero first row and column: entry `(x, y)` of the `(w + 1) × (h + 1)`
/// table is the sum of the pixels left of column `x` and above row `y`. Wrapping `u32`
/// arithmetic: a box sum (at most 25 · 255) is exact modulo 2³² whatever the image size.
fn integral_image(image: &Image<u8>) -> Vec<u32> {
    let (w, h) = (image.width(), image.height());
    let stride = w + 1;
    let mut table = vec![0u32; stride * (h + 1)];
    for y in 0..h {
        let mut row_sum = 0u32;
        for (x, &v) in image.row(y).iter().enumerate() {
            row_sum = row_sum.wrapping_add(v as u32);
            let above = table[y * stride + x + 1];
            table[(y + 1) * stride + x + 1] = above.wrapping_add(row_sum);
        }
    }
    table
}

/// Sum of the 5×5 box centred on `(x, y)` (at least [`SMOOTH_RADIUS_PX`] from the border).
#[inline]
fn box_sum(table: &[u32], stride: usize, x: usize, y: usize) -> u32 {
    let (x0, x1) = (x - SMOOTH_RADIUS_PX, x + SMOOTH_RADIUS_PX + 1);
    let (y0, y1) = (y - SMOOTH_RADIUS_PX, y + SMOOTH_RADIUS_PX + 1);
    table[y1 * stride + x1]
        .wrapping_sub(table[y0 * stride + x1])
        .wrapping_sub(table[y1 * stride + x0])
        .wrapping_add(table[y0 * stride + x0])
}

/// The BRIEF descriptor at `(x, y)`, at least [`DESCRIPTOR_BORDER_PX`] from the border: bit `i`
/// is set if the smoothed intensity at the pattern's first point is below the one at its second.
fn describe(
    table: &[u32],
    stride: usize,
    x: usize,
    y: usize,
    pattern: &[[i8; 4]; DESCRIPTOR_BITS],
) -> Descriptor {
    let at = |dx: i8, dy: i8| {
        box_sum(
            table,
            stride,
            x.wrapping_add_signed(dx as isize),
            y.wrapping_add_signed(dy as isize),
        )
    };
    let mut descriptor = [0u64; 4];
    for (i, &[ax, ay, bx, by]) in pattern.iter().enumerate() {
        if at(ax, ay) < at(bx, by) {
            descriptor[i / 64] |= 1 << (i % 64);
        }
    }
    descriptor
}

/// The comparison pattern `[x_a, y_a, x_b, y_b]` (offsets from the corner, px): points drawn
/// from an isotropic Gaussian of σ = 31/5 px (BRIEF's "G II" sampling) rounded and clamped to
/// the 31×31 patch, the two points of a pair distinct. Generated once from a fixed seed with only
/// integer and basic floating-point operations (no `ln`/`cos`, whose last bit may differ between
/// platforms), so the descriptors are the same on every run and every machine.
fn brief_pattern() -> &'static [[i8; 4]; DESCRIPTOR_BITS] {
    static PATTERN: OnceLock<[[i8; 4]; DESCRIPTOR_BITS]> = OnceLock::new();
    PATTERN.get_or_init(|| {
        // xorshift64* (Vigna 2016) with a fixed seed.
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut uniform = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            // 53 random bits into [0, 1).
            (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        };
        let sigma = (2 * PATCH_RADIUS_PX + 1) as f64 / 5.0;
        let limit = PATCH_RADIUS_PX as f64;
        // A standard normal deviate as the sum of 12 uniforms minus 6 (Irwin–Hall: mean 0,
        // variance 1, tails cut at ±6 σ, far outside the patch anyway).
        let mut coordinate = || {
            let normal = (0..12).map(|_| uniform()).sum::<f64>() - 6.0;
            (normal * sigma).round().clamp(-limit, limit) as i8
        };
        let mut pattern = [[0i8; 4]; DESCRIPTOR_BITS];
        for pair in pattern.iter_mut() {
            loop {
                let candidate = [coordinate(), coordinate(), coordinate(), coordinate()];
                if candidate[..2] != candidate[2..] {
                    *pair = candidate;
                    break;
                }
            }
        }
        pattern
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift64* for the synthetic scenes.
    struct Rng(u64);

    impl Rng {
        fn next_u64(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        /// Uniform in [0, 1).
        fn uniform(&mut self) -> f32 {
            (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
        }
        /// Uniform in [lo, hi).
        fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.uniform()
        }
    }

    const W: usize = 752;
    const H: usize = 480;
    /// Extra canvas around the images, so that shifted crops stay on the scene.
    const PAD: usize = 40;

    /// A textured scene of `(W + 2 PAD) × (H + 2 PAD)` grey levels: overlapping rectangles of
    /// random sizes, angles and contrasts (corners where their edges meet) over a fine random
    /// texture, edges softened by two passes of a 3×3 box.
    fn scene(seed: u64) -> Image<f32> {
        let (cw, ch) = (W + 2 * PAD, H + 2 * PAD);
        let mut rng = Rng(seed);
        let mut canvas = Image::<f32>::from_fn(cw, ch, |_, _| 128.0);
        for _ in 0..700 {
            // A rectangle at a random angle, so that its corners differ from one another.
            let (cx, cy) = (rng.range(0.0, cw as f32), rng.range(0.0, ch as f32));
            let (half_a, half_b) = (rng.range(3.0, 25.0), rng.range(3.0, 25.0));
            let (sin, cos) = rng.range(0.0, std::f32::consts::PI).sin_cos();
            let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
            let delta = sign * rng.range(15.0, 45.0);
            let reach = half_a.hypot(half_b);
            let span = |c: f32, n: usize| {
                (
                    (c - reach).max(0.0) as usize,
                    ((c + reach).max(0.0) as usize + 1).min(n),
                )
            };
            let ((xa, xb), (ya, yb)) = (span(cx, cw), span(cy, ch));
            for y in ya..yb {
                for x in xa..xb {
                    let (px, py) = (x as f32 - cx, y as f32 - cy);
                    let (u, v) = (cos * px + sin * py, -sin * px + cos * py);
                    if u.abs() < half_a && v.abs() < half_b {
                        canvas.set(x, y, canvas.get(x, y) + delta);
                    }
                }
            }
        }
        // Fine texture everywhere (bilinear interpolation of random values on a 6-px grid), as
        // on real surfaces: without it, unrelated rectangle corners look alike.
        const GRID_PX: usize = 6;
        let (gw, gh) = (cw / GRID_PX + 2, ch / GRID_PX + 2);
        let grid: Vec<f32> = (0..gw * gh).map(|_| rng.range(-12.0, 12.0)).collect();
        for y in 0..ch {
            for x in 0..cw {
                let (gx, gy) = (x / GRID_PX, y / GRID_PX);
                let fx = (x % GRID_PX) as f32 / GRID_PX as f32;
                let fy = (y % GRID_PX) as f32 / GRID_PX as f32;
                let g = |i: usize, j: usize| grid[(gy + j) * gw + gx + i];
                let top = g(0, 0) + fx * (g(1, 0) - g(0, 0));
                let bottom = g(0, 1) + fx * (g(1, 1) - g(0, 1));
                canvas.set(x, y, canvas.get(x, y) + top + fy * (bottom - top));
            }
        }
        for _ in 0..2 {
            let src = canvas.clone();
            canvas = Image::from_fn(cw, ch, |x, y| {
                let mut sum = 0.0;
                for yy in y.saturating_sub(1)..(y + 2).min(ch) {
                    for xx in x.saturating_sub(1)..(x + 2).min(cw) {
                        sum += src.get(xx, yy);
                    }
                }
                sum / 9.0
            });
        }
        canvas
    }

    /// The `W × H` image whose pixel `(x, y)` sees scene point `(x + PAD - dx, y + PAD - dy)`
    /// (the scene moved by `(dx, dy)` px), brightness `a·I + b`, plus uniform noise of ±`noise`.
    fn view(
        scene: &Image<f32>,
        dx: isize,
        dy: isize,
        a: f32,
        b: f32,
        noise: f32,
        seed: u64,
    ) -> Image<u8> {
        let mut rng = Rng(seed);
        Image::from_fn(W, H, |x, y| {
            let sx = (x + PAD).wrapping_add_signed(-dx);
            let sy = (y + PAD).wrapping_add_signed(-dy);
            let v = a * scene.get(sx, sy) + b + rng.range(-noise, noise);
            v.round().clamp(0.0, 255.0) as u8
        })
    }

    const SHIFT: (isize, isize) = (9, -6);

    /// Reference and query features of one scene, the query moved by `SHIFT`, darker and noisier.
    fn reference_and_query() -> (Vec<Feature>, Vec<Feature>) {
        let s = scene(7);
        let reference = view(&s, 0, 0, 1.0, 0.0, 1.0, 11);
        let query = view(&s, SHIFT.0, SHIFT.1, 0.7, 30.0, 2.0, 12);
        // 300 corners on a 16 px grid: the density the matching tests' bounds were set for (the
        // default's 600 on 12 px put more unrelated corners within a radius).
        let cfg = FeatureConfig {
            max_features: 300,
            cell_px: 16,
            ..FeatureConfig::default()
        };
        (detect(&reference, &cfg), detect(&query, &cfg))
    }

    /// Predictions `reference + SHIFT + offset + a deterministic error of up to ±3 px`.
    fn predictions(reference: &[Feature], offset: [f32; 2]) -> Vec<Option<[f32; 2]>> {
        let mut rng = Rng(99);
        reference
            .iter()
            .map(|f| {
                Some([
                    f.x_px + SHIFT.0 as f32 + offset[0] + rng.range(-3.0, 3.0),
                    f.y_px + SHIFT.1 as f32 + offset[1] + rng.range(-3.0, 3.0),
                ])
            })
            .collect()
    }

    fn descriptors(features: &[Feature]) -> Vec<Descriptor> {
        features.iter().map(|f| f.descriptor).collect()
    }

    fn is_correct(r: &Feature, q: &Feature) -> bool {
        (q.x_px - r.x_px - SHIFT.0 as f32).abs() <= 1.0
            && (q.y_px - r.y_px - SHIFT.1 as f32).abs() <= 1.0
    }

    #[test]
    fn guided_matching_finds_the_shifted_corners_under_a_brightness_change() {
        let (reference, query) = reference_and_query();
        assert!(
            reference.len() >= 200,
            "{} reference features",
            reference.len()
        );
        assert!(query.len() >= 200, "{} query features", query.len());
        let pairs = match_guided(
            &predictions(&reference, [0.0, 0.0]),
            &descriptors(&reference),
            &query,
            &MatchConfig::default(),
        );
        let correct = pairs
            .iter()
            .filter(|&&(i, j)| is_correct(&reference[i], &query[j]))
            .count();
        assert!(pairs.len() >= 100, "{} matches", pairs.len());
        assert!(
            correct as f32 > 0.9 * pairs.len() as f32,
            "{correct} of {} matches correct",
            pairs.len()
        );
        // Output contract: sorted by reference index, one-to-one.
        assert!(pairs.windows(2).all(|p| p[0].0 < p[1].0));
        let mut queries: Vec<usize> = pairs.iter().map(|p| p.1).collect();
        queries.sort_unstable();
        queries.dedup();
        assert_eq!(queries.len(), pairs.len());
    }

    #[test]
    fn a_wrong_prediction_gives_few_matches() {
        let (reference, query) = reference_and_query();
        let reference_descriptors = descriptors(&reference);
        let cfg = MatchConfig {
            radius_px: 40.0,
            ..MatchConfig::default()
        };
        let good = match_guided(
            &predictions(&reference, [0.0, 0.0]),
            &reference_descriptors,
            &query,
            &cfg,
        );
        // 160 px away: the true correspondence is never within the 40 px radius.
        let wrong = match_guided(
            &predictions(&reference, [160.0, 120.0]),
            &reference_descriptors,
            &query,
            &cfg,
        );
        assert!(
            wrong.len() * 5 <= good.len() && wrong.len() * 8 <= reference.len(),
            "{} matches with a wrong prediction, {} with the right one, {} features",
            wrong.len(),
            good.len(),
            reference.len()
        );
        // No prediction, no match.
        let none = vec![None; reference.len()];
        assert!(match_guided(&none, &reference_descriptors, &query, &cfg).is_empty());
    }

    #[test]
    fn hamming_counts_differing_bits() {
        let a: Descriptor = [0x0123_4567_89AB_CDEF, 0, u64::MAX, 0xF0F0_F0F0_0F0F_0F0F];
        assert_eq!(hamming(&a, &a), 0);
        assert_eq!(hamming(&a, &a.map(|w| !w)), 256);
        let mut b = a;
        b[3] ^= 1 << 63;
        b[1] ^= 0b101;
        assert_eq!(hamming(&a, &b), 3);
        assert_eq!(hamming(&[0; 4], &[u64::MAX, 0, 0, 0]), 64);
    }

    #[test]
    fn tiny_flat_and_degenerate_inputs_give_no_features() {
        let cfg = FeatureConfig::default();
        for (w, h) in [
            (0, 0),
            (0, 10),
            (1, 1),
            (10, 10),
            (34, 34),
            (100, 3),
            (3, 100),
        ] {
            let mut rng = Rng(5);
            let image = Image::from_fn(w, h, |_, _| (rng.next_u64() >> 56) as u8);
            assert!(detect(&image, &cfg).is_empty(), "{w}x{h}");
        }
        // A flat image and a smooth ramp (one gradient direction): no corner.
        let flat = Image::from_fn(W, H, |_, _| 90u8);
        assert!(detect(&flat, &cfg).is_empty());
        let ramp = Image::from_fn(W, H, |x, _| (x / 3) as u8);
        assert!(detect(&ramp, &cfg).is_empty());
        // The smallest image with room for a patch: at most its centre pixel, no panic.
        let s = scene(3);
        let small = Image::from_fn(35, 35, |x, y| s.get(x + 100, y + 100).round() as u8);
        let features = detect(&small, &cfg);
        assert!(features.len() <= 1);
        assert!(features.iter().all(|f| f.x_px == 17.0 && f.y_px == 17.0));
        // Degenerate settings do not panic.
        let textured = view(&s, 0, 0, 1.0, 0.0, 1.0, 1);
        let zero = FeatureConfig {
            max_features: 0,
            ..cfg.clone()
        };
        assert!(detect(&textured, &zero).is_empty());
        let huge_window = FeatureConfig {
            window_radius_px: usize::MAX,
            ..cfg.clone()
        };
        assert!(detect(&textured, &huge_window).is_empty());
        let unit_cells = FeatureConfig {
            cell_px: 0,
            max_features: 50,
            ..cfg.clone()
        };
        assert_eq!(detect(&textured, &unit_cells).len(), 50);
        // Empty or mismatched matching inputs.
        let bad = MatchConfig {
            radius_px: f32::NAN,
            ..MatchConfig::default()
        };
        let q = detect(&textured, &cfg);
        let p = vec![Some([q[0].x_px, q[0].y_px])];
        assert!(match_guided(&p, &[q[0].descriptor], &q, &bad).is_empty());
        assert!(match_guided(&p, &[], &q, &MatchConfig::default()).is_empty());
        assert!(match_guided(&p, &[q[0].descriptor], &[], &MatchConfig::default()).is_empty());
        let nan = vec![Some([f32::NAN, 3.0])];
        assert!(match_guided(&nan, &[q[0].descriptor], &q, &MatchConfig::default()).is_empty());
    }

    fn feature_at(x_px: f32, y_px: f32, descriptor: Descriptor) -> Feature {
        Feature {
            x_px,
            y_px,
            score: 10.0,
            descriptor,
        }
    }

    /// `d` with its first `n` bits flipped.
    fn flipped(d: Descriptor, n: usize) -> Descriptor {
        let mut out = d;
        for i in 0..n {
            out[i / 64] ^= 1 << (i % 64);
        }
        out
    }

    #[test]
    fn matches_are_one_to_one_keeping_the_closest_descriptor() {
        let d: Descriptor = [0xDEAD_BEEF_0000_FFFF, 0x1234, 0, u64::MAX];
        let query = [
            feature_at(100.0, 100.0, d),
            feature_at(400.0, 300.0, flipped(d, 100)),
        ];
        // Three references predicted near query 0 (its only candidate in the radius), at
        // distances 3, 1 and 5; a fourth near query 1.
        let reference = [flipped(d, 3), flipped(d, 1), flipped(d, 5), flipped(d, 110)];
        let predicted = [
            Some([102.0, 99.0]),
            Some([95.0, 110.0]),
            Some([100.0, 100.0]),
            Some([390.0, 310.0]),
        ];
        let pairs = match_guided(&predicted, &reference, &query, &MatchConfig::default());
        assert_eq!(pairs, vec![(1, 0), (3, 1)]);
        // On equal distances the lowest reference index keeps the query feature.
        let tied = [flipped(d, 2), flipped(d, 2)];
        let pairs = match_guided(&predicted[..2], &tied, &query, &MatchConfig::default());
        assert_eq!(pairs, vec![(0, 0)]);
    }

    #[test]
    fn ratio_distance_and_radius_rules() {
        let d: Descriptor = [1, 2, 3, 4];
        let cfg = MatchConfig {
            radius_px: 40.0,
            ..MatchConfig::default()
        };
        let predicted = [Some([200.0f32, 200.0])];
        // Best 10 bits, second 11: 10 < 0.8 · 11 fails.
        let ambiguous = [
            feature_at(210.0, 200.0, flipped(d, 11)),
            feature_at(200.0, 220.0, flipped(d, 10)),
        ];
        assert!(match_guided(&predicted, &[d], &ambiguous, &cfg).is_empty());
        // Second best moved outside the radius: the best alone passes.
        let alone = [
            feature_at(245.0, 200.0, flipped(d, 11)),
            feature_at(200.0, 220.0, flipped(d, 10)),
        ];
        assert_eq!(match_guided(&predicted, &[d], &alone, &cfg), vec![(0, 1)]);
        // Best 10, second 20: passes, the closer descriptor wins, not the closer position.
        let clear = [
            feature_at(201.0, 200.0, flipped(d, 20)),
            feature_at(200.0, 230.0, flipped(d, 10)),
        ];
        assert_eq!(match_guided(&predicted, &[d], &clear, &cfg), vec![(0, 1)]);
        // Too far in descriptor space.
        let far = [feature_at(200.0, 200.0, flipped(d, 65))];
        assert!(match_guided(&predicted, &[d], &far, &cfg).is_empty());
        let near = [feature_at(200.0, 200.0, flipped(d, 64))];
        assert_eq!(match_guided(&predicted, &[d], &near, &cfg), vec![(0, 0)]);
        // Outside the radius, even if identical.
        let outside = [feature_at(241.0, 200.0, d)];
        assert!(match_guided(&predicted, &[d], &outside, &cfg).is_empty());
    }

    #[test]
    fn at_most_one_feature_per_cell_strongest_first() {
        let s = scene(21);
        let image = view(&s, 0, 0, 1.0, 0.0, 1.0, 4);
        for cell_px in [16usize, 23, 40] {
            let cfg = FeatureConfig {
                cell_px,
                max_features: 10_000,
                ..FeatureConfig::default()
            };
            let features = detect(&image, &cfg);
            assert!(features.len() >= 100, "{} features", features.len());
            let mut cells: Vec<(usize, usize)> = features
                .iter()
                .map(|f| (f.x_px as usize / cell_px, f.y_px as usize / cell_px))
                .collect();
            let n = cells.len();
            cells.sort_unstable();
            cells.dedup();
            assert_eq!(cells.len(), n, "two features in one {cell_px}-px cell");
            for f in &features {
                assert!(f.score >= cfg.min_score);
                let border = DESCRIPTOR_BORDER_PX as f32;
                assert!(f.x_px >= border && f.x_px < (W as f32 - border));
                assert!(f.y_px >= border && f.y_px < (H as f32 - border));
            }
            assert!(features.windows(2).all(|p| p[0].score >= p[1].score));
        }
        // max_features keeps the strongest, deterministically.
        let cfg = FeatureConfig::default();
        let all = detect(
            &image,
            &FeatureConfig {
                max_features: 10_000,
                ..cfg.clone()
            },
        );
        let kept = detect(&image, &cfg);
        assert!(all.len() > cfg.max_features);
        assert_eq!(kept.len(), cfg.max_features);
        assert_eq!(kept[..], all[..cfg.max_features]);
        assert_eq!(detect(&image, &cfg), kept);
    }

    #[test]
    fn pattern_stays_in_the_patch() {
        let pattern = brief_pattern();
        let r = PATCH_RADIUS_PX as i8;
        for &[ax, ay, bx, by] in pattern {
            assert!([ax, ay, bx, by].iter().all(|v| (-r..=r).contains(v)));
            assert!((ax, ay) != (bx, by));
        }
        // Spread like a Gaussian of σ ≈ 6 px, not collapsed to the centre.
        let mean_sq: f32 = pattern
            .iter()
            .map(|p| (p[0] as f32).powi(2) + (p[1] as f32).powi(2))
            .sum::<f32>()
            / DESCRIPTOR_BITS as f32;
        assert!((40.0..110.0).contains(&mean_sq), "{mean_sq}");
    }
}
