//! Camera models: pinhole with radial-tangential distortion (EuRoC / mvBlueFOX) or equidistant
//! (Kannala-Brandt fisheye), projection and unprojection with analytic Jacobians, pyramid scaling
//! and precomputed undistortion maps; the vignetting model (photometric calibration).
//!
//! Pixel convention: the centre of pixel (col, row) is at `(u, v) = (col, row)`; the camera frame is
//! x right, y down, z forward. Normalised coordinates are `(X/Z, Y/Z)`.

mod model;
mod undistort;
mod vignette;

pub use model::{CameraModel, CameraModelError, Distortion};
pub use undistort::UndistortMap;
pub use vignette::{Vignette, correct_in_place, farthest_corner_px};
