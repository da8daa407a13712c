//! EuRoC/ASL IMU CSV (`mav0/imu0/data.csv`): timestamp ns, gyro rad/s, accel m/s² (body frame).

use std::path::{Path, PathBuf};

/// One row of an EuRoC IMU file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EurocImuRow {
    pub t_ns: i64,
    pub gyro_rad_s: [f64; 3],
    pub accel_m_s2: [f64; 3],
}

/// Why an EuRoC IMU file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum EurocImuError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {msg}")]
    Parse {
        path: PathBuf,
        line: usize,
        msg: String,
    },
}

/// Reads every row; `#` comment lines and blank lines are skipped. Rows must have 7 finite
/// columns and strictly increasing timestamps.
pub fn read_euroc_imu_csv(path: &Path) -> Result<Vec<EurocImuRow>, EurocImuError> {
    let text = std::fs::read_to_string(path).map_err(|source| EurocImuError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_euroc_imu_csv(&text, path)
}

/// [`read_euroc_imu_csv`] on text already in memory; `path` is only used in errors.
pub fn parse_euroc_imu_csv(text: &str, path: &Path) -> Result<Vec<EurocImuRow>, EurocImuError> {
    let mut rows: Vec<EurocImuRow> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let err = |msg: String| EurocImuError::Parse {
            path: path.to_path_buf(),
            line: i + 1,
            msg,
        };
        let cols: Vec<&str> = line.split(',').map(str::trim).collect();
        if cols.len() != 7 {
            return Err(err(format!("expected 7 columns, found {}", cols.len())));
        }
        let t_ns: i64 = cols[0]
            .parse()
            .map_err(|e| err(format!("timestamp {:?}: {e}", cols[0])))?;
        let mut v = [0.0f64; 6];
        for (k, c) in cols[1..].iter().enumerate() {
            v[k] = c
                .parse()
                .map_err(|e| err(format!("column {}: {c:?}: {e}", k + 2)))?;
            if !v[k].is_finite() {
                return Err(err(format!("column {} is not finite: {c}", k + 2)));
            }
        }
        if let Some(prev) = rows.last()
            && t_ns <= prev.t_ns
        {
            return Err(err(format!(
                "timestamp {t_ns} ns does not increase (previous {} ns)",
                prev.t_ns
            )));
        }
        rows.push(EurocImuRow {
            t_ns,
            gyro_rad_s: [v[0], v[1], v[2]],
            accel_m_s2: [v[3], v[4], v[5]],
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_reports_line_numbers() {
        let text = "#timestamp,...\n10,1,2,3,4,5,6\n\n20,1,2,3,4,5,6\n";
        let rows = parse_euroc_imu_csv(text, Path::new("x.csv")).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].accel_m_s2, [4.0, 5.0, 6.0]);
        let e = parse_euroc_imu_csv("10,1,2,3,4,5,6\n5,1,2,3,4,5,6\n", Path::new("x.csv"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("x.csv:2: timestamp 5 ns does not increase"),
            "{e}"
        );
        let e = parse_euroc_imu_csv("10,1,2,3,4,nan,6\n", Path::new("y.csv"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("y.csv:1: column 6 is not finite"), "{e}");
    }
}
