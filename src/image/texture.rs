//! How much texture an image has: the fraction of its pixels on an intensity edge. A covered
//! lens, a frame into the sun or a dead sensor reads as nearly none; the photometric tracker
//! must not be asked to align such a frame, because its affine brightness model can explain a
//! uniform image with a near-zero gain and call most points inliers.

use super::Image;

/// Fraction of the interior pixels of `img` whose forward-difference gradient magnitude is at
/// least `min_gradient_gray_px` (gray levels per pixel); 0 for an image smaller than 2x2.
pub fn textured_fraction(img: &Image<f32>, min_gradient_gray_px: f32) -> f32 {
    let (w, h) = (img.width(), img.height());
    if w < 2 || h < 2 {
        return 0.0;
    }
    let thr2 = min_gradient_gray_px * min_gradient_gray_px;
    let mut edges = 0usize;
    for y in 0..h - 1 {
        let (row, below) = (img.row(y), img.row(y + 1));
        for x in 0..w - 1 {
            let gx = row[x + 1] - row[x];
            let gy = below[x] - row[x];
            if gx * gx + gy * gy >= thr2 {
                edges += 1;
            }
        }
    }
    edges as f32 / ((w - 1) * (h - 1)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_uniform_image_has_none_and_a_checkerboard_all() {
        let mut img = Image::<f32>::new(16, 12);
        for y in 0..12 {
            img.row_mut(y).fill(40.0);
        }
        assert_eq!(textured_fraction(&img, 4.0), 0.0);
        for y in 0..12 {
            for (x, v) in img.row_mut(y).iter_mut().enumerate() {
                *v = if (x + y) % 2 == 0 { 0.0 } else { 100.0 };
            }
        }
        assert_eq!(textured_fraction(&img, 4.0), 1.0);
        // One vertical edge: the column before it, in every row that has a pixel right of it.
        let mut edge = Image::<f32>::new(10, 5);
        for y in 0..5 {
            for (x, v) in edge.row_mut(y).iter_mut().enumerate() {
                *v = if x < 5 { 10.0 } else { 60.0 };
            }
        }
        assert!((textured_fraction(&edge, 4.0) - 4.0 / 36.0).abs() < 1e-6);
        assert_eq!(textured_fraction(&Image::<f32>::new(1, 5), 4.0), 0.0);
    }
}
