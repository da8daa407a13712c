//! The on-disk camera layout shared by replay and recording: an ASL/EuRoC `cam0` folder
//! (`data.csv` = `#timestamp [ns],filename`, images in `data/`), plus our own `frames.csv`
//! beside `data.csv` in recordings, with the timing the ASL format has no room for:
//!
//! ```text
//! #timestamp [ns],frame_id,device [ns],host_receive [ns],exposure [us],flags,filename
//! ```
//!
//! `timestamp` is the frame time (exposure midpoint on the host monotonic clock); `exposure`
//! is empty when unknown; `flags` is [`crate::FrameFlags::to_field`]. Kept small on purpose:
//! the root crate's dataset module reads whole ASL datasets; this crate only needs `cam0`.

use crate::camera::CameraError;
use crate::frame::FrameFlags;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

/// Header line of `frames.csv`.
pub const FRAMES_CSV_HEADER: &str =
    "#timestamp [ns],frame_id,device [ns],host_receive [ns],exposure [us],flags,filename";
/// Header line of `data.csv`.
pub const DATA_CSV_HEADER: &str = "#timestamp [ns],filename";

/// One image of a `cam0` folder.
#[derive(Clone, Debug, PartialEq)]
pub struct CamEntry {
    /// The ASL timestamp (frame time), ns.
    pub t_ns: i64,
    /// Image path, absolute (the folder joined with `data/<filename>`).
    pub image: PathBuf,
    /// From `frames.csv` when the folder is one of our recordings.
    pub recorded: Option<RecordedTiming>,
}

/// Timing columns of `frames.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedTiming {
    pub frame_id: u64,
    pub device_ns: i64,
    pub host_receive_ns: i64,
    pub exposure_us: Option<f64>,
    pub flags: FrameFlags,
}

/// Finds the `cam0` folder from a dataset root, its `mav0`, or the `cam0` folder itself.
pub fn find_cam0(path: &Path) -> Result<PathBuf, CameraError> {
    for candidate in [
        path.join("mav0/cam0"),
        path.join("cam0"),
        path.to_path_buf(),
    ] {
        if candidate.join("data.csv").is_file() {
            return Ok(candidate);
        }
    }
    Err(CameraError::Open {
        device: format!("replay:{}", path.display()),
        reason:
            "no cam0/data.csv under it (expected an ASL/EuRoC dataset, its mav0/ or cam0/ folder)"
                .into(),
    })
}

/// Reads `cam0/data.csv` (and `frames.csv` if present). Rows must have strictly increasing
/// timestamps; every error names the file and line.
pub fn read_cam0(cam0: &Path) -> Result<Vec<CamEntry>, CameraError> {
    let data_csv = cam0.join("data.csv");
    let mut entries = Vec::new();
    for_each_row(&data_csv, |line, fields| {
        let parse_err = |msg: String| CameraError::Parse {
            path: data_csv.clone(),
            line,
            msg,
        };
        let [t, file] = fields else {
            return Err(parse_err(format!(
                "expected 2 fields `timestamp,filename`, found {}",
                fields.len()
            )));
        };
        let t_ns: i64 = t
            .parse()
            .map_err(|_| parse_err(format!("bad timestamp {t:?}")))?;
        if let Some(prev) = entries.last().map(|e: &CamEntry| e.t_ns) {
            if t_ns <= prev {
                return Err(parse_err(format!("timestamp {t_ns} not after {prev}")));
            }
        }
        entries.push(CamEntry {
            t_ns,
            image: cam0.join("data").join(file),
            recorded: None,
        });
        Ok(())
    })?;
    let frames_csv = cam0.join("frames.csv");
    if frames_csv.is_file() {
        let mut i = 0usize;
        for_each_row(&frames_csv, |line, fields| {
            let parse_err = |msg: String| CameraError::Parse {
                path: frames_csv.clone(),
                line,
                msg,
            };
            let [t, id, dev, host, exp, flags, _file] = fields else {
                return Err(parse_err(format!(
                    "expected 7 fields, found {}",
                    fields.len()
                )));
            };
            let num = |s: &str, what: &str| {
                s.parse::<i64>()
                    .map_err(|_| parse_err(format!("bad {what} {s:?}")))
            };
            let t_ns = num(t, "timestamp")?;
            let entry = entries
                .get_mut(i)
                .ok_or_else(|| parse_err("more rows than data.csv".into()))?;
            if entry.t_ns != t_ns {
                return Err(parse_err(format!(
                    "timestamp {t_ns} does not match data.csv row {} ({})",
                    i + 1,
                    entry.t_ns
                )));
            }
            let exposure_us = if exp.is_empty() {
                None
            } else {
                Some(
                    exp.parse::<f64>()
                        .ok()
                        .filter(|e| e.is_finite())
                        .ok_or_else(|| parse_err(format!("bad exposure {exp:?}")))?,
                )
            };
            entry.recorded = Some(RecordedTiming {
                frame_id: id
                    .parse()
                    .map_err(|_| parse_err(format!("bad frame id {id:?}")))?,
                device_ns: num(dev, "device time")?,
                host_receive_ns: num(host, "host time")?,
                exposure_us,
                flags: FrameFlags::parse_field(flags)
                    .ok_or_else(|| parse_err(format!("bad flags {flags:?}")))?,
            });
            i += 1;
            Ok(())
        })?;
    }
    Ok(entries)
}

/// Calls `f(line_number, trimmed_fields)` for every non-empty, non-comment line.
fn for_each_row(
    path: &Path,
    mut f: impl FnMut(usize, &[&str]) -> Result<(), CameraError>,
) -> Result<(), CameraError> {
    let io = |source| CameraError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    for (idx, line) in BufReader::new(file).lines().enumerate() {
        let line = line.map_err(io)?;
        let s = line.trim();
        if s.is_empty() || s.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = s.split(',').map(str::trim).collect();
        f(idx + 1, &fields)?;
    }
    Ok(())
}
