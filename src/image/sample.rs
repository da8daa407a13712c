//! Bilinear interpolation on `f32` images (the per-pixel hot path: `f32`, no bounds panics).

use super::Image;

/// Bilinear value at `(x, y)`, or `None` unless `0 <= x <= w-1` and `0 <= y <= h-1`.
#[inline]
pub fn bilinear(img: &Image<f32>, x: f32, y: f32) -> Option<f32> {
    let (x0, y0, fx, fy) = cell(img, x, y)?;
    let s = img.stride();
    let d = img.data();
    let i = y0 * s + x0;
    let (x1, y1) = (usize::from(fx > 0.0), if fy > 0.0 { s } else { 0 });
    let top = d[i] + fx * (d[i + x1] - d[i]);
    let bot = d[i + y1] + fx * (d[i + y1 + x1] - d[i + y1]);
    Some(top + fy * (bot - top))
}

/// Bilinear value and its exact partial derivatives `(v, dv/dx, dv/dy)` at `(x, y)`; `None` if the
/// 2x2 cell is not inside the image (needs `x < w-1` and `y < h-1`).
#[inline]
pub fn bilinear_with_gradient(img: &Image<f32>, x: f32, y: f32) -> Option<(f32, f32, f32)> {
    if !(x >= 0.0 && y >= 0.0) {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    if x0 + 1 >= img.width() || y0 + 1 >= img.height() {
        return None;
    }
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let s = img.stride();
    let d = img.data();
    let i = y0 * s + x0;
    let (a, b, c, e) = (d[i], d[i + 1], d[i + s], d[i + s + 1]);
    let top = a + fx * (b - a);
    let bot = c + fx * (e - c);
    let v = top + fy * (bot - top);
    let gx = (b - a) + fy * ((e - c) - (b - a));
    let gy = bot - top;
    Some((v, gx, gy))
}

#[inline]
fn cell(img: &Image<f32>, x: f32, y: f32) -> Option<(usize, usize, f32, f32)> {
    if !(x >= 0.0 && y >= 0.0) {
        return None; // also rejects NaN
    }
    let (w, h) = (img.width() as f32, img.height() as f32);
    if x > w - 1.0 || y > h - 1.0 {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    // On the last row/column the fraction is 0 and the +1 neighbour is never read.
    let (x0, fx) = if x0 + 1 >= img.width() {
        (img.width() - 1, 0.0)
    } else {
        (x0, x - x0 as f32)
    };
    let (y0, fy) = if y0 + 1 >= img.height() {
        (img.height() - 1, 0.0)
    } else {
        (y0, y - y0 as f32)
    };
    Some((x0, y0, fx, fy))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> Image<f32> {
        Image::from_fn(6, 5, |x, y| {
            2.0 * x as f32 + 3.0 * y as f32 + 0.5 * (x * y) as f32
        })
    }

    #[test]
    fn bilinear_reproduces_pixels_and_bilinear_functions() {
        let im = ramp();
        assert_eq!(bilinear(&im, 3.0, 2.0), Some(im.get(3, 2)));
        assert_eq!(bilinear(&im, 5.0, 4.0), Some(im.get(5, 4)));
        let (x, y) = (2.25f32, 1.75f32);
        let exact = 2.0 * x + 3.0 * y + 0.5 * x * y;
        assert!((bilinear(&im, x, y).unwrap() - exact).abs() < 1e-5);
        assert!(bilinear(&im, -0.1, 1.0).is_none());
        assert!(bilinear(&im, 5.01, 1.0).is_none());
        assert!(bilinear(&im, f32::NAN, 1.0).is_none());
    }

    #[test]
    fn gradient_matches_numeric() {
        let im = Image::from_fn(8, 8, |x, y| ((x * 7 + y * 13) % 11) as f32);
        let (x, y) = (3.3f32, 4.6f32);
        let (v, gx, gy) = bilinear_with_gradient(&im, x, y).unwrap();
        assert!((v - bilinear(&im, x, y).unwrap()).abs() < 1e-5);
        let h = 1e-2;
        let nx = (bilinear(&im, x + h, y).unwrap() - bilinear(&im, x - h, y).unwrap()) / (2.0 * h);
        let ny = (bilinear(&im, x, y + h).unwrap() - bilinear(&im, x, y - h).unwrap()) / (2.0 * h);
        assert!(
            (gx - nx).abs() < 1e-3 && (gy - ny).abs() < 1e-3,
            "{gx} {nx} {gy} {ny}"
        );
        assert!(bilinear_with_gradient(&im, 7.0, 3.0).is_none());
    }
}
