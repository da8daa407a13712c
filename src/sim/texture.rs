//! Procedural, seeded surface textures stored as images with a mip pyramid, so rendering is a
//! (trilinear) lookup rather than procedural noise per sample.
//!
//! Every texture mixes large genuinely uniform areas (the base albedo, with a very slow gradient
//! of a few percent: nothing for a direct method to lock onto, something for dense mapping to
//! fill) with features that have strong gradients at several scales: sharp-edged rectangles,
//! discs and soft blobs, tape lines, and rows of text-like glyphs. Albedo is in `[0, 1]`.

use super::rng::SimRng;
use super::scene::SurfaceKind;
use crate::image::Image;

/// Largest texture side, texels (the texel size grows for bigger surfaces).
pub const MAX_TEXTURE_SIDE: usize = 2048;

/// A texture with its mip levels; level `l` has texels of `texel_m · 2^l`.
#[derive(Clone, Debug)]
pub struct Texture {
    levels: Vec<Image<f32>>,
    /// Per level: texels per metre, last valid x and y texel coordinate.
    level_geom: Vec<[f32; 3]>,
    texel_m: f32,
    inv_texel_m: f32,
}

impl Texture {
    /// Builds the mip pyramid of `base` (2x2 box filter down to 1 texel).
    pub fn from_base(base: Image<f32>, texel_m: f64) -> Texture {
        let mut levels = vec![base];
        loop {
            let prev = levels.last().expect("non-empty");
            let (w, h) = (prev.width(), prev.height());
            if w == 1 && h == 1 {
                break;
            }
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            let next = Image::from_fn(nw, nh, |x, y| {
                let (x0, y0) = (2 * x, 2 * y);
                let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
                0.25 * (prev.get(x0, y0) + prev.get(x1, y0) + prev.get(x0, y1) + prev.get(x1, y1))
            });
            levels.push(next);
        }
        let level_geom = levels
            .iter()
            .enumerate()
            .map(|(l, img)| {
                [
                    (1.0 / (texel_m * (1u64 << l) as f64)) as f32,
                    (img.width() - 1) as f32,
                    (img.height() - 1) as f32,
                ]
            })
            .collect();
        Texture {
            levels,
            level_geom,
            texel_m: texel_m as f32,
            inv_texel_m: (1.0 / texel_m) as f32,
        }
    }

    /// Generates the texture of a `width_m x height_m` surface of `kind`.
    pub fn generate(
        width_m: f64,
        height_m: f64,
        texel_m: f64,
        kind: SurfaceKind,
        seed: u64,
    ) -> Self {
        let texel_m = texel_m
            .max(width_m / MAX_TEXTURE_SIDE as f64)
            .max(height_m / MAX_TEXTURE_SIDE as f64);
        let w = ((width_m / texel_m).ceil() as usize).max(1);
        let h = ((height_m / texel_m).ceil() as usize).max(1);
        let mut p = Painter {
            img: Image::new(w, h),
            texel_m,
            rng: SimRng::from_keys(seed, &[0x7E47]),
        };
        p.paint(kind, width_m, height_m);
        let base = p.img.map(|v| v.clamp(0.02, 0.98));
        Texture::from_base(base, texel_m)
    }

    /// Texel size of level 0, m.
    pub fn texel_m(&self) -> f64 {
        self.texel_m as f64
    }

    /// Level-0 image (albedo).
    pub fn base(&self) -> &Image<f32> {
        &self.levels[0]
    }

    /// Number of mip levels.
    pub fn num_levels(&self) -> usize {
        self.levels.len()
    }

    /// Albedo at surface coordinates `(a_m, b_m)` filtered over a footprint of `footprint_m`
    /// (trilinear between the two mip levels bracketing it; clamp-to-edge).
    #[inline]
    pub fn sample(&self, a_m: f32, b_m: f32, footprint_m: f32) -> f32 {
        let lod = (footprint_m * self.inv_texel_m).max(1.0).log2();
        let max = (self.levels.len() - 1) as f32;
        let lod = lod.min(max);
        let l0 = lod as usize;
        let f = lod - l0 as f32;
        let v0 = self.bilinear(l0, a_m, b_m);
        if f < 1e-3 || l0 + 1 >= self.levels.len() {
            return v0;
        }
        v0 + f * (self.bilinear(l0 + 1, a_m, b_m) - v0)
    }

