//! Summary statistics of a set of non-negative errors (same definitions as `evo`).

/// RMSE, mean, median and max of a set of errors, in the errors' unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorStats {
    pub rmse: f64,
    pub mean: f64,
    /// Middle value; the mean of the two middle values for an even count (as numpy's median).
    pub median: f64,
    pub max: f64,
    pub count: usize,
}

impl ErrorStats {
    /// Statistics of `errors`, or `None` when there are none or one is not finite.
    pub fn of(errors: &[f64]) -> Option<ErrorStats> {
        if errors.is_empty() || errors.iter().any(|e| !e.is_finite()) {
            return None;
        }
        let n = errors.len() as f64;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            0.5 * (sorted[mid - 1] + sorted[mid])
        };
        Some(ErrorStats {
            rmse: (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
            mean: errors.iter().sum::<f64>() / n,
            median,
            max: sorted[sorted.len() - 1],
            count: errors.len(),
        })
    }
}

/// `values` in ascending order (for [`percentile`]).
pub fn sorted(values: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = values.collect();
    v.sort_by(f64::total_cmp);
    v
}

/// The `p`-th percentile (0–100) of ascending `sorted`, nearest rank; 0 when empty.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        let s = ErrorStats::of(&[3.0, 4.0, 0.0, 1.0]).unwrap();
        assert_eq!(s.count, 4);
        assert!((s.rmse - (26.0f64 / 4.0).sqrt()).abs() < 1e-15);
        assert_eq!(s.mean, 2.0);
        assert_eq!(s.median, 2.0);
        assert_eq!(s.max, 4.0);
        assert_eq!(ErrorStats::of(&[5.0, 1.0, 2.0]).unwrap().median, 2.0);
    }

    #[test]
    fn empty_or_non_finite_gives_none() {
        assert_eq!(ErrorStats::of(&[]), None);
        assert_eq!(ErrorStats::of(&[1.0, f64::NAN]), None);
        assert_eq!(ErrorStats::of(&[f64::INFINITY]), None);
    }
}
