//! Line-by-line reading of the ASL `data.csv` files with file:line error context.

use super::DatasetError;
use crate::time::TimeNs;
use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

/// Iterates the data rows (comments and blank lines skipped) of a CSV file as
/// `(line_number, fields)`, checking that the first column (ns) strictly increases.
pub(crate) struct CsvRows {
    path: PathBuf,
    reader: BufReader<File>,
    /// The last line read, exactly as in the file without its `\n` (a `\r` is kept).
    raw: String,
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
            reader: BufReader::new(f),
            raw: String::new(),
            lineno: 0,
            last_t: None,
        })
    }

    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// The row last returned, byte for byte as in the file (without its line feed).
    pub(crate) fn raw_line(&self) -> &str {
        &self.raw
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
            self.raw.clear();
            match self.reader.read_line(&mut self.raw) {
                Ok(0) => return None,
                Ok(_) => {
                    if self.raw.ends_with('\n') {
                        self.raw.pop();
                    }
                }
                Err(source) => {
                    return Some(Err(DatasetError::Io {
                        path: self.path.clone(),
                        source,
                    }));
                }
            }
            self.lineno += 1;
            let s = self.raw.trim();
            if s.is_empty() || s.starts_with('#') {
                continue;
            }
            let mut fields: Vec<String> = s.split(',').map(|f| f.trim().to_string()).collect();
            let t_str = fields.remove(0);
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
            return Some(Ok((t, fields)));
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
