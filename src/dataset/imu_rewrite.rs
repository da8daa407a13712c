//! A copy of an ASL/EuRoC dataset whose IMU readings are turned and de-biased
//! (`vidslam dataset imu-rewrite`).
//!
//! Why: whether an odometry's error comes from how its IMU sits against the camera (a turned
//! gyro or accelerometer, a bias the rest cannot tell from a tilt) is answered by giving it the
//! same images with the IMU put right by hand, e.g. by the rotation `vidslam dataset imu-check`
//! fits against the ground truth, and replaying. Each sample becomes
//!
//! `ω' = Exp(r_g) ω − b_g`,  `a' = Exp(r_a) a − b_a`
//!
//! with `r_g`, `r_a` rotation vectors taking the sensors' axes to the body frame (the convention of
//! `[gyro_alignment] initial_rotation_deg`) and `b_g`, `b_a` biases in the body frame. The images,
//! depth, ground truth and everything else in `mav0/` are linked, not copied (a render is
//! gigabytes); `imu0/sensor.yaml` is copied; `imu0/data.csv` is written with each row's timestamp
//! text as it was and the six values at full precision (Rust's shortest round-trip form).
//!
//! Before the turn and the bias, a band of another dataset's gyro or accelerometer may be mixed in
//! ([`DonorMix`], `src/dataset/imu_mix.rs`).

use super::imu_mix::{ImuSensorKind, MixSummary, mix_in};
use super::writer::{IMU_CSV_HEADER, io};
use super::{
    DatasetError,
    asl::{mav0_of, read_imu_csv, read_imu_csv_with_lines},
};
use crate::geometry::exp_so3;
use crate::imu::ImuSample;
use nalgebra::{Matrix3, Vector3};
use std::io::{BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};

/// What is done to every IMU sample (all zero: the copy reads as the original).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuRewrite {
    /// Rotation vector taking the gyro's axes to the body frame, rad.
    pub gyro_rotation_rad: Vector3<f64>,
    /// Rotation vector taking the accelerometer's axes to the body frame, rad.
    pub accel_rotation_rad: Vector3<f64>,
    /// Subtracted from the turned angular rate, rad/s.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// Subtracted from the turned specific force, m/s².
    pub accel_bias_m_s2: Vector3<f64>,
}

impl ImuRewrite {
    /// The sample as the rewritten dataset holds it (same time).
    pub fn apply(&self, s: &ImuSample) -> ImuSample {
        self.with_matrices(&self.matrices(), s)
    }

    fn matrices(&self) -> (Matrix3<f64>, Matrix3<f64>) {
        (
            exp_so3(&self.gyro_rotation_rad),
            exp_so3(&self.accel_rotation_rad),
        )
    }

    fn with_matrices(&self, (rg, ra): &(Matrix3<f64>, Matrix3<f64>), s: &ImuSample) -> ImuSample {
        ImuSample {
            t: s.t,
            gyro_rad_s: rg * s.gyro_rad_s - self.gyro_bias_rad_s,
            accel_m_s2: ra * s.accel_m_s2 - self.accel_bias_m_s2,
        }
    }
}

/// Another dataset's gyro and/or accelerometer put into the rewritten one, in the frequency band
/// `[lo_hz, hi_hz)` of their difference (`src/dataset/imu_mix.rs`); the default mixes nothing.
#[derive(Clone, Debug, PartialEq)]
pub struct DonorMix {
    /// Dataset (folder holding `mav0/`, or `mav0/`) whose gyro is mixed in.
    pub gyro_from: Option<PathBuf>,
    /// Dataset whose accelerometer is mixed in.
    pub accel_from: Option<PathBuf>,
    /// Lower edge of the band, Hz (0: from the mean on).
    pub lo_hz: f64,
    /// Upper edge of the band, Hz (infinite: to the Nyquist rate).
    pub hi_hz: f64,
}

impl Default for DonorMix {
    fn default() -> Self {
        DonorMix {
            gyro_from: None,
            accel_from: None,
            lo_hz: 0.0,
            hi_hz: f64::INFINITY,
        }
    }
}

/// What [`rewrite_dataset`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct RewriteSummary {
    /// IMU rows written.
    pub samples: usize,
    /// Each sensor mixed in from a donor, and how.
    pub mixed: Vec<(ImuSensorKind, MixSummary)>,
    /// `mav0/` entries linked from the source (names), sorted.
    pub linked: Vec<String>,
    /// The new `mav0/imu0/data.csv`.
    pub imu_csv: PathBuf,
}