    #[inline]
    fn bilinear(&self, level: usize, a_m: f32, b_m: f32) -> f32 {
        let img = &self.levels[level];
        let [scale, xmax, ymax] = self.level_geom[level];
        let x = (a_m * scale - 0.5).clamp(0.0, xmax);
        let y = (b_m * scale - 0.5).clamp(0.0, ymax);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(xmax as usize), (y0 + 1).min(ymax as usize));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let d = img.data();
        let s = img.stride();
        let (a, b) = (d[y0 * s + x0], d[y0 * s + x1]);
        let (c, e) = (d[y1 * s + x0], d[y1 * s + x1]);
        let top = a + fx * (b - a);
        let bot = c + fx * (e - c);
        top + fy * (bot - top)
    }
}

/// Draws features in metres onto the texel grid.
struct Painter {
    img: Image<f32>,
    texel_m: f64,
    rng: SimRng,
}

impl Painter {
    fn w_m(&self) -> f64 {
        self.img.width() as f64 * self.texel_m
    }
    fn h_m(&self) -> f64 {
        self.img.height() as f64 * self.texel_m
    }

    /// Texel index range covering `[lo_m, hi_m)` along an axis of `n` texels.
    fn span(&self, lo_m: f64, hi_m: f64, n: usize) -> std::ops::Range<usize> {
        let a = (lo_m / self.texel_m).floor().max(0.0) as usize;
        let b = ((hi_m / self.texel_m).ceil().max(0.0) as usize).min(n);
        a.min(b)..b
    }

    fn fill_base(&mut self, albedo: f64) {
        // Very slow gradient (+-3 % across the surface): textureless for tracking purposes.
        let (gx, gy) = (self.rng.range(-0.03, 0.03), self.rng.range(-0.03, 0.03));
        let (w, h) = (self.img.width() as f64, self.img.height() as f64);
        for y in 0..self.img.height() {
            for x in 0..self.img.width() {
                let v = albedo * (1.0 + gx * (x as f64 / w - 0.5) + gy * (y as f64 / h - 0.5));
                self.img.set(x, y, v as f32);
            }
        }
    }

    /// Blends `v` into texel `(x, y)` with the coverage of a shape whose edge is `inside_m` away
    /// (positive inside): a one-texel-wide anti-aliased edge, so magnified curves stay smooth.
    fn cover(&mut self, x: usize, y: usize, inside_m: f64, v: f64) {
        let c = (0.5 + inside_m / self.texel_m).clamp(0.0, 1.0) as f32;
        if c > 0.0 {
            let old = self.img.get(x, y);
            self.img.set(x, y, old + c * (v as f32 - old));
        }
    }

    fn rect(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, v: f64) {
        let (xs, ys) = (
            self.span(x0, x1, self.img.width()),
            self.span(y0, y1, self.img.height()),
        );
        for y in ys {
            for x in xs.clone() {
                self.img.set(x, y, v as f32);
            }
        }
    }

    fn disc(&mut self, cx: f64, cy: f64, r: f64, v: f64) {
        let (xs, ys) = (
            self.span(
                cx - r - self.texel_m,
                cx + r + self.texel_m,
                self.img.width(),
            ),
            self.span(
                cy - r - self.texel_m,
                cy + r + self.texel_m,
                self.img.height(),
            ),
        );
        for y in ys {
            for x in xs.clone() {
                let (px, py) = (
                    (x as f64 + 0.5) * self.texel_m,
                    (y as f64 + 0.5) * self.texel_m,
                );
                let dist = ((px - cx).powi(2) + (py - cy).powi(2)).sqrt();
                self.cover(x, y, r - dist, v);
            }
        }
    }

    /// Soft Gaussian blob of std `sigma`, adding `amp` at its centre.
    fn blob(&mut self, cx: f64, cy: f64, sigma: f64, amp: f64) {
        let r = 3.0 * sigma;
        let (xs, ys) = (
            self.span(cx - r, cx + r, self.img.width()),
            self.span(cy - r, cy + r, self.img.height()),
        );
        for y in ys {
            for x in xs.clone() {
                let (px, py) = (
                    (x as f64 + 0.5) * self.texel_m,
                    (y as f64 + 0.5) * self.texel_m,
                );
                let d2 = ((px - cx).powi(2) + (py - cy).powi(2)) / (sigma * sigma);
                let v = self.img.get(x, y) as f64 + amp * (-0.5 * d2).exp();
                self.img.set(x, y, v as f32);
            }
        }
    }

