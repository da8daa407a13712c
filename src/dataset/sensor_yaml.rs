//! Reading and writing the OpenCV-style `sensor.yaml` files of the ASL/EuRoC layout (`%YAML:1.0`
//! header, `T_BS` as `{cols, rows, data}`), for `cam0` and `imu0`.

use crate::camera::{CameraModel, Distortion, Vignette};
use crate::imu::ImuNoise;
use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use yaml_rust2::{Yaml, YamlLoader};

#[derive(Debug, thiserror::Error)]
pub enum SensorYamlError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: YAML syntax: {msg}")]
    Syntax { path: PathBuf, msg: String },
    #[error("{path}: key '{key}': {msg}")]
    Key {
        path: PathBuf,
        key: String,
        msg: String,
    },
}

/// `cam0/sensor.yaml`.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSensor {
    pub model: CameraModel,
    /// Camera-to-body transform (`T_BS`): `p_body = t_body_cam * p_cam`.
    pub t_body_cam: Isometry3<f64>,
    pub rate_hz: f64,
}

/// `imu0/sensor.yaml`.
#[derive(Clone, Debug, PartialEq)]
pub struct ImuSensor {
    pub noise: ImuNoise,
    /// IMU-to-body transform (`T_BS`; identity in EuRoC, where the body frame is the IMU frame).
    pub t_body_imu: Isometry3<f64>,
    pub rate_hz: f64,
}

struct Doc {
    path: PathBuf,
    root: Yaml,
}

impl Doc {
    fn load(path: &Path) -> Result<Doc, SensorYamlError> {
        let text = std::fs::read_to_string(path).map_err(|source| SensorYamlError::Io {
            path: path.into(),
            source,
        })?;
        // OpenCV writes a `%YAML:1.0` directive that YAML 1.2 parsers reject; drop directives.
        let body: String = text
            .lines()
            .map(|l| {
                if l.trim_start().starts_with('%') {
                    ""
                } else {
                    l
                }
            })
            .collect::<Vec<_>>()
            .join("\n");
        let docs = YamlLoader::load_from_str(&body).map_err(|e| SensorYamlError::Syntax {
            path: path.into(),
            msg: e.to_string(),
        })?;
        let root = docs.into_iter().next().unwrap_or(Yaml::Null);
        if root.as_hash().is_none() {
            return Err(SensorYamlError::Syntax {
                path: path.into(),
                msg: "top level is not a mapping".into(),
            });
        }
        Ok(Doc {
            path: path.into(),
            root,
        })
    }

    fn err(&self, key: &str, msg: impl Into<String>) -> SensorYamlError {
        SensorYamlError::Key {
            path: self.path.clone(),
            key: key.into(),
            msg: msg.into(),
        }
    }

    fn get(&self, key: &str) -> Option<&Yaml> {
        let v = &self.root[key];
        (!v.is_badvalue() && !v.is_null()).then_some(v)
    }

    fn str(&self, key: &str) -> Result<Option<String>, SensorYamlError> {
        match self.get(key) {
            None => Ok(None),
            Some(Yaml::String(s)) => Ok(Some(s.clone())),
            Some(_) => Err(self.err(key, "expected a string")),
        }
    }

    fn number(&self, key: &str) -> Result<f64, SensorYamlError> {
        let v = self.get(key).ok_or_else(|| self.err(key, "missing"))?;
        as_number(v).ok_or_else(|| self.err(key, "expected a number"))
    }

    fn numbers(&self, key: &str, n: usize) -> Result<Vec<f64>, SensorYamlError> {
        let v = self.get(key).ok_or_else(|| self.err(key, "missing"))?;
        numbers_of(v, n).map_err(|m| self.err(key, m))
    }

    fn transform(&self, key: &str) -> Result<Isometry3<f64>, SensorYamlError> {
        let v = self.get(key).ok_or_else(|| self.err(key, "missing"))?;
        let rows = as_number(&v["rows"]).unwrap_or(4.0);
        let cols = as_number(&v["cols"]).unwrap_or(4.0);
        if rows != 4.0 || cols != 4.0 {
            return Err(self.err(key, format!("expected a 4x4 matrix, found {rows}x{cols}")));
        }
        let d = numbers_of(&v["data"], 16).map_err(|m| self.err(&format!("{key}.data"), m))?;
        let m = Matrix4::from_row_slice(&d);
        isometry_from_matrix(&m).map_err(|m| self.err(key, m))
    }
}

