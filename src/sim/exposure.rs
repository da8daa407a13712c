//! The camera's photometric model: auto exposure (exposure time and analog gain with slow
//! first-order dynamics), vignetting, and sensor noise (shot + read noise) parameters.
//!
//! A pixel integrates radiance `L` (albedo × shade, in [0, 1]) over the exposure and reads
//! `DN = L · V(u, v) · 255 · (exposure_s · gain) / REFERENCE_EXPOSURE_S` before noise and 8-bit
//! quantisation, `V` being the vignetting factor. The auto exposure measures each frame's mean
//! `L·V` and moves the product `exposure_s · gain` a fraction [`AE_RATE`] of the way (in log
//! space) towards the value that would map it to [`AE_TARGET_DN`]; exposure time is used first (up
//! to [`MAX_EXPOSURE_S`]), then gain. Like a real AE, this gives slow brightness changes as the
//! camera turns from bright walls to the darker floor.

/// Exposure × gain at which radiance 1 maps to 255 DN, s.
pub const REFERENCE_EXPOSURE_S: f64 = 0.004;
/// Mean grey level the auto exposure aims for.
pub const AE_TARGET_DN: f64 = 110.0;
/// Fraction of the log-error corrected per frame.
pub const AE_RATE: f64 = 0.15;
pub const MIN_EXPOSURE_S: f64 = 0.000_2;
pub const MAX_EXPOSURE_S: f64 = 0.010;
pub const MAX_GAIN: f64 = 4.0;
/// Vignetting: `V = 1 - VIGNETTING · (ρ / ρ_max)²`, ρ the distance to the principal point.
pub const VIGNETTING: f64 = 0.35;

/// The simulator's vignetting as the photometric calibration it writes (`cam0/vignette.yaml`):
/// centred on the principal point, `ρ_max` the distance to the farthest image corner.
pub fn vignette_model(cam: &crate::camera::CameraModel) -> crate::camera::Vignette {
    let rho_max = crate::camera::farthest_corner_px([cam.cx, cam.cy], cam.width, cam.height);
    crate::camera::Vignette {
        centre_px: [cam.cx, cam.cy],
        radius_px: rho_max.max(1.0),
        coefficients: [-VIGNETTING, 0.0, 0.0],
    }
}
/// Full-well capacity at unity gain, electrons per 255 DN (shot noise).
pub const FULL_WELL_E: f64 = 8000.0;
/// Read noise, DN at unity gain.
pub const READ_NOISE_DN: f64 = 0.8;

/// Exposure state for one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exposure {
    pub exposure_s: f64,
    pub gain: f64,
}

impl Exposure {
    /// The ideal (no auto exposure) setting: radiance 1 → 255 DN.
    pub fn ideal() -> Self {
        Exposure {
            exposure_s: REFERENCE_EXPOSURE_S,
            gain: 1.0,
        }
    }

    /// Grey levels per unit radiance.
    pub fn dn_per_radiance(&self) -> f64 {
        255.0 * self.exposure_s * self.gain / REFERENCE_EXPOSURE_S
    }

    /// Splits an exposure-gain product (s) into exposure time first, then gain.
    fn from_product(product_s: f64) -> Self {
        let exposure_s = product_s.clamp(MIN_EXPOSURE_S, MAX_EXPOSURE_S);
        let gain = (product_s / exposure_s).clamp(1.0, MAX_GAIN);
        Exposure { exposure_s, gain }
    }
}

/// Auto-exposure controller.
#[derive(Clone, Debug)]
pub struct AutoExposure {
    current: Exposure,
}

impl Default for AutoExposure {
    fn default() -> Self {
        // Start as if the scene had mean radiance 0.5.
        AutoExposure {
            current: Exposure::from_product(AE_TARGET_DN / (0.5 * 255.0) * REFERENCE_EXPOSURE_S),
        }
    }
}

impl AutoExposure {
    /// Exposure to use for the next frame.
    pub fn current(&self) -> Exposure {
        self.current
    }

    /// Updates from the mean vignetted radiance of the frame just taken.
    pub fn update(&mut self, mean_radiance: f64) {
        if mean_radiance.is_nan() || mean_radiance <= 1e-6 {
            return;
        }
        let product = self.current.exposure_s * self.current.gain;
        let wanted = AE_TARGET_DN / (mean_radiance * 255.0) * REFERENCE_EXPOSURE_S;
        let next = product * (wanted / product).powf(AE_RATE);
        self.current = Exposure::from_product(next);
    }
}

/// Noise standard deviation (DN) of a pixel reading `dn` at analog `gain`.
#[inline]
pub fn noise_std_dn(dn: f32, gain: f32) -> f32 {
    let shot_var = dn.max(0.0) * gain * (255.0 / FULL_WELL_E as f32);
    let read = READ_NOISE_DN as f32 * gain;
    (shot_var + read * read).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_exposure_converges_slowly_to_the_target() {
        let mut ae = AutoExposure::default();
        let radiance = 0.2;
        let mut prev_err = f64::INFINITY;
        for _ in 0..60 {
            let dn = radiance * ae.current().dn_per_radiance();
            let err = (dn - AE_TARGET_DN).abs();
            assert!(err <= prev_err + 1e-9);
            prev_err = err;
            ae.update(radiance);
        }
        assert!(prev_err < 0.5, "{prev_err}");
        // One step only moves part of the way.
        let mut ae2 = AutoExposure::default();
        let before = ae2.current().dn_per_radiance();
        ae2.update(0.1);
        let after = ae2.current().dn_per_radiance();
        assert!(after > before && after < 2.0 * before);
    }

    #[test]
    fn noise_grows_with_signal_and_gain() {
        assert!(noise_std_dn(200.0, 1.0) > noise_std_dn(20.0, 1.0));
        assert!(noise_std_dn(100.0, 2.0) > noise_std_dn(100.0, 1.0));
        assert!((noise_std_dn(0.0, 1.0) - READ_NOISE_DN as f32).abs() < 1e-6);
    }
}
