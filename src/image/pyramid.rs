//! Image pyramids (2x2 block averaging) with per-level gradient images, in preallocated buffers
//! that are refilled per frame without allocating.

use super::Image;

/// Levels of an `f32` image pyramid plus central-difference gradients per level.
#[derive(Clone, Debug)]
pub struct Pyramid {
    levels: Vec<Image<f32>>,
    grad_x: Vec<Image<f32>>,
    grad_y: Vec<Image<f32>>,
    /// Whether `grad_x`/`grad_y` belong to the current levels (see [`Pyramid::fill_levels_from_u8`]).
    gradients_ready: bool,
}

impl Pyramid {
    /// Buffers for `num_levels` levels of a `width x height` image (level 0 = full size).
    pub fn new(width: usize, height: usize, num_levels: usize) -> Self {
        let dims: Vec<(usize, usize)> =
            (0..num_levels).map(|l| (width >> l, height >> l)).collect();
        let mk = || {
            dims.iter()
                .map(|&(w, h)| Image::new(w, h))
                .collect::<Vec<_>>()
        };
        Pyramid {
            levels: mk(),
            grad_x: mk(),
            grad_y: mk(),
            gradients_ready: true,
        }
    }

    pub fn num_levels(&self) -> usize {
        self.levels.len()
    }

    pub fn level(&self, l: usize) -> &Image<f32> {
        &self.levels[l]
    }

    /// `(d/dx, d/dy)` images of level `l` (central differences, 0 on the border).
    ///
    /// Panics if the levels were refilled by [`Pyramid::fill_levels_from_u8`] and
    /// [`Pyramid::ensure_gradients`] was not called since (a programming error: the gradients
    /// would be those of an older image).
    pub fn gradients(&self, l: usize) -> (&Image<f32>, &Image<f32>) {
        assert!(
            self.gradients_ready,
            "Pyramid::gradients after fill_levels_from_u8 without ensure_gradients"
        );
        (&self.grad_x[l], &self.grad_y[l])
    }

    /// A pyramid of `num_levels` levels built from an 8-bit image (allocates; the per-frame paths
    /// keep one pyramid and refill it with [`Pyramid::fill_from_u8`]).
    pub fn from_u8(img: &Image<u8>, num_levels: usize) -> Self {
        let mut p = Pyramid::new(img.width(), img.height(), num_levels);
        p.fill_from_u8(img);
        p
    }

    /// Refills every level, and its gradients, from an 8-bit image of the size given at
    /// construction.
    pub fn fill_from_u8(&mut self, img: &Image<u8>) {
        self.fill_levels_from_u8(img);
        self.ensure_gradients();
    }

    /// Refills the intensity levels only; the gradients are computed by the next
    /// [`Pyramid::ensure_gradients`]. The tracker needs no gradients of the frames it tracks
    /// (inverse compositional: the keyframe's are used), only of a frame that becomes a keyframe.
    pub fn fill_levels_from_u8(&mut self, img: &Image<u8>) {
        let base = &mut self.levels[0];
        assert_eq!(
            (img.width(), img.height()),
            (base.width(), base.height()),
            "pyramid size mismatch"
        );
        for y in 0..img.height() {
            for (d, s) in base.row_mut(y).iter_mut().zip(img.row(y)) {
                *d = *s as f32;
            }
        }
        self.downsample_levels();
        self.gradients_ready = false;
    }

    /// Computes the gradients of the current levels if they are not up to date.
    pub fn ensure_gradients(&mut self) {
        if !self.gradients_ready {
            for l in 0..self.levels.len() {
                gradients(&self.levels[l], &mut self.grad_x[l], &mut self.grad_y[l]);
            }
            self.gradients_ready = true;
        }
    }

    /// Refills every level from an `f32` image of the size given at construction.
    pub fn fill_from_f32(&mut self, img: &Image<f32>) {
        let base = &mut self.levels[0];
        assert_eq!(
            (img.width(), img.height()),
            (base.width(), base.height()),
            "pyramid size mismatch"
        );
        for y in 0..img.height() {
            base.row_mut(y).copy_from_slice(img.row(y));
        }
        self.downsample_levels();
        self.gradients_ready = false;
        self.ensure_gradients();
    }

