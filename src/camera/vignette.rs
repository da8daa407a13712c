//! Vignetting: the lens and sensor pass less light towards the image corners, so one scene point
//! reads darker near the border than at the centre. Direct methods compare raw intensities of the
//! same point seen at different image positions, and the affine brightness model (one gain for
//! the whole image) cannot absorb a gain that depends on the position: without correction, fast
//! rotations bias the pose (the photometric error pulls points towards where they are brighter)
//! and the mapper's patch costs mix in the position difference. DSO's photometric calibration
//! (Engel et al. 2016) removes it before tracking; so do we.
//!
//! Model, radial polynomial about a centre (usually the principal point):
//! `V(u, v) = 1 + k₁ s² + k₂ s⁴ + k₃ s⁶`, `s = ‖(u, v) − c‖ / radius_px`.
//! The corrected image is `I / V`.

use crate::image::Image;

/// A radial vignetting model (the file `cam0/vignette.yaml` of a dataset).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vignette {
    /// Centre of the fall-off, pixels (pixel-centre convention of [`crate::camera`]).
    pub centre_px: [f64; 2],
    /// Distance from the centre at which `s = 1`, pixels.
    pub radius_px: f64,
    /// `[k₁, k₂, k₃]` of the module documentation.
    pub coefficients: [f64; 3],
}

/// Distance from `centre_px` to the farthest corner of a `width`×`height` image, pixels.
pub fn farthest_corner_px(centre_px: [f64; 2], width: usize, height: usize) -> f64 {
    let (w, h) = (width as f64, height as f64);
    [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
        .iter()
        .map(|(x, y)| ((x - centre_px[0]).powi(2) + (y - centre_px[1]).powi(2)).sqrt())
        .fold(0.0, f64::max)
}

/// Smallest attenuation accepted anywhere in the image (a gain above 1 / this is implausible).
pub const MIN_FACTOR: f64 = 0.05;

impl Vignette {
    /// Attenuation `V` at pixel `(u, v)`.
    pub fn factor(&self, u_px: f64, v_px: f64) -> f64 {
        let s2 = ((u_px - self.centre_px[0]).powi(2) + (v_px - self.centre_px[1]).powi(2))
            / self.radius_px.powi(2);
        let [k1, k2, k3] = self.coefficients;
        1.0 + s2 * (k1 + s2 * (k2 + s2 * k3))
    }

    /// Checks that the model is finite and that `V` stays in `[MIN_FACTOR, 1.5]` over a
    /// `width`×`height` image; the error names the offending value.
    pub fn validate(&self, width: usize, height: usize) -> Result<(), String> {
        let finite = self.centre_px.iter().all(|v| v.is_finite())
            && self.coefficients.iter().all(|v| v.is_finite());
        if !finite {
            return Err("non-finite centre or coefficient".into());
        }
        if !(self.radius_px.is_finite() && self.radius_px > 0.0) {
            return Err(format!("radius_px = {} (must be > 0)", self.radius_px));
        }
        // V is a polynomial in s²: check it densely along the radius up to the farthest corner.
        let far = farthest_corner_px(self.centre_px, width, height);
        for k in 0..=256 {
            let rho = far * k as f64 / 256.0;
            let v = self.factor(self.centre_px[0] + rho, self.centre_px[1]);
            if !(MIN_FACTOR..=1.5).contains(&v) {
                return Err(format!(
                    "attenuation {v:.3} at {rho:.0} px from the centre (allowed {MIN_FACTOR}..1.5)"
                ));
            }
        }
        Ok(())
    }

    /// Per-pixel gains `1 / V` for a `width`×`height` image, row-major (precompute once, then
    /// [`correct_in_place`] each frame).
    pub fn correction_table(&self, width: usize, height: usize) -> Vec<f32> {
        let mut t = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                t.push((1.0 / self.factor(x as f64, y as f64).max(MIN_FACTOR)) as f32);
            }
        }
        t
    }
}

/// Divides `image` by the vignetting in place (`table` from [`Vignette::correction_table`] of
/// the same size), rounding to the nearest grey level. Returns how many pixels saturated at 255.
/// Does not allocate.
pub fn correct_in_place(image: &mut Image<u8>, table: &[f32]) -> usize {
    let w = image.width();
    assert_eq!(table.len(), w * image.height(), "vignette table size");
    let mut saturated = 0;
    for y in 0..image.height() {
        let gains = &table[y * w..(y + 1) * w];
        for (p, g) in image.row_mut(y).iter_mut().zip(gains) {
            let v = *p as f32 * g + 0.5;
            if v >= 255.0 {
                saturated += (*p < 255) as usize;
                *p = 255;
            } else {
                *p = v as u8;
            }
        }
    }
    saturated
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sim_like() -> Vignette {
        Vignette {
            centre_px: [367.2, 248.4],
            radius_px: 447.0,
            coefficients: [-0.35, 0.0, 0.0],
        }
    }

    #[test]
    fn factor_is_one_at_the_centre_and_follows_the_polynomial() {
        let v = Vignette {
            coefficients: [-0.2, 0.05, -0.01],
            ..sim_like()
        };
        assert_eq!(v.factor(367.2, 248.4), 1.0);
        // s = 1 along x: 1 − 0.2 + 0.05 − 0.01.
        assert!((v.factor(367.2 + 447.0, 248.4) - 0.84).abs() < 1e-12);
        // s = 0.5 along y: 1 − 0.2/4 + 0.05/16 − 0.01/64.
        let s = 1.0 - 0.05 + 0.003125 - 0.000_156_25;
        assert!((v.factor(367.2, 248.4 - 223.5) - s).abs() < 1e-12);
    }

    #[test]
    fn correction_flattens_a_vignetted_uniform_image() {
        let v = sim_like();
        let (w, h) = (752, 480);
        let mut img = Image::from_fn(w, h, |x, y| {
            (160.0 * v.factor(x as f64, y as f64)).round() as u8
        });
        let table = v.correction_table(w, h);
        assert_eq!(correct_in_place(&mut img, &table), 0);
        let (lo, hi) = img
            .data()
            .iter()
            .fold((255u8, 0u8), |(lo, hi), &p| (lo.min(p), hi.max(p)));
        // Rounding to 8 bits before the division leaves at most ±1 grey level.
        assert!(lo >= 159 && hi <= 161, "{lo}..{hi}");
    }

    #[test]
    fn saturation_is_clamped_and_counted() {
        let v = sim_like();
        let mut img = Image::from_fn(4, 1, |_, _| 250u8);
        let table = vec![1.0, 1.1, 1.0, 2.0];
        assert_eq!(correct_in_place(&mut img, &table), 2);
        assert_eq!(img.row(0), &[250, 255, 250, 255]);
        assert!(v.validate(752, 480).is_ok());
    }

    #[test]
    fn validate_rejects_implausible_models() {
        let bad = Vignette {
            coefficients: [-1.2, 0.0, 0.0],
            ..sim_like()
        };
        let e = bad.validate(752, 480).unwrap_err();
        assert!(e.contains("attenuation"), "{e}");
        let bad = Vignette {
            radius_px: 0.0,
            ..sim_like()
        };
        assert!(bad.validate(752, 480).unwrap_err().contains("radius_px"));
        let bad = Vignette {
            coefficients: [f64::NAN, 0.0, 0.0],
            ..sim_like()
        };
        assert!(bad.validate(752, 480).is_err());
    }
}