/// Writes `out/mav0/` from `src` (the folder holding `mav0/`, or `mav0/` itself): every entry of
/// `mav0/` but `imu0` linked by its absolute path, `imu0/`'s files copied but `data.csv`, which is
/// rewritten: `mix`'s donors mixed in, then every row through `rw` (a malformed row, here or in a
/// donor, is an error naming its file and line; nothing is skipped, and `data.csv` appears only
/// once complete). `out` must not exist or be an empty folder: a rewrite never overwrites a
/// dataset.
#[cfg(unix)]
pub fn rewrite_dataset(
    src: &Path,
    out: &Path,
    rw: &ImuRewrite,
    mix: &DonorMix,
) -> Result<RewriteSummary, DatasetError> {
    let src_mav0 = mav0_of(src);
    let src_imu = src_mav0.join("imu0/data.csv");
    if !src_imu.is_file() {
        return Err(DatasetError::Layout {
            path: src.to_path_buf(),
            msg: "no mav0/imu0/data.csv here (expected the folder holding mav0/, or mav0/)".into(),
        });
    }
    let src_mav0 = src_mav0.canonicalize().map_err(io(&src_mav0))?;
    // Every row read (and every donor) before anything is written: a band needs the whole record,
    // and a bad donor leaves no half-made copy.
    let (mut samples, stamps): (Vec<ImuSample>, Vec<String>) = read_imu_csv_with_lines(&src_imu)?
        .into_iter()
        .map(|(s, line)| {
            let stamp = line
                .split(',')
                .next()
                .unwrap_or_default()
                .trim()
                .to_string();
            (s, stamp)
        })
        .unzip();
    let donors = [
        (ImuSensorKind::Gyro, &mix.gyro_from),
        (ImuSensorKind::Accel, &mix.accel_from),
    ];
    if donors.iter().any(|(_, from)| from.is_some()) {
        in_time_order(&samples, &src_imu)?;
    }
    let mut mixed = Vec::new();
    for (sensor, from) in donors {
        let Some(from) = from else { continue };
        let donor_csv = mav0_of(from).join("imu0/data.csv");
        if !donor_csv.is_file() {
            return Err(DatasetError::Layout {
                path: from.to_path_buf(),
                msg: "no mav0/imu0/data.csv here to mix in".into(),
            });
        }
        let donor = read_imu_csv(&donor_csv)?;
        in_time_order(&donor, &donor_csv)?;
        mixed.push((
            sensor,
            mix_in(&mut samples, &donor, sensor, mix.lo_hz, mix.hi_hz),
        ));
    }
    if out.exists() {
        let mut entries = std::fs::read_dir(out).map_err(io(out))?;
        if entries.next().is_some() {
            return Err(DatasetError::Layout {
                path: out.to_path_buf(),
                msg: "exists and is not empty; choose a new folder (a rewrite never overwrites)"
                    .into(),
            });
        }
    }
    let out_mav0 = out.join("mav0");
    let out_imu0 = out_mav0.join("imu0");
    std::fs::create_dir_all(&out_imu0).map_err(io(&out_imu0))?;

    let mut linked = Vec::new();
    for e in std::fs::read_dir(&src_mav0).map_err(io(&src_mav0))? {
        let e = e.map_err(io(&src_mav0))?;
        let name = e.file_name();
        if name == "imu0" {
            continue;
        }
        let dst = out_mav0.join(&name);
        std::os::unix::fs::symlink(e.path(), &dst).map_err(io(&dst))?;
        linked.push(name.to_string_lossy().into_owned());
    }
    linked.sort();
    let src_imu0 = src_mav0.join("imu0");
    for e in std::fs::read_dir(&src_imu0).map_err(io(&src_imu0))? {
        let e = e.map_err(io(&src_imu0))?;
        if e.file_name() == "data.csv" || !e.path().is_file() {
            continue;
        }
        let dst = out_imu0.join(e.file_name());
        std::fs::copy(e.path(), &dst).map_err(io(&dst))?;
    }

    let header = {
        let f = std::fs::File::open(&src_imu).map_err(io(&src_imu))?;
        let mut first = String::new();
        std::io::BufReader::new(f)
            .read_line(&mut first)
            .map_err(io(&src_imu))?;
        let first = first.trim_end_matches(['\r', '\n']);
        if first.starts_with('#') {
            first.to_string()
        } else {
            IMU_CSV_HEADER.to_string()
        }
    };
    // Written under another name and renamed when complete: a rewrite stopped by a malformed row
    // (or a full disk) leaves no `data.csv` that reads as a shorter flight.
    let imu_csv = out_imu0.join("data.csv");
    let partial = out_imu0.join("data.csv.partial");
    let mut w = BufWriter::new(std::fs::File::create(&partial).map_err(io(&partial))?);
    writeln!(w, "{header}").map_err(io(&partial))?;
    let m = rw.matrices();
    for (s, stamp) in samples.iter().zip(&stamps) {
        let s = rw.with_matrices(&m, s);
        let (g, a) = (s.gyro_rad_s, s.accel_m_s2);
        writeln!(
            w,
            "{},{},{},{},{},{},{}",
            stamp, g.x, g.y, g.z, a.x, a.y, a.z
        )
        .map_err(io(&partial))?;
    }
    w.flush().map_err(io(&partial))?;
    drop(w);
    std::fs::rename(&partial, &imu_csv).map_err(io(&imu_csv))?;
    Ok(RewriteSummary {
        samples: samples.len(),
        mixed,
        linked,
        imu_csv,
    })
}

