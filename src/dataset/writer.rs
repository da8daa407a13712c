//! Writer for the ASL/EuRoC layout (used by the simulator and recorders). Rows are appended and
//! flushed as they come, so an interrupted run leaves a readable prefix.

use super::DatasetError;
use super::asl::DEPTH_PNG_UNITS_PER_M;
use super::groundtruth::GroundTruth;
use super::sensor_yaml::{CameraSensor, ImuSensor, write_camera_yaml, write_imu_yaml};
use crate::image::{Image, write_png_gray8, write_png_gray16};
use crate::imu::ImuSample;
use crate::time::TimeNs;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Creates `root/mav0/{cam0,imu0,depth0,state_groundtruth_estimate0}` and writes into them.
pub struct AslWriter {
    mav0: PathBuf,
    cam_csv: BufWriter<File>,
    imu_csv: BufWriter<File>,
    depth_csv: Option<BufWriter<File>>,
}

/// Header line of `imu0/data.csv` (EuRoC's).
pub(super) const IMU_CSV_HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],\
     w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]";

/// The error of an I/O operation on `path`, naming it.
pub(super) fn io(path: &Path) -> impl Fn(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.into(),
        source,
    }
}

fn create_csv(path: &Path, header: &str) -> Result<BufWriter<File>, DatasetError> {
    let mut w = BufWriter::new(File::create(path).map_err(io(path))?);
    writeln!(w, "{header}").map_err(io(path))?;
    Ok(w)
}

impl AslWriter {
    /// Creates the layout under `root` and writes both `sensor.yaml` files. With `with_depth`,
    /// `mav0/depth0` is created too.
    pub fn create(
        root: &Path,
        camera: &CameraSensor,
        imu: &ImuSensor,
        with_depth: bool,
        comment: &str,
    ) -> Result<Self, DatasetError> {
        let mav0 = root.join("mav0");
        for d in ["cam0/data", "imu0", "state_groundtruth_estimate0"] {
            let p = mav0.join(d);
            std::fs::create_dir_all(&p).map_err(io(&p))?;
        }
        let cy = mav0.join("cam0/sensor.yaml");
        write_camera_yaml(&cy, camera, comment).map_err(io(&cy))?;
        let iy = mav0.join("imu0/sensor.yaml");
        write_imu_yaml(&iy, imu, comment).map_err(io(&iy))?;
        let depth_csv = if with_depth {
            let p = mav0.join("depth0/data");
            std::fs::create_dir_all(&p).map_err(io(&p))?;
            Some(create_csv(
                &mav0.join("depth0/data.csv"),
                "#timestamp [ns],filename",
            )?)
        } else {
            None
        };
        Ok(AslWriter {
            cam_csv: create_csv(&mav0.join("cam0/data.csv"), "#timestamp [ns],filename")?,
            imu_csv: create_csv(&mav0.join("imu0/data.csv"), IMU_CSV_HEADER)?,
            depth_csv,
            mav0,
        })
    }

    pub fn mav0(&self) -> &Path {
        &self.mav0
    }

    /// Writes `cam0/data/<t>.png` and its `data.csv` row.
    pub fn write_frame(&mut self, t: TimeNs, img: &Image<u8>) -> Result<(), DatasetError> {
        let name = format!("{}.png", t.0);
        write_png_gray8(&self.mav0.join("cam0/data").join(&name), img)
            .map_err(DatasetError::Image)?;
        let p = self.mav0.join("cam0/data.csv");
        writeln!(self.cam_csv, "{},{name}", t.0).map_err(io(&p))?;
        self.cam_csv.flush().map_err(io(&p))
    }

    /// Writes a depth map (m; non-finite or <= 0 means none) as 16-bit PNG, see
    /// [`DEPTH_PNG_UNITS_PER_M`].
    pub fn write_depth(&mut self, t: TimeNs, depth_m: &Image<f32>) -> Result<(), DatasetError> {
        let p = self.mav0.join("depth0/data.csv");
        let csv = self
            .depth_csv
            .as_mut()
            .ok_or_else(|| DatasetError::Layout {
                path: p.clone(),
                msg: "writer created without depth0".into(),
            })?;
        let name = format!("{}.png", t.0);
        let enc = depth_m.map(|d| {
            if d.is_finite() && d > 0.0 {
                (d as f64 * DEPTH_PNG_UNITS_PER_M)
                    .round()
                    .clamp(1.0, 65535.0) as u16
            } else {
                0
            }
        });
        write_png_gray16(&self.mav0.join("depth0/data").join(&name), &enc)
            .map_err(DatasetError::Image)?;
        writeln!(csv, "{},{name}", t.0).map_err(io(&p))?;
        csv.flush().map_err(io(&p))
    }

    /// Appends an IMU row (buffered; flushed by [`finish`](Self::finish) or every frame).
    pub fn write_imu(&mut self, s: &ImuSample) -> Result<(), DatasetError> {
        let (g, a) = (s.gyro_rad_s, s.accel_m_s2);
        writeln!(
            self.imu_csv,
            "{},{},{},{},{},{},{}",
            s.t.0, g.x, g.y, g.z, a.x, a.y, a.z
        )
        .map_err(io(&self.mav0.join("imu0/data.csv")))
    }

    /// Appends a raw IMU row as given (for byte-identical pass-through of a real recording).
    pub fn write_imu_raw_line(&mut self, line: &str) -> Result<(), DatasetError> {
        writeln!(self.imu_csv, "{line}").map_err(io(&self.mav0.join("imu0/data.csv")))
    }

    /// Writes the ground truth file.
    pub fn write_groundtruth(&self, gt: &GroundTruth) -> Result<(), DatasetError> {
        gt.write(&self.mav0.join("state_groundtruth_estimate0/data.csv"))
    }

    /// Flushes everything.
    pub fn finish(mut self) -> Result<(), DatasetError> {
        let p = self.mav0.join("imu0/data.csv");
        self.imu_csv.flush().map_err(io(&p))?;
        self.cam_csv.flush().map_err(io(&p))?;
        if let Some(d) = self.depth_csv.as_mut() {
            d.flush().map_err(io(&p))?;
        }
        Ok(())
    }
}