fn as_number(v: &Yaml) -> Option<f64> {
    match v {
        Yaml::Integer(i) => Some(*i as f64),
        Yaml::Real(_) => v.as_f64(),
        _ => None,
    }
    .filter(|x| x.is_finite())
}

fn numbers_of(v: &Yaml, n: usize) -> Result<Vec<f64>, String> {
    let arr = v.as_vec().ok_or("expected a list of numbers")?;
    if arr.len() != n {
        return Err(format!("expected {n} numbers, found {}", arr.len()));
    }
    arr.iter()
        .enumerate()
        .map(|(i, x)| as_number(x).ok_or_else(|| format!("element {i} is not a finite number")))
        .collect()
}

/// Converts a 4x4 homogeneous matrix to an isometry, re-orthonormalising a rotation that is
/// orthonormal to calibration precision (1e-3) and rejecting anything else.
pub fn isometry_from_matrix(m: &Matrix4<f64>) -> Result<Isometry3<f64>, String> {
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    let orth_err = (r.transpose() * r - Matrix3::identity()).norm();
    if orth_err > 1e-3 || r.determinant() < 0.0 {
        return Err(format!(
            "rotation block is not a rotation (|RᵀR - I| = {orth_err:.2e})"
        ));
    }
    if (m.fixed_view::<1, 4>(3, 0) - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)).norm() > 1e-9 {
        return Err("last row must be 0 0 0 1".into());
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    let t = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Isometry3::from_parts(t, rot))
}

/// Reads `cam0/sensor.yaml`.
pub fn read_camera_yaml(path: &Path) -> Result<CameraSensor, SensorYamlError> {
    let doc = Doc::load(path)?;
    if let Some(model) = doc.str("camera_model")?
        && model != "pinhole"
    {
        return Err(doc.err(
            "camera_model",
            format!("'{model}' is not supported (pinhole)"),
        ));
    }
    let res = doc.numbers("resolution", 2)?;
    let intr = doc.numbers("intrinsics", 4)?;
    let dist_model = doc
        .str("distortion_model")?
        .unwrap_or_else(|| "none".into());
    let distortion = match dist_model.as_str() {
        "radial-tangential" | "radtan" => {
            let c = doc.numbers("distortion_coefficients", 4)?;
            Distortion::RadTan {
                k1: c[0],
                k2: c[1],
                p1: c[2],
                p2: c[3],
            }
        }
        "equidistant" | "fisheye" => {
            let c = doc.numbers("distortion_coefficients", 4)?;
            Distortion::Equidistant {
                k1: c[0],
                k2: c[1],
                k3: c[2],
                k4: c[3],
            }
        }
        "none" => Distortion::None,
        other => {
            return Err(doc.err(
                "distortion_model",
                format!("'{other}' is not supported (radial-tangential, equidistant, none)"),
            ));
        }
    };
    let (w, h) = (res[0], res[1]);
    if w < 1.0 || h < 1.0 || w.fract() != 0.0 || h.fract() != 0.0 {
        return Err(doc.err("resolution", format!("bad size {w}x{h}")));
    }
    let model = CameraModel::new(
        w as usize,
        h as usize,
        [intr[0], intr[1], intr[2], intr[3]],
        distortion,
    )
    .map_err(|e| doc.err("intrinsics", e.to_string()))?;
    let rate_hz = doc.number("rate_hz")?;
    if rate_hz <= 0.0 {
        return Err(doc.err("rate_hz", "must be positive"));
    }
    Ok(CameraSensor {
        model,
        t_body_cam: doc.transform("T_BS")?,
        rate_hz,
    })
}

/// Reads `imu0/sensor.yaml`.
pub fn read_imu_yaml(path: &Path) -> Result<ImuSensor, SensorYamlError> {
    let doc = Doc::load(path)?;
    let noise = ImuNoise {
        gyro_noise_density: doc.number("gyroscope_noise_density")?,
        gyro_random_walk: doc.number("gyroscope_random_walk")?,
        accel_noise_density: doc.number("accelerometer_noise_density")?,
        accel_random_walk: doc.number("accelerometer_random_walk")?,
    };
    for (k, v) in [
        ("gyroscope_noise_density", noise.gyro_noise_density),
        ("gyroscope_random_walk", noise.gyro_random_walk),
        ("accelerometer_noise_density", noise.accel_noise_density),
        ("accelerometer_random_walk", noise.accel_random_walk),
    ] {
        if v <= 0.0 {
            return Err(doc.err(k, "must be positive"));
        }
    }
    let t_body_imu = match doc.get("T_BS") {
        Some(_) => doc.transform("T_BS")?,
        None => Isometry3::identity(),
    };
    let rate_hz = doc.number("rate_hz")?;
    if rate_hz <= 0.0 {
        return Err(doc.err("rate_hz", "must be positive"));
    }
    Ok(ImuSensor {
        noise,
        t_body_imu,
        rate_hz,
    })
}