    fn downsample_levels(&mut self) {
        for l in 1..self.levels.len() {
            let (lo, hi) = self.levels.split_at_mut(l);
            downsample(&lo[l - 1], &mut hi[0]);
        }
    }
}

/// 2x2 block average; pixel `i` of the output covers input pixels `2i, 2i+1`.
fn downsample(src: &Image<f32>, dst: &mut Image<f32>) {
    for y in 0..dst.height() {
        let (r0, r1) = (src.row(2 * y), src.row(2 * y + 1));
        for (x, d) in dst.row_mut(y).iter_mut().enumerate() {
            *d = 0.25 * (r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]);
        }
    }
}

fn gradients(img: &Image<f32>, gx: &mut Image<f32>, gy: &mut Image<f32>) {
    let (w, h) = (img.width(), img.height());
    if h < 3 || w < 3 {
        gx.data_mut().fill(0.0);
        gy.data_mut().fill(0.0);
        return;
    }
    // Only the border is zeroed: every interior pixel is written below.
    for g in [&mut *gx, &mut *gy] {
        g.row_mut(0).fill(0.0);
        g.row_mut(h - 1).fill(0.0);
    }
    for y in 1..h - 1 {
        let (up, mid, down) = (img.row(y - 1), img.row(y), img.row(y + 1));
        let rx = gx.row_mut(y);
        rx[0] = 0.0;
        rx[w - 1] = 0.0;
        for x in 1..w - 1 {
            rx[x] = 0.5 * (mid[x + 1] - mid[x - 1]);
        }
        let ry = gy.row_mut(y);
        ry[0] = 0.0;
        ry[w - 1] = 0.0;
        for x in 1..w - 1 {
            ry[x] = 0.5 * (down[x] - up[x]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_average_blocks_and_gradients_match_ramps() {
        let img = Image::from_fn(16, 8, |x, y| (3 * x + 5 * y) as u8);
        let mut p = Pyramid::new(16, 8, 3);
        p.fill_from_u8(&img);
        assert_eq!((p.level(2).width(), p.level(2).height()), (4, 2));
        // Block (0,0) of level 1 averages (0,0),(1,0),(0,1),(1,1): 0,3,5,8 -> 4.
        assert_eq!(p.level(1).get(0, 0), 4.0);
        let (gx, gy) = p.gradients(0);
        assert_eq!((gx.get(5, 4), gy.get(5, 4)), (3.0, 5.0));
        // A ramp stays a ramp with doubled slope per level.
        let (gx1, gy1) = p.gradients(1);
        assert_eq!((gx1.get(3, 2), gy1.get(3, 2)), (6.0, 10.0));
        assert_eq!(gx.get(0, 4), 0.0);
    }

    #[test]
    fn lazy_gradients_of_a_refilled_pyramid_equal_a_fresh_pyramids() {
        let a = Image::from_fn(37, 23, |x, y| ((7 * x * y + 3 * x) % 251) as u8);
        let b = Image::from_fn(37, 23, |x, y| ((x * x + 11 * y) % 253) as u8);
        let mut p = Pyramid::from_u8(&a, 3);
        p.fill_levels_from_u8(&b);
        p.ensure_gradients();
        let fresh = Pyramid::from_u8(&b, 3);
        for l in 0..3 {
            assert_eq!(p.level(l).data(), fresh.level(l).data(), "level {l}");
            let ((gx, gy), (fx, fy)) = (p.gradients(l), fresh.gradients(l));
            assert_eq!(gx.data(), fx.data(), "d/dx of level {l}");
            assert_eq!(gy.data(), fy.data(), "d/dy of level {l}");
        }
    }

    #[test]
    #[should_panic(expected = "without ensure_gradients")]
    fn gradients_of_refilled_levels_are_not_handed_out_stale() {
        let img = Image::from_fn(16, 8, |x, y| (3 * x + 5 * y) as u8);
        let mut p = Pyramid::from_u8(&img, 2);
        p.fill_levels_from_u8(&img);
        let _ = p.gradients(0);
    }
}