/// An error naming `path` if `rows`' stamps go backwards anywhere (mixing walks them in order).
fn in_time_order(rows: &[ImuSample], path: &Path) -> Result<(), DatasetError> {
    match rows.windows(2).position(|w| w[1].t.0 < w[0].t.0) {
        Some(i) => Err(DatasetError::Layout {
            path: path.to_path_buf(),
            msg: format!(
                "timestamps go backwards after data row {} (mixing needs time order)",
                i + 1
            ),
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::read_imu_csv;
    use crate::time::TimeNs;
    use std::f64::consts::FRAC_PI_2;

    fn sample(t: i64, g: [f64; 3], a: [f64; 3]) -> ImuSample {
        ImuSample {
            t: TimeNs(t),
            gyro_rad_s: Vector3::from(g),
            accel_m_s2: Vector3::from(a),
        }
    }

    #[test]
    fn turns_each_sensor_by_its_own_rotation_then_takes_its_bias_out() {
        let rw = ImuRewrite {
            gyro_rotation_rad: Vector3::new(0.0, 0.0, FRAC_PI_2),
            accel_rotation_rad: Vector3::new(FRAC_PI_2, 0.0, 0.0),
            gyro_bias_rad_s: Vector3::new(0.01, 0.0, 0.0),
            accel_bias_m_s2: Vector3::new(0.0, 0.0, 0.5),
        };
        let out = rw.apply(&sample(7, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]));
        assert_eq!(out.t, TimeNs(7));
        // z by +90°: x → y; then the bias.
        assert!((out.gyro_rad_s - Vector3::new(-0.01, 1.0, 0.0)).norm() < 1e-12);
        // x by +90°: y → z; then the bias.
        assert!((out.accel_m_s2 - Vector3::new(0.0, 0.0, 0.5)).norm() < 1e-12);
        let same = ImuRewrite::default().apply(&sample(1, [0.1, 0.2, 0.3], [9.8, 0.1, -0.2]));
        assert_eq!(same, sample(1, [0.1, 0.2, 0.3], [9.8, 0.1, -0.2]));
    }

    fn small_dataset(root: &Path, imu_rows: &str) {
        let mav0 = root.join("mav0");
        std::fs::create_dir_all(mav0.join("imu0")).unwrap();
        std::fs::create_dir_all(mav0.join("cam0/data")).unwrap();
        std::fs::write(mav0.join("cam0/data.csv"), "#timestamp [ns],filename\n").unwrap();
        std::fs::write(mav0.join("imu0/sensor.yaml"), "rate_hz: 200\n").unwrap();
        std::fs::write(mav0.join("imu0/data.csv"), imu_rows).unwrap();
    }

    #[test]
    fn a_rewritten_copy_links_the_rest_and_keeps_the_stamps() {
        let tmp = tempfile::tempdir().unwrap();
        let src = tmp.path().join("src");
        small_dataset(
            &src,
            "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n\
             1403715274302142976,0.1,0.2,0.3,9.0,0.5,-3.0\n\
             1403715274307142912,0.0,0.0,0.0,9.8,0.0,0.0\n",
        );
        let out = tmp.path().join("out");
        let rw = ImuRewrite {
            accel_bias_m_s2: Vector3::new(0.0, 0.5, 0.0),
            ..Default::default()
        };
        let sum = rewrite_dataset(&src, &out, &rw, &DonorMix::default()).unwrap();
        assert_eq!(sum.samples, 2);
        assert_eq!(sum.linked, vec!["cam0".to_string()]);
        assert!(out.join("mav0/cam0").is_symlink());
        assert!(out.join("mav0/cam0/data.csv").is_file());
        assert_eq!(
            std::fs::read_to_string(out.join("mav0/imu0/sensor.yaml")).unwrap(),
            "rate_hz: 200\n"
        );
        let text = std::fs::read_to_string(&sum.imu_csv).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z");
        assert_eq!(lines[1], "1403715274302142976,0.1,0.2,0.3,9,0,-3");
        let rows = read_imu_csv(&sum.imu_csv).unwrap();
        let orig = read_imu_csv(&src.join("mav0/imu0/data.csv")).unwrap();
        assert_eq!(rows.len(), 2);
        for (r, o) in rows.iter().zip(&orig) {
            assert_eq!(r, &rw.apply(o));
        }
        // Never over an existing dataset.
        let again = rewrite_dataset(&src, &out, &rw, &DonorMix::default())
            .unwrap_err()
            .to_string();
        assert!(again.contains("not empty"), "{again}");
    }

    #[test]
    fn a_malformed_row_names_its_line_and_a_missing_imu_its_folder() {
        let tmp = tempfile::tempdir().unwrap();
        let src = tmp.path().join("src");
        small_dataset(
            &src,
            "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n1,0,0,0,9.8,0,0\n2,0,0,x,9.8,0,0\n",
        );
        let e = rewrite_dataset(
            &src,
            &tmp.path().join("out"),
            &ImuRewrite::default(),
            &DonorMix::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("data.csv") && e.contains(":3"), "{e}");
        assert!(!tmp.path().join("out/mav0/imu0/data.csv").exists());
        let e = rewrite_dataset(
            tmp.path(),
            &tmp.path().join("o2"),
            &ImuRewrite::default(),
            &DonorMix::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("no mav0/imu0/data.csv"), "{e}");
    }
}
