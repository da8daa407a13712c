//! Lower-envelope clock model: device time → host monotonic time.
//!
//! # Model
//!
//! The device clock and the host clock are related by an affine map over the window of interest:
//! `host_true = host_anchor + (device - device_anchor) * (1 + skew)`. Each observation is a device
//! timestamp `d_i` and the host time `h_i` at which it was received, `h_i = host_true(d_i) + δ_i`
//! with an unknown delay `δ_i ≥ 0`. Every observation therefore lies on or above the true line, and
//! the line is the one that lies below all observations and is *closest* to them. Minimising the
//! summed residual `Σ (h_i − line(d_i))` subject to `line(d_i) ≤ h_i` is a linear program whose
//! optimum is the edge of the lower convex hull of the points spanning the mean device time `d̄`
//! (the objective equals `Σ h_i − n · line(d̄)`, so it maximises the line's height at `d̄`). This
//! is the TICSync estimator; unlike least squares it is unbiased by the mean delay and its error
//! shrinks with the *smallest* delays seen, not their spread.
//!
//! # Window
//!
//! Observations live in a sliding window (`window_ns`, `max_observations`) so slow drift of the
//! skew (temperature) is followed. The hull is maintained incrementally as points arrive (device
//! times increase, so appending is the monotone-chain step, amortised O(1)); when the window
//! overflows it is trimmed to three quarters of its limits and the hull rebuilt, so the cost stays
//! amortised O(1) per observation plus an O(log hull) edge search.
//!
//! # Robustness
//!
//! * Hull arithmetic is exact (`i128` cross products on integer nanoseconds).
//! * With few observations the spanning hull edge can have an implausible slope; a slope beyond
//!   `max_abs_skew_ppm` is clamped and the line lowered until it touches the hull, which is the
//!   best lower bound with that slope.
//! * A device timestamp earlier than the previous one means the device clock restarted (power
//!   cycle, counter reset): the model starts over and counts it in [`ClockModel::resets`]. An equal
//!   device timestamp keeps the earlier of the two receive times.

use std::collections::VecDeque;

/// Parameters of a [`ClockModel`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClockModelConfig {
    /// Span of device time kept in the window, ns. Longer windows average more delays; shorter ones
    /// follow skew changes faster. Default 30 s.
    pub window_ns: i64,
    /// Most observations kept in the window (bounds memory). Default 8192.
    pub max_observations: usize,
    /// Observations (since the last restart) required before [`ClockModel::device_to_host_ns`]
    /// answers. At least 1; default 2 (the skew needs two).
    pub min_observations: usize,
    /// Largest plausible clock skew, ppm; steeper hull edges are clamped. Default 1000 ppm (crystal
    /// oscillators are within ±100 ppm; this only guards the first few observations).
    pub max_abs_skew_ppm: f64,
}

impl Default for ClockModelConfig {
    fn default() -> Self {
        ClockModelConfig {
            window_ns: 30_000_000_000,
            max_observations: 8192,
            min_observations: 2,
            max_abs_skew_ppm: 1000.0,
        }
    }
}

/// The fitted line: `host = host_anchor_ns + (device - device_anchor_ns) * (1 + skew)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fit {
    device_anchor_ns: i64,
    host_anchor_ns: i64,
    skew: f64,
}

/// Device time → host monotonic time, offset + skew, fitted to the lower envelope of
/// (device timestamp, host receive time) observations. See the module docs for the estimator.
#[derive(Clone, Debug)]
pub struct ClockModel {
    config: ClockModelConfig,
    /// Observations in the window, device time strictly increasing: (device_ns, host_ns).
    window: VecDeque<(i64, i64)>,
    /// Lower convex hull of `window`, left to right.
    hull: Vec<(i64, i64)>,
    /// Σ (device_ns − device_ref_ns) over `window`, for the mean device time.
    device_sum_ns: i128,
    device_ref_ns: i64,
    observations: usize,
    resets: usize,
    fit: Option<Fit>,
}

impl ClockModel {
    /// An empty model. Out-of-range config values are corrected (`min_observations ≥ 1`,
    /// `max_observations ≥ 2`, `window_ns ≥ 1`, a non-finite or negative skew bound becomes the
    /// default).
    pub fn new(config: ClockModelConfig) -> Self {
        let mut config = config;
        config.min_observations = config.min_observations.max(1);
        config.max_observations = config.max_observations.max(2);
        config.window_ns = config.window_ns.max(1);
        if !(config.max_abs_skew_ppm.is_finite() && config.max_abs_skew_ppm >= 0.0) {
            config.max_abs_skew_ppm = ClockModelConfig::default().max_abs_skew_ppm;
        }
        ClockModel {
            config,
            window: VecDeque::new(),
            hull: Vec::new(),
            device_sum_ns: 0,
            device_ref_ns: 0,
            observations: 0,
            resets: 0,
            fit: None,
        }
    }

