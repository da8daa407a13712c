//! Line-by-line reading of the ASL `data.csv` files with file:line error context.

use super::DatasetError;
use crate::time::TimeNs;
use std::fs::File;
use std::io::{BufRead, BufReader, Lines};
use std::path::{Path, PathBuf};

/// Iterates the data rows (comments and blank lines skipped) of a CSV file as
/// `(line_number, fields)`, checking that the first column (ns) strictly increases.
pub(crate) struct CsvRows {
    path: PathBuf,
    lines: Lines<BufReader<File>>,
    lineno: usize,
    last_t: Option<TimeNs>,
}

impl CsvRows {
    pub(crate) fn open(path: &Path) -> Result<Self, DatasetError> {
        let f = File::open(path).map_err(|source| DatasetError::Io {
            path: path.into(),
            source,
        })?;
        Ok(CsvRows {
            path: path.into(),
            lines: BufReader::new(f).lines(),
            lineno: 0,
            last_t: None,
        })
    }

    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// Line number (1-based) of the row last returned.
    pub(crate) fn line(&self) -> usize {
        self.lineno
    }

    pub(crate) fn error(&self, msg: impl Into<String>) -> DatasetError {
        DatasetError::Parse {
            path: self.path.clone(),
            line: self.lineno,
            msg: msg.into(),
        }
    }

    /// Next row: its timestamp and the remaining fields (trimmed).
    pub(crate) fn next_row(&mut self) -> Option<Result<(TimeNs, Vec<String>), DatasetError>> {
        loop {
            let line = match self.lines.next()? {
                Ok(l) => l,
                Err(source) => {
                    return Some(Err(DatasetError::Io {
                        path: self.path.clone(),
                        source,
                    }));
                }
            };
            self.lineno += 1;
            let s = line.trim();
            if s.is_empty() || s.starts_with('#') {
                continue;
            }
            let mut fields = s.split(',').map(|f| f.trim().to_string());
            let t_str = fields.next().unwrap_or_default();
            let t = match t_str.parse::<i64>() {
                Ok(v) => TimeNs(v),
                Err(_) => {
                    return Some(Err(self.error(format!(
                        "column 1: '{t_str}' is not an integer timestamp in ns"
                    ))));
                }
            };
            if let Some(prev) = self.last_t
                && t <= prev
            {
                return Some(Err(self.error(format!(
                    "timestamp {} ns is not after the previous row's {} ns",
                    t.0, prev.0
                ))));
            }
            self.last_t = Some(t);
            return Some(Ok((t, fields.collect())));
        }
    }

    /// Parses `fields[i]` as a finite f64 (column numbers in errors count the timestamp as 1).
    pub(crate) fn number(&self, fields: &[String], i: usize) -> Result<f64, DatasetError> {
        let s = fields.get(i).ok_or_else(|| {
            self.error(format!(
                "missing column {} (found {})",
                i + 2,
                fields.len() + 1
            ))
        })?;
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(self.error(format!("column {}: '{s}' is not a finite number", i + 2))),
        }
    }
}