    /// A straight band of `width` from `(x0, y0)` to `(x1, y1)`.
    fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), width: f64, v: f64) {
        let (dx, dy) = (x1 - x0, y1 - y0);
        let len2 = (dx * dx + dy * dy).max(1e-12);
        let (xs, ys) = (
            self.span(x0.min(x1) - width, x0.max(x1) + width, self.img.width()),
            self.span(y0.min(y1) - width, y0.max(y1) + width, self.img.height()),
        );
        for y in ys {
            for x in xs.clone() {
                let (px, py) = (
                    (x as f64 + 0.5) * self.texel_m,
                    (y as f64 + 0.5) * self.texel_m,
                );
                let t = (((px - x0) * dx + (py - y0) * dy) / len2).clamp(0.0, 1.0);
                let (qx, qy) = (x0 + t * dx - px, y0 + t * dy - py);
                let dist = (qx * qx + qy * qy).sqrt();
                self.cover(x, y, 0.5 * width - dist, v);
            }
        }
    }

    /// Rows of text-like glyphs (5x7 random bit patterns) of glyph height `gh` in a box.
    fn text(&mut self, x0: f64, y0: f64, width: f64, rows: usize, gh: f64, v: f64) {
        let cell = gh / 7.0;
        let gw = 5.0 * cell;
        for r in 0..rows {
            let by = y0 + r as f64 * gh * 1.6;
            let mut bx = x0;
            while bx + gw <= x0 + width {
                let word = 2 + self.rng.below(7);
                for _ in 0..word {
                    if bx + gw > x0 + width {
                        break;
                    }
                    let bits = self.rng.next_u64();
                    for k in 0..35 {
                        if bits >> k & 1 == 1 && (bits >> (k + 29)) & 1 == 0 {
                            let (cx, cy) = ((k % 5) as f64, (k / 5) as f64);
                            self.rect(
                                bx + cx * cell,
                                by + cy * cell,
                                bx + (cx + 1.0) * cell,
                                by + (cy + 1.0) * cell,
                                v,
                            );
                        }
                    }
                    bx += gw + cell;
                }
                bx += 2.0 * gw;
            }
        }
    }

    /// A framed poster: border, fill, shapes and text.
    fn poster(&mut self, x0: f64, y0: f64, w: f64, h: f64) {
        let fill = self.rng.range(0.15, 0.9);
        let ink = if fill > 0.5 {
            self.rng.range(0.03, 0.2)
        } else {
            self.rng.range(0.75, 0.97)
        };
        let b = (0.02 * w.min(h)).max(0.01);
        self.rect(x0, y0, x0 + w, y0 + h, ink);
        self.rect(x0 + b, y0 + b, x0 + w - b, y0 + h - b, fill);
        let shapes = 1 + self.rng.below(4);
        for _ in 0..shapes {
            let r = self.rng.range(0.06, 0.22) * w.min(h);
            let cx = self.rng.range(x0 + r + b, x0 + w - r - b);
            let cy = self.rng.range(y0 + r + b, y0 + 0.6 * h);
            let shade = self.rng.range(0.05, 0.95);
            if self.rng.uniform() < 0.5 {
                self.disc(cx, cy, r, shade);
            } else {
                self.rect(cx - r, cy - 0.7 * r, cx + r, cy + 0.7 * r, shade);
            }
        }
        let gh = self.rng.range(0.015, 0.05).min(0.08 * h);
        let rows = ((0.3 * h) / (1.6 * gh)) as usize;
        self.text(
            x0 + 3.0 * b,
            y0 + 0.62 * h,
            w - 6.0 * b,
            rows.max(1),
            gh,
            ink,
        );
    }

    fn random_point(&mut self, margin: f64) -> (f64, f64) {
        let (w, h) = (self.w_m(), self.h_m());
        (
            self.rng
                .range(margin.min(0.5 * w), (w - margin).max(0.5 * w)),
            self.rng
                .range(margin.min(0.5 * h), (h - margin).max(0.5 * h)),
        )
    }

    fn paint(&mut self, kind: SurfaceKind, width_m: f64, height_m: f64) {
        let area = width_m * height_m;
        match kind {
            SurfaceKind::Floor => {
                let base = self.rng.range(0.32, 0.45);
                self.fill_base(base);
                for _ in 0..(area * 0.12).ceil() as usize {
                    // mats / floor markings: large uniform rectangles
                    let (w, h) = (self.rng.range(0.5, 1.6), self.rng.range(0.4, 1.2));
                    let (x, y) = self.random_point(0.5);
                    let v = self.rng.range(0.15, 0.7);
                    self.rect(x - 0.5 * w, y - 0.5 * h, x + 0.5 * w, y + 0.5 * h, v);
                }
                for _ in 0..(area * 0.12).ceil() as usize {
                    // tape marks, 0.4-2 m long
                    let a = self.random_point(0.2);
                    let (len, ang) = (self.rng.range(0.4, 2.0), self.rng.range(0.0, 6.3));
                    let b = (a.0 + len * ang.cos(), a.1 + len * ang.sin());
                    let v = if self.rng.uniform() < 0.5 { 0.9 } else { 0.08 };
                    let lw = self.rng.range(0.03, 0.06);
                    self.line(a, b, lw, v);
                }
                for _ in 0..(area * 0.12).ceil() as usize {
                    // sheets of paper, signs and floor stickers
                    let (w, h) = (self.rng.range(0.15, 0.5), self.rng.range(0.15, 0.4));
                    let (x, y) = self.random_point(0.5);
                    self.poster(x, y, w, h);
                }
                for _ in 0..(area * 0.6).ceil() as usize {
                    let (x, y) = self.random_point(0.1);
                    let s = self.rng.range(0.02, 0.15);
                    let amp = self.rng.range(-0.25, 0.25);
                    self.blob(x, y, s, amp);
                }
                for _ in 0..(area * 0.08).ceil() as usize {
                    let (x, y) = self.random_point(0.6);
                    let g = self.rng.range(0.03, 0.08);
                    self.text(x - 0.4, y, 0.8, 2, g, 0.9);
                }
            }
            SurfaceKind::Wall => {
                let base = self.rng.range(0.5, 0.72);
                self.fill_base(base);
                let n_posters = (area * 0.16).ceil() as usize;
                for _ in 0..n_posters {
                    let (w, h) = (self.rng.range(0.4, 1.3), self.rng.range(0.4, 1.1));
                    let (x, y) = self.random_point(0.8);
                    self.poster(x - 0.5 * w, (y - 0.5 * h).max(0.3), w, h);
                }
                for _ in 0..(area * 0.04).ceil() as usize {
                    // door frames / cabinets: tall dark rectangles with a lighter inside
                    let w = self.rng.range(0.6, 1.1);
                    let (x, _) = self.random_point(0.6);
                    let h = (self.h_m() * self.rng.range(0.55, 0.75)).min(2.1);
                    let v = self.rng.range(0.1, 0.3);
                    self.rect(x - 0.5 * w, 0.0, x + 0.5 * w, h, v);
                    let v2 = self.rng.range(0.35, 0.6);
                    self.rect(x - 0.5 * w + 0.05, 0.0, x + 0.5 * w - 0.05, h - 0.05, v2);
                }
                for _ in 0..(area * 0.3).ceil() as usize {
                    let (x, y) = self.random_point(0.1);
                    let (s, amp) = (self.rng.range(0.01, 0.06), self.rng.range(-0.3, 0.2));
                    self.blob(x, y, s, amp);
                }
                for _ in 0..(area * 0.1).ceil() as usize {
                    let (x, y) = self.random_point(0.5);
                    let g = self.rng.range(0.02, 0.06);
                    self.text(x - 0.3, y, 0.6, 3, g, 0.1);
                }
                for _ in 0..(area * 0.05).ceil() as usize {
                    // shelves / cable ducts: long thin horizontal bands
                    let (x, y) = self.random_point(0.5);
                    let len = self.rng.range(0.8, 2.5);
                    let (v, th) = (self.rng.range(0.1, 0.9), self.rng.range(0.02, 0.06));
                    self.rect(x - 0.5 * len, y, x + 0.5 * len, y + th, v);
                }
            }
            SurfaceKind::Ceiling => {
                let base = self.rng.range(0.7, 0.85);
                self.fill_base(base);
                // light fittings on a coarse grid, many cells left empty
                let pitch = self.rng.range(1.2, 1.8);
                let mut y = 0.6;
                while y + 0.6 < self.h_m() {
                    let mut x = 0.6;
                    while x + 0.6 < self.w_m() {
                        if self.rng.uniform() < 0.45 {
                            self.rect(x, y, x + 0.6, y + 0.6, 0.3);
                            self.rect(x + 0.03, y + 0.03, x + 0.57, y + 0.57, 0.97);
                        }
                        x += pitch;
                    }
                    y += pitch;
                }
                for _ in 0..(area * 0.1).ceil() as usize {
                    let (x, y) = self.random_point(0.1);
                    let r = self.rng.range(0.03, 0.08);
                    self.disc(x, y, r, 0.25);
                }
            }
            SurfaceKind::Box => {
                let base = self.rng.range(0.25, 0.7);
                self.fill_base(base);
                // tape across, a label, marks
                let v = self.rng.range(0.05, 0.95);
                let tw = self.rng.range(0.04, 0.07);
                let y = 0.5 * self.h_m();
                self.rect(0.0, y - 0.5 * tw, self.w_m(), y + 0.5 * tw, v);
                if width_m > 0.3 && height_m > 0.3 {
                    let (lw, lh) = (0.45 * width_m, 0.3 * height_m);
                    let (x, y) = (self.rng.range(0.05, width_m - lw - 0.05), 0.08 * height_m);
                    self.poster(x, y, lw, lh);
                }
                for _ in 0..(area * 4.0).ceil() as usize {
                    let (x, y) = self.random_point(0.02);
                    let (s, amp) = (self.rng.range(0.005, 0.03), self.rng.range(-0.3, 0.3));
                    self.blob(x, y, s, amp);
                }
            }
            SurfaceKind::Panel | SurfaceKind::Poster => {
                let base = self.rng.range(0.3, 0.8);
                self.fill_base(base);
                let m = 0.05 * width_m.min(height_m);
                self.poster(m, m, width_m - 2.0 * m, height_m - 2.0 * m);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mip_levels_preserve_the_mean_and_sampling_is_exact_on_texels() {
        let base = Image::from_fn(8, 4, |x, y| (x + 10 * y) as f32);
        let t = Texture::from_base(base.clone(), 0.01);
        assert_eq!(t.num_levels(), 4);
        let mean0: f32 = base.data().iter().sum::<f32>() / 32.0;
        let l1 = &t.levels[1];
        let mean1: f32 = l1.data().iter().sum::<f32>() / (l1.width() * l1.height()) as f32;
        assert!((mean0 - mean1).abs() < 1e-5);
        // Texel (3, 2) centre is at (3.5, 2.5) texels = (0.035, 0.025) m.
        assert!((t.sample(0.035, 0.025, 0.001) - 23.0).abs() < 1e-4);
        // A huge footprint returns the coarsest level: the mean.
        assert!((t.sample(0.04, 0.02, 10.0) - mean0).abs() < 1e-3);
    }

    #[test]
    fn generated_textures_have_both_flat_and_strong_gradient_areas() {
        for (k, kind) in [SurfaceKind::Wall, SurfaceKind::Floor, SurfaceKind::Box]
            .iter()
            .enumerate()
        {
            let t = Texture::generate(4.0, 3.0, 0.01, *kind, 77 + k as u64);
            let img = t.base();
            let (mut flat, mut strong, mut n) = (0usize, 0usize, 0usize);
            for y in 0..img.height() - 1 {
                for x in 0..img.width() - 1 {
                    let g = (img.get(x + 1, y) - img.get(x, y)).abs()
                        + (img.get(x, y + 1) - img.get(x, y)).abs();
                    n += 1;
                    if g < 0.002 {
                        flat += 1;
                    }
                    if g > 0.1 {
                        strong += 1;
                    }
                }
            }
            let (f, s) = (flat as f64 / n as f64, strong as f64 / n as f64);
            assert!(f > 0.3, "{kind:?}: flat fraction {f}");
            assert!(s > 0.002, "{kind:?}: strong-edge fraction {s}");
            let again = Texture::generate(4.0, 3.0, 0.01, *kind, 77 + k as u64);
            assert_eq!(again.base(), img, "deterministic");
        }
    }
}