    /// The configuration in use (after the corrections of [`ClockModel::new`]).
    pub fn config(&self) -> &ClockModelConfig {
        &self.config
    }

    /// One observation: a device timestamp and the host monotonic time at which it was received
    /// (receive time = true time + non-negative transport delay).
    pub fn observe(&mut self, device_ns: i64, host_ns: i64) {
        if let Some(&(last_device_ns, last_host_ns)) = self.window.back() {
            if device_ns < last_device_ns {
                self.restart();
                self.resets += 1;
            } else if device_ns == last_device_ns {
                if host_ns < last_host_ns {
                    // Same device instant received earlier: the smaller delay is the better bound.
                    self.window.pop_back();
                    self.window.push_back((device_ns, host_ns));
                    self.rebuild_hull();
                    self.refit();
                }
                self.observations += 1;
                return;
            }
        }
        if self.window.is_empty() {
            self.device_ref_ns = device_ns;
        }
        self.window.push_back((device_ns, host_ns));
        self.device_sum_ns += (device_ns as i128) - (self.device_ref_ns as i128);
        self.observations += 1;

        let front_device_ns = self.window.front().map_or(device_ns, |p| p.0);
        let span_ns = (device_ns as i128) - (front_device_ns as i128);
        if span_ns > self.config.window_ns as i128
            || self.window.len() > self.config.max_observations
        {
            self.trim();
            self.rebuild_hull();
        } else {
            push_lower_hull(&mut self.hull, (device_ns, host_ns));
        }
        self.refit();
    }

    /// Host monotonic time of a device timestamp, once at least the configured minimum of
    /// observations has been seen since the last restart. Device times outside the window are
    /// extrapolated with the current skew.
    pub fn device_to_host_ns(&self, device_ns: i64) -> Option<i64> {
        if self.observations < self.config.min_observations {
            return None;
        }
        let fit = self.fit?;
        let dt_ns = (device_ns as i128) - (fit.device_anchor_ns as i128);
        let correction_ns = (dt_ns as f64 * fit.skew).round();
        let host = (fit.host_anchor_ns as i128) + dt_ns + (correction_ns as i128);
        Some(host.clamp(i64::MIN as i128, i64::MAX as i128) as i64)
    }

    /// Estimated skew of the host clock relative to the device clock, ppm: the host clock advances
    /// `1 + skew_ppm·1e-6` ns per device ns (positive when the device clock runs slow). `None`
    /// before two distinct device timestamps have been seen.
    pub fn skew_ppm(&self) -> Option<f64> {
        if self.hull.len() < 2 {
            return None;
        }
        self.fit.map(|f| f.skew * 1e6)
    }

    /// Observations seen since the last restart (including those already out of the window).
    pub fn observations(&self) -> usize {
        self.observations
    }

    /// Observations currently in the sliding window.
    pub fn window_len(&self) -> usize {
        self.window.len()
    }

    /// Times the model started over because the device clock went backwards.
    pub fn resets(&self) -> usize {
        self.resets
    }

    /// Forgets every observation (e.g. after reopening the device); keeps the reset counter.
    pub fn restart(&mut self) {
        self.window.clear();
        self.hull.clear();
        self.device_sum_ns = 0;
        self.observations = 0;
        self.fit = None;
    }

    /// Drops the oldest observations until the window is within 3/4 of its limits.
    fn trim(&mut self) {
        let Some(&(newest_device_ns, _)) = self.window.back() else {
            return;
        };
        let keep_span_ns = (self.config.window_ns as i128) * 3 / 4;
        let keep_len = (self.config.max_observations * 3 / 4).max(2);
        while let Some(&(d, _)) = self.window.front() {
            let too_old = (newest_device_ns as i128) - (d as i128) > keep_span_ns;
            if self.window.len() > 2 && (too_old || self.window.len() > keep_len) {
                self.window.pop_front();
                self.device_sum_ns -= (d as i128) - (self.device_ref_ns as i128);
            } else {
                break;
            }
        }
    }

    fn rebuild_hull(&mut self) {
        self.hull.clear();
        for &p in &self.window {
            push_lower_hull(&mut self.hull, p);
        }
    }

