//! Reader for the ASL/EuRoC folder layout: `mav0/cam0`, `mav0/imu0`,
//! `mav0/state_groundtruth_estimate0`, plus the simulator's `mav0/depth0`.
//!
//! Everything streams: [`AslDataset::events`] merges IMU rows and frame rows in time order and an
//! image is decoded only when [`FrameRecord::load`] is called, so a long sequence never sits in
//! memory.

use super::DatasetError;
use super::csv_lines::CsvRows;
use super::groundtruth::{GroundTruth, read_groundtruth};
use super::sensor_yaml::{
    CameraSensor, ImuSensor, read_camera_yaml, read_imu_yaml, read_vignette_yaml,
};
use crate::camera::Vignette;
use crate::image::{Image, read_png_gray8, read_png_gray16};
use crate::imu::ImuSample;
use crate::time::TimeNs;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Depth PNG encoding of `mav0/depth0`: 16-bit, `value = depth_m * DEPTH_PNG_UNITS_PER_M`,
/// 0 = no depth (the TUM RGB-D convention; range 0.2 mm .. 13.1 m).
pub const DEPTH_PNG_UNITS_PER_M: f64 = 5000.0;

/// An opened ASL dataset (the folder that contains `mav0/`, or `mav0/` itself).
#[derive(Clone, Debug)]
pub struct AslDataset {
    mav0: PathBuf,
    /// `cam0/sensor.yaml`.
    pub camera: CameraSensor,
    /// `imu0/sensor.yaml`.
    pub imu: ImuSensor,
    /// `cam0/vignette.yaml`, if the dataset has a photometric calibration (the simulator writes
    /// one; EuRoC has none).
    pub vignette: Option<Vignette>,
}

/// A frame row of `cam0/data.csv`; the image is loaded on demand.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    pub t: TimeNs,
    pub path: PathBuf,
    /// Row of `data.csv` that named it (for error messages).
    pub csv_line: usize,
}

impl FrameRecord {
    /// Decodes the 8-bit image.
    pub fn load(&self) -> Result<Image<u8>, DatasetError> {
        read_png_gray8(&self.path).map_err(DatasetError::Image)
    }
}

/// One item of the merged stream. At equal timestamps the IMU sample comes first.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    Imu(ImuSample),
    Frame(FrameRecord),
}

/// The `mav0/` folder of `root`: `root/mav0` if there is one, else `root` itself.
pub(super) fn mav0_of(root: &Path) -> PathBuf {
    if root.join("mav0").is_dir() {
        root.join("mav0")
    } else {
        root.to_path_buf()
    }
}

impl AslDataset {
    /// Opens `root` (either the folder holding `mav0/` or `mav0/` itself) and reads both sensor
    /// descriptions.
    pub fn open(root: &Path) -> Result<Self, DatasetError> {
        let mav0 = mav0_of(root);
        if !mav0.join("cam0").is_dir() && !mav0.join("imu0").is_dir() {
            return Err(DatasetError::Layout {
                path: root.into(),
                msg: "no mav0/cam0 or mav0/imu0 folder (expected the ASL/EuRoC layout)".into(),
            });
        }
        let camera = read_camera_yaml(&mav0.join("cam0/sensor.yaml"))?;
        let imu = read_imu_yaml(&mav0.join("imu0/sensor.yaml"))?;
        let vp = mav0.join("cam0/vignette.yaml");
        let vignette = if vp.exists() {
            Some(read_vignette_yaml(
                &vp,
                (camera.model.width, camera.model.height),
            )?)
        } else {
            None
        };
        Ok(AslDataset {
            mav0,
            camera,
            imu,
            vignette,
        })
    }

    /// The `mav0` folder.
    pub fn mav0(&self) -> &Path {
        &self.mav0
    }

    /// Streams `cam0/data.csv`; each row's image must exist.
    pub fn frames(&self) -> Result<FrameIter, DatasetError> {
        Ok(FrameIter {
            rows: CsvRows::open(&self.mav0.join("cam0/data.csv"))?,
            dir: self.mav0.join("cam0/data"),
        })
    }

    /// Streams `imu0/data.csv` (gyro xyz rad/s, then accel xyz m/s^2).
    pub fn imu_samples(&self) -> Result<ImuIter, DatasetError> {
        Ok(ImuIter {
            rows: CsvRows::open(&self.mav0.join("imu0/data.csv"))?,
        })
    }

    /// IMU and frames merged in time order.
    pub fn events(&self) -> Result<EventIter, DatasetError> {
        Ok(EventIter {
            imu: self.imu_samples()?,
            frames: self.frames()?,
            next_imu: None,
            next_frame: None,
            primed: false,
        })
    }

    /// Ground truth (`state_groundtruth_estimate0/data.csv`), if the dataset has it.
    pub fn ground_truth(&self) -> Result<Option<GroundTruth>, DatasetError> {
        let p = self.mav0.join("state_groundtruth_estimate0/data.csv");
        if !p.exists() {
            return Ok(None);
        }
        read_groundtruth(&p).map(Some)
    }

