//! Lossless recording in the ASL layout: `<out>/mav0/cam0/data/<t_ns>.png`, `data.csv`, and
//! `frames.csv` with device time, host time, exposure and flags (see [`crate::asl`]).
//!
//! Crash safety: each PNG is written to a temporary name and renamed, then both CSV rows are
//! written and flushed, so a kill loses at most the frame in flight and never leaves a CSV row
//! pointing at a truncated image. A recording can be replayed with [`crate::ReplayCamera`].

use crate::asl::{DATA_CSV_HEADER, FRAMES_CSV_HEADER};
use crate::camera::CameraError;
use crate::frame::Frame;
use crate::png_io;
use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes frames to a new recording folder.
pub struct Recorder {
    cam0: PathBuf,
    data_csv: BufWriter<File>,
    frames_csv: BufWriter<File>,
    scratch: Vec<u8>,
    last_t_ns: Option<i64>,
    written: u64,
    skipped_non_monotonic: u64,
}

impl Recorder {
    /// Creates `<out>/mav0/cam0/` (refuses to overwrite an existing `data.csv`).
    pub fn create(out: &Path) -> Result<Self, CameraError> {
        let cam0 = out.join("mav0").join("cam0");
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CameraError::Io { path, source }
        };
        fs::create_dir_all(cam0.join("data")).map_err(io(&cam0))?;
        let data_path = cam0.join("data.csv");
        if data_path.exists() {
            return Err(CameraError::Io {
                path: data_path,
                source: std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    "a recording is already there",
                ),
            });
        }
        let frames_path = cam0.join("frames.csv");
        let mut data_csv = BufWriter::new(File::create(&data_path).map_err(io(&data_path))?);
        let mut frames_csv = BufWriter::new(File::create(&frames_path).map_err(io(&frames_path))?);
        writeln!(data_csv, "{DATA_CSV_HEADER}")
            .and_then(|()| data_csv.flush())
            .map_err(io(&data_path))?;
        writeln!(frames_csv, "{FRAMES_CSV_HEADER}")
            .and_then(|()| frames_csv.flush())
            .map_err(io(&frames_path))?;
        Ok(Recorder {
            cam0,
            data_csv,
            frames_csv,
            scratch: Vec::new(),
            last_t_ns: None,
            written: 0,
            skipped_non_monotonic: 0,
        })
    }

    /// The `cam0` folder written to.
    pub fn cam0(&self) -> &Path {
        &self.cam0
    }

    /// Frames written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Frames not written because their time did not increase (ASL needs strictly increasing
    /// timestamps; this only happens if the clock model's mapping stepped back).
    pub fn skipped_non_monotonic(&self) -> u64 {
        self.skipped_non_monotonic
    }

    /// Appends one frame; returns `false` if it was skipped as non-monotonic.
    ///
    /// The ASL timestamp is the frame time (exposure midpoint, host clock); frames whose time
    /// is not known yet (clock model still converging) fall back to the host receive time.
    pub fn write(&mut self, frame: &Frame) -> Result<bool, CameraError> {
        let m = &frame.meta;
        let t_ns = m.frame_time_ns.unwrap_or(m.host_receive_ns);
        if self.last_t_ns.is_some_and(|last| t_ns <= last) {
            self.skipped_non_monotonic += 1;
            return Ok(false);
        }
        let name = format!("{t_ns}.png");
        let final_path = self.cam0.join("data").join(&name);
        let tmp_path = self.cam0.join("data").join(format!(".{name}.tmp"));
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CameraError::Io { path, source }
        };
        png_io::encode(
            &tmp_path,
            m.width_px,
            m.height_px,
            m.pixel_format,
            frame.pixels(),
            &mut self.scratch,
        )
        .map_err(io(&tmp_path))?;
        fs::rename(&tmp_path, &final_path).map_err(io(&final_path))?;
        let exposure = m
            .exposure_us
            .filter(|e| e.is_finite())
            .map_or(String::new(), |e| format!("{e}"));
        let data_path = self.cam0.join("data.csv");
        writeln!(self.data_csv, "{t_ns},{name}")
            .and_then(|()| self.data_csv.flush())
            .map_err(io(&data_path))?;
        let frames_path = self.cam0.join("frames.csv");
        writeln!(
            self.frames_csv,
            "{t_ns},{},{},{},{exposure},{},{name}",
            m.frame_id,
            m.device_ns,
            m.host_receive_ns,
            m.flags.to_field()
        )
        .and_then(|()| self.frames_csv.flush())
        .map_err(io(&frames_path))?;
        self.last_t_ns = Some(t_ns);
        self.written += 1;
        Ok(true)
    }
}