    fn refit(&mut self) {
        self.fit = match self.hull.as_slice() {
            [] => None,
            [(d, h)] => Some(Fit {
                device_anchor_ns: *d,
                host_anchor_ns: *h,
                skew: 0.0,
            }),
            hull => {
                let n = self.window.len() as i128;
                let mean_device_ns = (self.device_ref_ns as i128) + self.device_sum_ns / n;
                // First vertex strictly right of the mean; the spanning edge ends there.
                let right = hull
                    .partition_point(|&(d, _)| (d as i128) <= mean_device_ns)
                    .clamp(1, hull.len() - 1);
                let (d0, h0) = hull[right - 1];
                let (d1, h1) = hull[right];
                let dd = (d1 as i128 - d0 as i128) as f64;
                let skew = ((h1 as i128 - h0 as i128) - (d1 as i128 - d0 as i128)) as f64 / dd;
                let max_skew = self.config.max_abs_skew_ppm * 1e-6;
                if skew.abs() <= max_skew {
                    Some(Fit {
                        device_anchor_ns: d0,
                        host_anchor_ns: h0,
                        skew,
                    })
                } else {
                    Some(lowest_line_with_skew(hull, skew.clamp(-max_skew, max_skew)))
                }
            }
        };
    }
}

/// The highest line of the given skew below every hull vertex: it touches the vertex minimising
/// `h − d·(1 + skew)`.
fn lowest_line_with_skew(hull: &[(i64, i64)], skew: f64) -> Fit {
    let (d_ref, h_ref) = hull[0];
    let height = |&(d, h): &(i64, i64)| {
        let dd = (d as i128 - d_ref as i128) as f64;
        (h as i128 - h_ref as i128) as f64 - dd * (1.0 + skew)
    };
    let mut best = hull[0];
    for p in hull {
        if height(p) < height(&best) {
            best = *p;
        }
    }
    Fit {
        device_anchor_ns: best.0,
        host_anchor_ns: best.1,
        skew,
    }
}

/// Monotone-chain step: appends `p` (device time greater than every vertex) to a lower hull.
fn push_lower_hull(hull: &mut Vec<(i64, i64)>, p: (i64, i64)) {
    while hull.len() >= 2 {
        let a = hull[hull.len() - 2];
        let b = hull[hull.len() - 1];
        if cross(a, b, p) <= 0 {
            hull.pop();
        } else {
            break;
        }
    }
    hull.push(p);
}

/// z of (b − a) × (c − a), exact.
fn cross(a: (i64, i64), b: (i64, i64), c: (i64, i64)) -> i128 {
    let (abx, aby) = (b.0 as i128 - a.0 as i128, b.1 as i128 - a.1 as i128);
    let (acx, acy) = (c.0 as i128 - a.0 as i128, c.1 as i128 - a.1 as i128);
    abx * acy - aby * acx
}

#[cfg(test)]
mod tests {
    use super::*;