    /// Path of the ground-truth depth map for the frame at `t`, if `mav0/depth0` has one.
    pub fn depth_path(&self, t: TimeNs) -> Option<PathBuf> {
        let p = self.mav0.join("depth0/data").join(format!("{}.png", t.0));
        p.exists().then_some(p)
    }

    /// Loads the ground-truth depth (m, 0 = none) of the frame at `t`.
    pub fn load_depth_m(&self, t: TimeNs) -> Result<Option<Image<f32>>, DatasetError> {
        let Some(p) = self.depth_path(t) else {
            return Ok(None);
        };
        let raw = read_png_gray16(&p).map_err(DatasetError::Image)?;
        Ok(Some(raw.map(|v| (v as f64 / DEPTH_PNG_UNITS_PER_M) as f32)))
    }
}

/// Iterator over `cam0/data.csv`.
pub struct FrameIter {
    rows: CsvRows,
    dir: PathBuf,
}

impl Iterator for FrameIter {
    type Item = Result<FrameRecord, DatasetError>;
    fn next(&mut self) -> Option<Self::Item> {
        let (t, fields) = match self.rows.next_row()? {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        let name = fields
            .first()
            .cloned()
            .unwrap_or_else(|| format!("{}.png", t.0));
        let path = self.dir.join(&name);
        if !path.is_file() {
            return Some(Err(self
                .rows
                .error(format!("image '{}' does not exist", path.display()))));
        }
        Some(Ok(FrameRecord {
            t,
            path,
            csv_line: self.rows.line(),
        }))
    }
}

/// Iterator over `imu0/data.csv`.
pub struct ImuIter {
    rows: CsvRows,
}

impl Iterator for ImuIter {
    type Item = Result<ImuSample, DatasetError>;
    fn next(&mut self) -> Option<Self::Item> {
        let (t, f) = match self.rows.next_row()? {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        let parse = || -> Result<ImuSample, DatasetError> {
            if f.len() < 6 {
                return Err(self
                    .rows
                    .error(format!("expected 7 columns, found {}", f.len() + 1)));
            }
            let n = |i| self.rows.number(&f, i);
            Ok(ImuSample {
                t,
                gyro_rad_s: Vector3::new(n(0)?, n(1)?, n(2)?),
                accel_m_s2: Vector3::new(n(3)?, n(4)?, n(5)?),
            })
        };
        Some(parse())
    }
}

impl ImuIter {
    /// The row last returned, byte for byte as in the file (without its line feed).
    pub(crate) fn raw_line(&self) -> &str {
        self.rows.raw_line()
    }

    /// Streams an EuRoC `imu0/data.csv` file (timestamp ns, gyro xyz rad/s, accel xyz m/s^2).
    pub fn open(path: &Path) -> Result<Self, DatasetError> {
        Ok(ImuIter {
            rows: CsvRows::open(path)?,
        })
    }

    pub fn path(&self) -> &Path {
        self.rows.path()
    }
}

/// Reads a whole EuRoC IMU CSV file; errors name the file and line.
pub fn read_imu_csv(path: &Path) -> Result<Vec<ImuSample>, DatasetError> {
    ImuIter::open(path)?.collect()
}

/// Like [`read_imu_csv`], keeping each row's exact text (without its line feed) for byte-identical
/// pass-through of a real recording.
pub fn read_imu_csv_with_lines(path: &Path) -> Result<Vec<(ImuSample, String)>, DatasetError> {
    let mut it = ImuIter::open(path)?;
    let mut out = Vec::new();
    while let Some(s) = it.next() {
        out.push((s?, it.raw_line().to_string()));
    }
    Ok(out)
}

/// Merged, time-ordered stream of IMU samples and frames.
pub struct EventIter {
    imu: ImuIter,
    frames: FrameIter,
    next_imu: Option<ImuSample>,
    next_frame: Option<FrameRecord>,
    primed: bool,
}

impl Iterator for EventIter {
    type Item = Result<Event, DatasetError>;
    fn next(&mut self) -> Option<Self::Item> {
        if !self.primed {
            self.primed = true;
            match self.imu.next().transpose() {
                Ok(v) => self.next_imu = v,
                Err(e) => return Some(Err(e)),
            }
            match self.frames.next().transpose() {
                Ok(v) => self.next_frame = v,
                Err(e) => return Some(Err(e)),
            }
        }
        let take_imu = match (&self.next_imu, &self.next_frame) {
            (None, None) => return None,
            (Some(_), None) => true,
            (None, Some(_)) => false,
            (Some(i), Some(f)) => i.t <= f.t,
        };
        if take_imu {
            let out = self.next_imu.take().map(Event::Imu);
            match self.imu.next().transpose() {
                Ok(v) => self.next_imu = v,
                Err(e) => return Some(Err(e)),
            }
            out.map(Ok)
        } else {
            let out = self.next_frame.take().map(Event::Frame);
            match self.frames.next().transpose() {
                Ok(v) => self.next_frame = v,
                Err(e) => return Some(Err(e)),
            }
            out.map(Ok)
        }
    }
}
