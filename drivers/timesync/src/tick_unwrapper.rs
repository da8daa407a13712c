//! Unwrapping of a free-running `u32` hardware tick counter into monotonic nanoseconds.

/// Extends a wrapping `u32` tick counter (e.g. the 3DM-GX4 internal timestamp, a camera's frame
/// clock) to an `i64` count that keeps increasing across wraparound, and converts it to
/// nanoseconds.
///
/// Consecutive readings are assumed less than half the counter range (2^31 ticks) apart, so the
/// signed 32-bit difference between them is the true elapsed tick count: a reading just past the
/// wrap is a small step forward, and a slightly older reading (reordering) a small step back.
#[derive(Clone, Debug)]
pub struct TickUnwrapper {
    tick_hz: u64,
    last_raw: Option<u32>,
    ticks: i64,
    wraps: u64,
}

impl TickUnwrapper {
    /// A new unwrapper for a counter running at `tick_hz` ticks per second (at least 1). The
    /// first reading maps to its own raw value (no wrap counted yet).
    pub fn new(tick_hz: u64) -> Self {
        TickUnwrapper {
            tick_hz: tick_hz.max(1),
            last_raw: None,
            ticks: 0,
            wraps: 0,
        }
    }

    /// The unwrapped tick count of a raw reading.
    pub fn unwrap_ticks(&mut self, raw: u32) -> i64 {
        match self.last_raw {
            None => self.ticks = raw as i64,
            Some(last) => {
                let step = raw.wrapping_sub(last) as i32 as i64;
                if (step > 0 && raw < last) || (step < 0 && raw > last) {
                    // Crossed 0 forwards (or back across it).
                    self.wraps = self.wraps.wrapping_add(1);
                }
                self.ticks = self.ticks.saturating_add(step);
            }
        }
        self.last_raw = Some(raw);
        self.ticks
    }

    /// The unwrapped time of a raw reading, ns (`ticks · 1e9 / tick_hz`, rounded down, exact in
    /// `i128`).
    pub fn unwrap_ns(&mut self, raw: u32) -> i64 {
        let ticks = self.unwrap_ticks(raw);
        self.ticks_to_ns(ticks)
    }

    /// Nanoseconds of an unwrapped tick count.
    pub fn ticks_to_ns(&self, ticks: i64) -> i64 {
        let ns = (ticks as i128) * 1_000_000_000 / (self.tick_hz as i128);
        ns.clamp(i64::MIN as i128, i64::MAX as i128) as i64
    }

    /// Counter frequency, ticks per second.
    pub fn tick_hz(&self) -> u64 {
        self.tick_hz
    }

    /// Times the raw counter crossed zero.
    pub fn wraps(&self) -> u64 {
        self.wraps
    }

    /// Forgets the previous reading (after a device restart the counter starts again).
    pub fn reset(&mut self) {
        self.last_raw = None;
        self.ticks = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_across_wraparound() {
        let mut u = TickUnwrapper::new(1000);
        let start = u32::MAX - 2500;
        let mut prev = u.unwrap_ticks(start);
        assert_eq!(prev, start as i64);
        let mut raw = start;
        for _ in 0..5000 {
            raw = raw.wrapping_add(1);
            let t = u.unwrap_ticks(raw);
            assert_eq!(t, prev + 1);
            prev = t;
        }
        assert_eq!(prev, start as i64 + 5000);
        assert_eq!(u.wraps(), 1);
        assert_eq!(
            u.unwrap_ns(raw.wrapping_add(1000)),
            (start as i64 + 6000) * 1_000_000
        );
    }

    #[test]
    fn many_wraps_with_large_steps() {
        // Steps of 2^30 ticks: four readings per wrap; after 40 steps, 10 wraps.
        let mut u = TickUnwrapper::new(62_500);
        u.unwrap_ticks(0);
        let mut raw = 0u32;
        let mut last = 0;
        for _ in 0..40 {
            raw = raw.wrapping_add(1 << 30);
            last = u.unwrap_ticks(raw);
        }
        assert_eq!(last, 40 * (1i64 << 30));
        assert_eq!(u.wraps(), 10);
        assert_eq!(u.ticks_to_ns(62_500), 1_000_000_000);
        assert_eq!(u.ticks_to_ns(1), 16_000);
    }

    #[test]
    fn small_step_back_is_not_a_wrap() {
        let mut u = TickUnwrapper::new(1_000_000);
        assert_eq!(u.unwrap_ticks(100), 100);
        assert_eq!(u.unwrap_ticks(90), 90);
        assert_eq!(u.unwrap_ticks(5), 5);
        assert_eq!(u.unwrap_ticks(u32::MAX), -1);
        assert_eq!(u.unwrap_ticks(3), 3);
        assert_eq!(u.wraps(), 2);
        u.reset();
        assert_eq!(u.unwrap_ticks(7), 7);
    }
}
