//! One IMU's readings mixed into another's, in a frequency band (`vidslam dataset imu-rewrite
//! --gyro-from/--accel-from DIR --mix-band-hz LO,HI`).
//!
//! Why: a render of a real flight with its real IMU (S-V101) and the same render with the
//! simulator's IMU (consistent with the rendered camera by construction) differ in an odometry's
//! error; which part of the real sensor's disagreement costs it is answered by replaying the
//! consistent IMU with one band of the real one's difference put in:
//!
//! `x'(t) = x(t) + B[lo, hi)(d)(t)`,  `d(t) = x_donor(t) − x(t)`
//!
//! per axis of the chosen sensor, where `x_donor(t)` is the donor's row nearest in time (within half
//! the base's sample period; a row without one keeps `d = 0`) and `B` keeps the discrete Fourier
//! components of the whole series whose frequency `k · rate / n` lies in `[lo, hi)` — a
//! zero-phase, brick-wall band over the record (NumPy's `irfft(mask · rfft(d))`). `[0, ∞)` puts
//! the donor's readings in whole, bit for bit. The series is taken as uniformly sampled at the
//! base's median rate (EuRoC's IMU is; its stamps jitter by microseconds). A brick wall rings
//! (Gibbs) around a step in the difference and wraps at the record's ends, so a band is a
//! diagnosis of a slowly varying disagreement, not a filter for a stream.

use crate::imu::ImuSample;
use nalgebra::Vector3;

/// Which sensor of the donor is mixed in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImuSensorKind {
    Gyro,
    Accel,
}

/// What [`mix_in`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MixSummary {
    /// Base rows given the donor's nearest row.
    pub matched: usize,
    /// Base rows with no donor row within half a sample period (left as they were).
    pub unmatched: usize,
    /// RMS of the band of the difference that was added, per axis (rad/s or m/s²).
    pub band_rms: Vector3<f64>,
}

/// Median sample rate of `samples`, Hz (`None` below two samples or for equal stamps).
pub fn median_rate_hz(samples: &[ImuSample]) -> Option<f64> {
    let mut dt: Vec<i64> = samples.windows(2).map(|w| w[1].t.0 - w[0].t.0).collect();
    if dt.is_empty() {
        return None;
    }
    let mid = dt.len() / 2;
    let (_, m, _) = dt.select_nth_unstable(mid);
    (*m > 0).then(|| 1e9 / *m as f64)
}

/// The part of `x` whose discrete Fourier components have frequency `k · rate_hz / n` in
/// `[lo_hz, hi_hz)`, `k = 0 ..= n/2` (each with its mirror), as a real series of the same length.
/// Computed as the projection onto the components below `hi` less those below `lo`, each
/// component by a direct sum over the series (cost `n` per component kept; a 143 s, 200 Hz
/// record up to 1 Hz is 143 components).
pub fn band_pass(x: &[f64], rate_hz: f64, lo_hz: f64, hi_hz: f64) -> Vec<f64> {
    let below_hi = below(x, rate_hz, hi_hz);
    let below_lo = below(x, rate_hz, lo_hz);
    below_hi.iter().zip(&below_lo).map(|(h, l)| h - l).collect()
}

/// The projection of `x` onto its Fourier components of frequency below `cut_hz`.
fn below(x: &[f64], rate_hz: f64, cut_hz: f64) -> Vec<f64> {
    let n = x.len();
    if n == 0 || cut_hz <= 0.0 {
        return vec![0.0; n];
    }
    // Components k with k · rate / n < cut, k ≤ n / 2.
    let half = n / 2;
    let kept = (0..=half)
        .take_while(|&k| (k as f64) * rate_hz / (n as f64) < cut_hz)
        .count();
    if kept == half + 1 {
        return x.to_vec();
    }
    // Twiddles e^{2πi j / n}; the phase k·t is taken modulo n in integers, so it stays exact.
    let (cos, sin): (Vec<f64>, Vec<f64>) = (0..n)
        .map(|j| {
            let a = std::f64::consts::TAU * (j as f64) / (n as f64);
            (a.cos(), a.sin())
        })
        .unzip();
    let mut out = vec![0.0; n];
    for k in 0..kept {
        let (mut re, mut im) = (0.0, 0.0);
        let mut j = 0usize;
        for &v in x {
            re += v * cos[j];
            im -= v * sin[j];
            j += k;
            if j >= n {
                j -= n;
            }
        }
        // A real series' component k and its mirror n − k together; k = 0 (and k = n/2 for an
        // even n, whose mirror is itself) once.
        let w = if k == 0 || 2 * k == n { 1.0 } else { 2.0 } / n as f64;
        let mut j = 0usize;
        for o in out.iter_mut() {
            *o += w * (re * cos[j] - im * sin[j]);
            j += k;
            if j >= n {
                j -= n;
            }
        }
    }
    out
}