    /// splitmix64: a tiny deterministic generator so the tests need no dependency.
    struct Rng(u64);
    impl Rng {
        fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        /// Uniform in (0, 1].
        fn uniform(&mut self) -> f64 {
            ((self.next_u64() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
        }
        fn exponential(&mut self, mean: f64) -> f64 {
            -mean * self.uniform().ln()
        }
    }

    /// Simulated link: the device clock runs `drift_ppm` fast with an arbitrary offset; a sample
    /// stamped on the device at true host time `t` is received at `t + Exp(mean_delay)`.
    struct Link {
        drift_ppm: f64,
        device_offset_ns: i64,
        host_start_ns: i64,
    }
    impl Link {
        fn device_ns(&self, host_true_ns: i64) -> i64 {
            let dt = (host_true_ns - self.host_start_ns) as f64;
            self.device_offset_ns + (dt * (1.0 + self.drift_ppm * 1e-6)).round() as i64
        }
        fn host_true_ns(&self, device_ns: i64) -> f64 {
            self.host_start_ns as f64
                + (device_ns - self.device_offset_ns) as f64 / (1.0 + self.drift_ppm * 1e-6)
        }
    }

    /// Runs `duration_s` of observations at `rate_hz`; returns the model and the worst absolute
    /// error (ns) of the mapping over device times of the last second, plus the same for a
    /// least-squares fit of the same data (what a naive estimator gets).
    fn simulate(
        rate_hz: f64,
        duration_s: f64,
        mean_delay_s: f64,
        seed: u64,
    ) -> (ClockModel, f64, f64) {
        let link = Link {
            drift_ppm: 50.0,
            device_offset_ns: 7_123_456_789_012,
            host_start_ns: 1_000_000_000_000,
        };
        let mut rng = Rng(seed);
        let mut model = ClockModel::new(ClockModelConfig::default());
        let n = (duration_s * rate_hz) as usize;
        let mut pairs = Vec::with_capacity(n);
        for i in 0..n {
            let t_true_ns = link.host_start_ns + (i as f64 * 1e9 / rate_hz) as i64;
            let d = link.device_ns(t_true_ns);
            let h = t_true_ns + (rng.exponential(mean_delay_s) * 1e9).round() as i64;
            model.observe(d, h);
            pairs.push((d, h));
        }
        // Least squares over the same observations, for contrast.
        let (d0, h0) = pairs[0];
        let xs: Vec<f64> = pairs.iter().map(|p| (p.0 - d0) as f64).collect();
        let ys: Vec<f64> = pairs.iter().map(|p| (p.1 - h0) as f64).collect();
        let mx = xs.iter().sum::<f64>() / n as f64;
        let my = ys.iter().sum::<f64>() / n as f64;
        let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
        let b = sxy / sxx;

        let last_device_ns = pairs[n - 1].0;
        let mut worst_ns: f64 = 0.0;
        let mut worst_ls_ns: f64 = 0.0;
        for k in 0..=100 {
            let d = last_device_ns - k * 10_000_000;
            let truth = link.host_true_ns(d);
            let est = model.device_to_host_ns(d).expect("model ready") as f64;
            worst_ns = worst_ns.max((est - truth).abs());
            let ls = h0 as f64 + my + b * ((d - d0) as f64 - mx);
            worst_ls_ns = worst_ls_ns.max((ls - truth).abs());
        }
        (model, worst_ns, worst_ls_ns)
    }

    #[test]
    fn exponential_jitter_50ppm_offset_error_below_100us_after_10s() {
        for seed in [1, 2, 3, 4, 5] {
            let (model, err_ns, ls_err_ns) = simulate(100.0, 10.0, 2e-3, seed);
            assert!(
                err_ns < 100_000.0,
                "seed {seed}: lower-envelope error {err_ns} ns"
            );
            // The same data through least squares is off by about the mean delay (2 ms): the
            // test data does exercise the difference.
            assert!(
                ls_err_ns > 1_000_000.0,
                "seed {seed}: least-squares error {ls_err_ns} ns"
            );
            // Host advances 1/(1+50e-6) per device ns: skew ≈ −50 ppm.
            let skew = model.skew_ppm().unwrap();
            eprintln!("seed {seed}: err {err_ns} ns, ls {ls_err_ns} ns, skew {skew} ppm");
            assert!((skew + 50.0).abs() < 10.0, "seed {seed}: skew {skew} ppm");
        }
    }

    #[test]
    fn heavy_jitter_at_imu_rate_over_a_trimmed_window() {
        // 1 kHz for 40 s: the window (30 s, 8192 obs) is trimmed many times; mean delay 10 ms.
        let (model, err_ns, _) = simulate(1000.0, 40.0, 10e-3, 9);
        assert!(err_ns < 100_000.0, "error {err_ns} ns");
        assert!(model.window_len() <= 8192);
        assert_eq!(model.observations(), 40_000);
    }

    #[test]
    fn needs_min_observations_then_exact_on_delay_free_data() {
        let mut m = ClockModel::new(ClockModelConfig {
            min_observations: 3,
            ..Default::default()
        });
        assert_eq!(m.device_to_host_ns(0), None);
        m.observe(1_000, 501_000);
        m.observe(2_000, 502_000);
        assert_eq!(m.device_to_host_ns(0), None);
        m.observe(3_000, 503_000);
        assert_eq!(m.device_to_host_ns(10_000), Some(510_000));
        assert_eq!(m.skew_ppm(), Some(0.0));
    }

    #[test]
    fn device_clock_going_back_restarts_the_model() {
        let mut m = ClockModel::new(ClockModelConfig::default());
        for i in 0..10 {
            m.observe(1_000_000 + i * 1_000, 5_000_000 + i * 1_000);
        }
        m.observe(10, 9_000_000);
        assert_eq!(m.resets(), 1);
        assert_eq!(m.observations(), 1);
        assert_eq!(m.device_to_host_ns(10), None);
        m.observe(1_010, 9_001_000);
        assert_eq!(m.device_to_host_ns(2_010), Some(9_002_000));
    }

    #[test]
    fn repeated_device_time_keeps_the_earliest_receipt() {
        let mut m = ClockModel::new(ClockModelConfig::default());
        m.observe(0, 1_000);
        m.observe(1_000, 2_500);
        m.observe(1_000, 2_000);
        m.observe(1_000, 2_700);
        assert_eq!(m.device_to_host_ns(2_000), Some(3_000));
    }

    #[test]
    fn implausible_skew_from_two_points_is_clamped() {
        let mut m = ClockModel::new(ClockModelConfig::default());
        m.observe(0, 0);
        m.observe(1_000_000, 1_500_000); // 50 % apparent skew: a delayed second sample
        let skew = m.skew_ppm().unwrap();
        assert!((skew - 1000.0).abs() < 1e-9, "{skew}");
        // The line stays below both observations.
        assert!(m.device_to_host_ns(0).unwrap() <= 0);
        assert!(m.device_to_host_ns(1_000_000).unwrap() <= 1_500_000);
    }
}