fn write_t_bs(out: &mut String, t: &Isometry3<f64>) {
    let m = t.to_homogeneous();
    out.push_str("T_BS:\n  cols: 4\n  rows: 4\n  data: [");
    for r in 0..4 {
        if r > 0 {
            out.push_str("\n         ");
        }
        for c in 0..4 {
            let sep = if r == 3 && c == 3 { "" } else { ", " };
            write!(out, "{:.12}{sep}", m[(r, c)]).unwrap();
        }
    }
    out.push_str("]\n");
}

/// Writes `cam0/sensor.yaml` in the EuRoC layout.
pub fn write_camera_yaml(path: &Path, cam: &CameraSensor, comment: &str) -> std::io::Result<()> {
    let m = &cam.model;
    let mut out = String::from("%YAML:1.0\nsensor_type: camera\n");
    writeln!(out, "comment: {comment}").unwrap();
    write_t_bs(&mut out, &cam.t_body_cam);
    writeln!(out, "rate_hz: {}", cam.rate_hz).unwrap();
    writeln!(out, "resolution: [{}, {}]", m.width, m.height).unwrap();
    out.push_str("camera_model: pinhole\n");
    writeln!(
        out,
        "intrinsics: [{}, {}, {}, {}] # fu, fv, cu, cv",
        m.fx, m.fy, m.cx, m.cy
    )
    .unwrap();
    let (name, c) = match m.distortion {
        Distortion::None => ("none", [0.0; 4]),
        Distortion::RadTan { k1, k2, p1, p2 } => ("radial-tangential", [k1, k2, p1, p2]),
        Distortion::Equidistant { k1, k2, k3, k4 } => ("equidistant", [k1, k2, k3, k4]),
    };
    writeln!(out, "distortion_model: {name}").unwrap();
    writeln!(
        out,
        "distortion_coefficients: [{}, {}, {}, {}]",
        c[0], c[1], c[2], c[3]
    )
    .unwrap();
    std::fs::write(path, out)
}

/// Reads `cam0/vignette.yaml` (vidslam's photometric calibration, see [`Vignette`]):
/// `vignette_model: radial-polynomial`, `centre_px: [cu, cv]`, `radius_px: r`,
/// `coefficients: [k1, k2, k3]`. `resolution` is the image size the model is checked over.
pub fn read_vignette_yaml(
    path: &Path,
    resolution: (usize, usize),
) -> Result<Vignette, SensorYamlError> {
    let doc = Doc::load(path)?;
    match doc.str("vignette_model")? {
        Some(m) if m == "radial-polynomial" => {}
        Some(m) => {
            return Err(doc.err(
                "vignette_model",
                format!("'{m}' is not supported (radial-polynomial)"),
            ));
        }
        None => return Err(doc.err("vignette_model", "missing")),
    }
    let c = doc.numbers("centre_px", 2)?;
    let k = doc.numbers("coefficients", 3)?;
    let v = Vignette {
        centre_px: [c[0], c[1]],
        radius_px: doc.number("radius_px")?,
        coefficients: [k[0], k[1], k[2]],
    };
    v.validate(resolution.0, resolution.1)
        .map_err(|m| doc.err("coefficients", m))?;
    Ok(v)
}

/// Writes `cam0/vignette.yaml` (read by [`read_vignette_yaml`]).
pub fn write_vignette_yaml(path: &Path, v: &Vignette, comment: &str) -> std::io::Result<()> {
    let mut out = String::from("%YAML:1.0\n");
    writeln!(out, "comment: {comment}").unwrap();
    out.push_str(
        "# V = 1 + k1 s^2 + k2 s^4 + k3 s^6, s = distance to centre_px / radius_px; image / V\n",
    );
    out.push_str("vignette_model: radial-polynomial\n");
    writeln!(out, "centre_px: [{}, {}]", v.centre_px[0], v.centre_px[1]).unwrap();
    writeln!(out, "radius_px: {}", v.radius_px).unwrap();
    let [k1, k2, k3] = v.coefficients;
    writeln!(out, "coefficients: [{k1}, {k2}, {k3}]").unwrap();
    std::fs::write(path, out)
}

