//! Time: signed 64-bit nanoseconds everywhere (the EuRoC/ASL convention).
//!
//! [`TimeNs`] is a point in time on some clock (dataset clock, host monotonic clock, device clock —
//! the variable name says which). Durations are plain `i64` nanoseconds (`_ns`) or `f64` seconds
//! (`_s`); conversions are explicit.

use serde::{Deserialize, Serialize};
use std::fmt;

/// Nanoseconds since an arbitrary epoch of the clock that produced it.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[serde(transparent)]
pub struct TimeNs(pub i64);

impl TimeNs {
    pub const NS_PER_S: i64 = 1_000_000_000;

    /// From seconds; rounds to the nearest nanosecond.
    pub fn from_secs_f64(t_s: f64) -> Self {
        TimeNs((t_s * 1e9).round() as i64)
    }

    /// To seconds. An f64 holds ns resolution up to ~104 days of epoch offset; for absolute
    /// Unix-epoch times (1.4e18 ns) the result is exact only to ~0.25 us. Use [`TimeNs::secs_since`]
    /// for differences.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    /// `self - earlier` in seconds, exact for any pair of nearby absolute times.
    pub fn secs_since(self, earlier: TimeNs) -> f64 {
        (self.0 - earlier.0) as f64 * 1e-9
    }

    /// `self - earlier` in nanoseconds.
    pub fn ns_since(self, earlier: TimeNs) -> i64 {
        self.0 - earlier.0
    }

    pub fn add_ns(self, dt_ns: i64) -> Self {
        TimeNs(self.0 + dt_ns)
    }

    /// TUM-format seconds string with nanosecond precision, without going through an f64.
    pub fn to_secs_string(self) -> String {
        let sign = if self.0 < 0 { "-" } else { "" };
        let a = self.0.unsigned_abs();
        format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000)
    }

    /// Parses a decimal seconds string (as in TUM files) exactly to nanoseconds, without an f64
    /// round trip. Accepts an optional sign, up to 9 fractional digits (more are rounded), and
    /// scientific notation (through f64, as a fallback).
    pub fn parse_secs(s: &str) -> Option<Self> {
        let s = s.trim();
        if s.contains(['e', 'E']) {
            let v: f64 = s.parse().ok()?;
            return v.is_finite().then(|| TimeNs::from_secs_f64(v));
        }
        let (neg, body) = match s.strip_prefix('-') {
            Some(b) => (true, b),
            None => (false, s.strip_prefix('+').unwrap_or(s)),
        };
        let (int_part, frac_part) = body.split_once('.').unwrap_or((body, ""));
        if int_part.is_empty() && frac_part.is_empty() {
            return None;
        }
        if !int_part.bytes().all(|b| b.is_ascii_digit())
            || !frac_part.bytes().all(|b| b.is_ascii_digit())
        {
            return None;
        }
        let secs: i64 = if int_part.is_empty() {
            0
        } else {
            int_part.parse().ok()?
        };
        let mut frac_ns: i64 = 0;
        for (i, b) in frac_part.bytes().enumerate() {
            let d = (b - b'0') as i64;
            if i < 9 {
                frac_ns += d * 10i64.pow(8 - i as u32);
            } else if i == 9 {
                if d >= 5 {
                    frac_ns += 1;
                }
            } else {
                break;
            }
        }
        let ns = secs.checked_mul(Self::NS_PER_S)?.checked_add(frac_ns)?;
        Some(TimeNs(if neg { -ns } else { ns }))
    }
}

/// Now on the host's monotonic clock (Linux `CLOCK_MONOTONIC`: nanoseconds since boot, not counting
/// suspend, never stepped by NTP). This is the "host monotonic" time base that live pipelines
/// stamp samples with; it is the same clock as Python's `time.monotonic_ns()` on Linux.
pub fn host_monotonic_now() -> TimeNs {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_MONOTONIC) failed");
    // time_t / c_long are i32 on 32-bit ARM companion computers: the casts are not no-ops there.
    #[allow(clippy::unnecessary_cast)]
    TimeNs(ts.tv_sec as i64 * TimeNs::NS_PER_S + ts.tv_nsec as i64)
}

impl fmt::Display for TimeNs {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ns", self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secs_string_round_trip_is_exact() {
        for ns in [
            0i64,
            1,
            999_999_999,
            1_403_715_273_262_142_976,
            -1_500_000_001,
        ] {
            let t = TimeNs(ns);
            assert_eq!(TimeNs::parse_secs(&t.to_secs_string()), Some(t), "{ns}");
        }
    }

    #[test]
    fn parse_secs_forms() {
        assert_eq!(TimeNs::parse_secs("1.5"), Some(TimeNs(1_500_000_000)));
        assert_eq!(TimeNs::parse_secs("-0.25"), Some(TimeNs(-250_000_000)));
        assert_eq!(TimeNs::parse_secs("3"), Some(TimeNs(3_000_000_000)));
        assert_eq!(TimeNs::parse_secs(".5"), Some(TimeNs(500_000_000)));
        assert_eq!(
            TimeNs::parse_secs("1.0000000006"),
            Some(TimeNs(1_000_000_001))
        );
        assert_eq!(TimeNs::parse_secs("1.4e0"), Some(TimeNs(1_400_000_000)));
        assert_eq!(TimeNs::parse_secs("abc"), None);
        assert_eq!(TimeNs::parse_secs(""), None);
        assert_eq!(TimeNs::parse_secs("1.2.3"), None);
    }

    #[test]
    fn host_monotonic_clock_is_monotonic_and_positive() {
        let a = host_monotonic_now();
        let b = host_monotonic_now();
        assert!(a.0 > 0 && b >= a, "{a} then {b}");
    }

    #[test]
    fn differences_are_exact_for_absolute_times() {
        let a = TimeNs(1_403_715_273_262_142_976);
        let b = a.add_ns(50_000_128);
        assert_eq!(b.ns_since(a), 50_000_128);
        assert!((b.secs_since(a) - 0.050_000_128).abs() < 1e-15);
    }
}
