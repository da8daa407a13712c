//! Camera models: pinhole with radial-tangential distortion (EuRoC / mvBlueFOX) or equidistant
//! (Kannala-Brandt fisheye), projection and unprojection with analytic Jacobians, pyramid scaling,
//! precomputed undistortion maps and pixel rays; the vignetting model (photometric calibration).
//!
//! Pixel convention: the centre of pixel (col, row) is at `(u, v) = (col, row)`; the camera frame is
//! x right, y down, z forward. Normalised coordinates are `(X/Z, Y/Z)`.

mod model;
mod pixel_rays;
mod undistort;
mod vignette;

pub use model::{CameraModel, CameraModelError, Distortion};
pub use pixel_rays::PixelRays;
pub use undistort::UndistortMap;
pub use vignette::{Vignette, correct_in_place, farthest_corner_px};