/// Writes `imu0/sensor.yaml` in the EuRoC layout.
pub fn write_imu_yaml(path: &Path, imu: &ImuSensor, comment: &str) -> std::io::Result<()> {
    let n = &imu.noise;
    let mut out = String::from("%YAML:1.0\nsensor_type: imu\n");
    writeln!(out, "comment: {comment}").unwrap();
    write_t_bs(&mut out, &imu.t_body_imu);
    writeln!(out, "rate_hz: {}", imu.rate_hz).unwrap();
    writeln!(
        out,
        "gyroscope_noise_density: {:e}     # [ rad / s / sqrt(Hz) ]",
        n.gyro_noise_density
    )
    .unwrap();
    writeln!(
        out,
        "gyroscope_random_walk: {:e}       # [ rad / s^2 / sqrt(Hz) ]",
        n.gyro_random_walk
    )
    .unwrap();
    writeln!(
        out,
        "accelerometer_noise_density: {:e} # [ m / s^2 / sqrt(Hz) ]",
        n.accel_noise_density
    )
    .unwrap();
    writeln!(
        out,
        "accelerometer_random_walk: {:e}   # [ m / s^3 / sqrt(Hz) ]",
        n.accel_random_walk
    )
    .unwrap();
    std::fs::write(path, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_and_imu_yaml_round_trip() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        let cam = CameraSensor {
            model: CameraModel::euroc_cam0(),
            t_body_cam: Isometry3::new(
                nalgebra::Vector3::new(-0.02, -0.06, 0.01),
                nalgebra::Vector3::new(0.01, -0.02, 1.57),
            ),
            rate_hz: 20.0,
        };
        write_camera_yaml(&d.join("cam.yaml"), &cam, "test").unwrap();
        let back = read_camera_yaml(&d.join("cam.yaml")).unwrap();
        assert_eq!(back.model, cam.model);
        assert!((back.t_body_cam.to_homogeneous() - cam.t_body_cam.to_homogeneous()).norm() < 1e-9);
        let imu = ImuSensor {
            noise: ImuNoise::euroc_adis16448(),
            t_body_imu: Isometry3::identity(),
            rate_hz: 200.0,
        };
        write_imu_yaml(&d.join("imu.yaml"), &imu, "test").unwrap();
        assert_eq!(read_imu_yaml(&d.join("imu.yaml")).unwrap(), imu);
    }

    #[test]
    fn vignette_yaml_round_trip_and_errors() {
        let v = Vignette {
            centre_px: [367.215, 248.375],
            radius_px: 447.25,
            coefficients: [-0.35, 0.01, -0.002],
        };
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("vignette.yaml");
        write_vignette_yaml(&p, &v, "test").unwrap();
        assert_eq!(read_vignette_yaml(&p, (752, 480)).unwrap(), v);
        std::fs::write(&p, "vignette_model: radial-polynomial\ncentre_px: [1, 2]\nradius_px: 100\ncoefficients: [-0.99, 0, 0]\n").unwrap();
        let e = read_vignette_yaml(&p, (752, 480)).unwrap_err().to_string();
        assert!(
            e.contains("vignette.yaml") && e.contains("coefficients") && e.contains("attenuation"),
            "{e}"
        );
        std::fs::write(&p, "vignette_model: lut\n").unwrap();
        let e = read_vignette_yaml(&p, (752, 480)).unwrap_err().to_string();
        assert!(e.contains("vignette_model"), "{e}");
    }

    #[test]
    fn errors_name_file_and_key() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("cam.yaml");
        std::fs::write(
            &p,
            "%YAML:1.0\nresolution: [752, 480]\nintrinsics: [1, 2, 3]\n",
        )
        .unwrap();
        let e = read_camera_yaml(&p).unwrap_err().to_string();
        assert!(
            e.contains("cam.yaml") && e.contains("'intrinsics'") && e.contains("4 numbers"),
            "{e}"
        );
        std::fs::write(
            &p,
            "%YAML:1.0\nresolution: [752, 480]\nintrinsics: [1, 2, 3, 4]\n\
             distortion_model: weird\n",
        )
        .unwrap();
        let e = read_camera_yaml(&p).unwrap_err().to_string();
        assert!(
            e.contains("'distortion_model'") && e.contains("weird"),
            "{e}"
        );
        std::fs::write(&p, "%YAML:1.0\ngyroscope_noise_density: abc\n").unwrap();
        let e = read_imu_yaml(&p).unwrap_err().to_string();
        assert!(e.contains("'gyroscope_noise_density'"), "{e}");
    }
}
