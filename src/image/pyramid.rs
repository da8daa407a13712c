//! Image pyramids (2x2 block averaging) with per-level gradient images, in preallocated buffers
//! that are refilled per frame without allocating.

use super::Image;

/// Levels of an `f32` image pyramid plus central-difference gradients per level.
#[derive(Clone, Debug)]
pub struct Pyramid {
    levels: Vec<Image<f32>>,
    grad_x: Vec<Image<f32>>,
    grad_y: Vec<Image<f32>>,
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
        }
    }

    pub fn num_levels(&self) -> usize {
        self.levels.len()
    }

    pub fn level(&self, l: usize) -> &Image<f32> {
        &self.levels[l]
    }

    /// `(d/dx, d/dy)` images of level `l` (central differences, 0 on the border).
    pub fn gradients(&self, l: usize) -> (&Image<f32>, &Image<f32>) {
        (&self.grad_x[l], &self.grad_y[l])
    }

    /// A pyramid of `num_levels` levels built from an 8-bit image (allocates; the per-frame paths
    /// keep one pyramid and refill it with [`Pyramid::fill_from_u8`]).
    pub fn from_u8(img: &Image<u8>, num_levels: usize) -> Self {
        let mut p = Pyramid::new(img.width(), img.height(), num_levels);
        p.fill_from_u8(img);
        p
    }

    /// Refills every level from an 8-bit image of the size given at construction.
    pub fn fill_from_u8(&mut self, img: &Image<u8>) {
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
        self.rebuild();
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
        self.rebuild();
    }

    fn rebuild(&mut self) {
        for l in 1..self.levels.len() {
            let (lo, hi) = self.levels.split_at_mut(l);
            downsample(&lo[l - 1], &mut hi[0]);
        }
        for l in 0..self.levels.len() {
            gradients(&self.levels[l], &mut self.grad_x[l], &mut self.grad_y[l]);
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
    gx.data_mut().fill(0.0);
    gy.data_mut().fill(0.0);
    for y in 1..h.saturating_sub(1) {
        let (up, mid, down) = (img.row(y - 1), img.row(y), img.row(y + 1));
        let rx = gx.row_mut(y);
        for x in 1..w - 1 {
            rx[x] = 0.5 * (mid[x + 1] - mid[x - 1]);
        }
        let ry = gy.row_mut(y);
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
}