/// Puts the band `[lo_hz, hi_hz)` of `donor`'s difference from `base` into `base`'s `sensor`
/// (the module's doc). `donor` must be sorted by time; `base` is sorted by time and at least two
/// samples long (else nothing is done and every row counts as unmatched).
pub fn mix_in(
    base: &mut [ImuSample],
    donor: &[ImuSample],
    sensor: ImuSensorKind,
    lo_hz: f64,
    hi_hz: f64,
) -> MixSummary {
    let Some(rate_hz) = median_rate_hz(base) else {
        return MixSummary {
            unmatched: base.len(),
            ..Default::default()
        };
    };
    let half_period_ns = (0.5e9 / rate_hz) as i64;
    let value = |s: &ImuSample| match sensor {
        ImuSensorKind::Gyro => s.gyro_rad_s,
        ImuSensorKind::Accel => s.accel_m_s2,
    };
    let mut sum = MixSummary::default();
    let mut d = [
        vec![0.0; base.len()],
        vec![0.0; base.len()],
        vec![0.0; base.len()],
    ];
    let mut donor_row = vec![None; base.len()];
    let mut j = 0usize;
    for (i, s) in base.iter().enumerate() {
        // The donor's rows are walked once: `j` is the first not earlier than this row.
        while j < donor.len() && donor[j].t.0 < s.t.0 {
            j += 1;
        }
        let nearest = [j.checked_sub(1), (j < donor.len()).then_some(j)]
            .into_iter()
            .flatten()
            .min_by_key(|&c| (donor[c].t.0 - s.t.0).abs())
            .filter(|&c| (donor[c].t.0 - s.t.0).abs() <= half_period_ns);
        match nearest {
            Some(c) => {
                donor_row[i] = Some(c);
                let diff = value(&donor[c]) - value(s);
                for (axis, col) in d.iter_mut().enumerate() {
                    col[i] = diff[axis];
                }
                sum.matched += 1;
            }
            None => sum.unmatched += 1,
        }
    }
    // The whole band is the donor's reading itself (not `x + (x_donor − x)`, which may differ in
    // the last bit).
    let whole = lo_hz <= 0.0 && hi_hz == f64::INFINITY;
    let band = d.map(|col| band_pass(&col, rate_hz, lo_hz, hi_hz));
    let mut sq = Vector3::zeros();
    for (i, s) in base.iter_mut().enumerate() {
        let b = Vector3::new(band[0][i], band[1][i], band[2][i]);
        sq += b.component_mul(&b);
        let v = match sensor {
            ImuSensorKind::Gyro => &mut s.gyro_rad_s,
            ImuSensorKind::Accel => &mut s.accel_m_s2,
        };
        match donor_row[i] {
            Some(c) if whole => *v = value(&donor[c]),
            _ => *v += b,
        }
    }
    if !base.is_empty() {
        sum.band_rms = (sq / base.len() as f64).map(f64::sqrt);
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::TimeNs;
    use std::f64::consts::TAU;

    /// `n` samples at 200 Hz of a constant, a 0.5 Hz and a 3 Hz sine (each a whole number of
    /// cycles over the record: exact components).
    fn three_tones(n: usize) -> (Vec<f64>, [Vec<f64>; 3]) {
        let t = |i: usize| i as f64 / 200.0;
        let c: Vec<f64> = (0..n).map(|_| 0.7).collect();
        let slow: Vec<f64> = (0..n)
            .map(|i| 0.2 * (TAU * 0.5 * t(i) + 0.3).sin())
            .collect();
        let fast: Vec<f64> = (0..n).map(|i| 0.05 * (TAU * 3.0 * t(i)).cos()).collect();
        let x = (0..n).map(|i| c[i] + slow[i] + fast[i]).collect();
        (x, [c, slow, fast])
    }

    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn each_band_keeps_its_own_tones_and_the_bands_add_up_to_the_series() {
        // 8 s at 200 Hz: components every 0.125 Hz, so 0.5 and 3 Hz are bins 4 and 24.
        let (x, [c, slow, fast]) = three_tones(1600);
        assert!(max_diff(&band_pass(&x, 200.0, 0.0, 0.1), &c) < 1e-9);
        assert!(max_diff(&band_pass(&x, 200.0, 0.1, 1.0), &slow) < 1e-9);
        assert!(max_diff(&band_pass(&x, 200.0, 1.0, f64::INFINITY), &fast) < 1e-9);
        assert!(max_diff(&band_pass(&x, 200.0, 0.0, f64::INFINITY), &x) == 0.0);
        assert!(
            band_pass(&x, 200.0, 5.0, 50.0)
                .iter()
                .all(|v| v.abs() < 1e-9)
        );
        // An odd length, with a tone that is not a whole number of cycles: the bands still add
        // up to the series exactly (a partition of the components).
        let y: Vec<f64> = (0..1001)
            .map(|i| (TAU * 0.37 * i as f64 / 200.0).sin() + 0.01 * i as f64)
            .collect();
        let parts = [
            band_pass(&y, 200.0, 0.0, 0.2),
            band_pass(&y, 200.0, 0.2, 1.5),
            band_pass(&y, 200.0, 1.5, f64::INFINITY),
        ];
        let sum: Vec<f64> = (0..y.len())
            .map(|i| parts.iter().map(|p| p[i]).sum())
            .collect();
        assert!(max_diff(&sum, &y) < 1e-9);
        // The Nyquist component of an even length, (−1)^i, belongs to the top band only.
        let alt: Vec<f64> = (0..64)
            .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        assert!(max_diff(&band_pass(&alt, 200.0, 99.0, 101.0), &alt) < 1e-12);
        assert!(
            band_pass(&alt, 200.0, 0.0, 99.0)
                .iter()
                .all(|v| v.abs() < 1e-12)
        );
    }

    fn samples(n: usize, stamp_offset_ns: i64, accel: impl Fn(usize) -> f64) -> Vec<ImuSample> {
        (0..n)
            .map(|i| ImuSample {
                t: TimeNs(1_000_000_000 + 5_000_000 * i as i64 + stamp_offset_ns),
                gyro_rad_s: Vector3::new(0.01, 0.02, 0.03),
                accel_m_s2: Vector3::new(9.81, accel(i), 0.0),
            })
            .collect()
    }

    #[test]
    fn a_band_of_the_donor_s_difference_goes_into_the_chosen_sensor_only() {
        let (tones, [_, slow, fast]) = three_tones(1600);
        let mut base = samples(1600, 0, |_| 0.0);
        // The donor's stamps are 1 ms off (nearest within half a period) and its gyro differs.
        let mut donor = samples(1600, 1_000_000, |i| tones[i]);
        for s in &mut donor {
            s.gyro_rad_s = Vector3::new(1.0, 1.0, 1.0);
        }
        let sum = mix_in(&mut base, &donor, ImuSensorKind::Accel, 0.1, 1.0);
        assert_eq!((sum.matched, sum.unmatched), (1600, 0));
        let y: Vec<f64> = base.iter().map(|s| s.accel_m_s2.y).collect();
        assert!(max_diff(&y, &slow) < 1e-9);
        assert!((sum.band_rms.y - 0.2 / 2f64.sqrt()).abs() < 1e-9);
        assert!(
            base.iter()
                .all(|s| s.accel_m_s2.x == 9.81 && s.accel_m_s2.z == 0.0)
        );
        assert!(
            base.iter()
                .all(|s| s.gyro_rad_s == Vector3::new(0.01, 0.02, 0.03))
        );
        assert!(max_diff(&y, &fast) > 0.1);

        // The whole band puts the donor's sensor in as it reads; a donor row 3 ms away is too
        // far (half a period is 2.5 ms) and its base row is kept.
        let mut base = samples(1600, 0, |_| 0.0);
        let mut donor = samples(1600, 0, |i| tones[i]);
        for s in &mut donor {
            s.gyro_rad_s = Vector3::new(1.0, 1.0, 1.0);
        }
        donor[10].t.0 += 3_000_000;
        let sum = mix_in(&mut base, &donor, ImuSensorKind::Gyro, 0.0, f64::INFINITY);
        assert_eq!((sum.matched, sum.unmatched), (1599, 1));
        assert!(base[10].gyro_rad_s == Vector3::new(0.01, 0.02, 0.03));
        assert!(
            base.iter().enumerate().all(
                |(i, s)| i == 10 || (s.gyro_rad_s - Vector3::new(1.0, 1.0, 1.0)).norm() < 1e-15
            )
        );
        // Too short to have a rate: nothing done, every row unmatched.
        let mut one = samples(1, 0, |_| 0.0);
        let sum = mix_in(&mut one, &donor, ImuSensorKind::Accel, 0.0, 1.0);
        assert_eq!((sum.matched, sum.unmatched), (0, 1));
    }
}
