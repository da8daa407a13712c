//! vidslam: tightly-coupled monocular visual-inertial direct SLAM (Concha et al., ICRA 2016).
//!
//! Layers, each importing only from the ones before it in this list:
//! `time`, `geometry` → `image` → `camera`, `imu` → `smoother`, `dataset` → `eval`, `sim` → `tracking`,
//! `mapping` → `loop_closure` → `runtime`, `output` → `cli` (the driver crates under `drivers/` sit below all of them).
//! Frame and naming conventions are documented once in [`geometry`].

pub mod camera;
pub mod cli;
pub mod dataset;
pub mod eval;
pub mod geometry;
pub mod image;
pub mod imu;
pub mod loop_closure;
pub mod mapping;
pub mod output;
pub mod runtime;
pub mod sim;
pub mod smoother;
pub mod time;
pub mod tracking;
