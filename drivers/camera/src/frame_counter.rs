//! Device frame counters: unwrapping to 64 bits and counting the frames lost in gaps.

/// Unwraps a wrapping device frame counter and reports how many frames were skipped.
///
/// GigE Vision 1.x block ids are 16 bits and skip 0 on wrap (65535 → 1); V4L2 sequence numbers
/// are 32 bits; GEV 2 extended ids and Aravis's in-process fake are 64 bits.
#[derive(Clone, Debug)]
pub struct FrameCounter {
    bits: u32,
    zero_is_invalid: bool,
    last_raw: Option<u64>,
    unwrapped: u64,
}

impl FrameCounter {
    /// `bits`: counter width (1..=64); `zero_is_invalid`: the counter skips 0 when it wraps.
    pub fn new(bits: u32, zero_is_invalid: bool) -> Self {
        assert!((1..=64).contains(&bits));
        FrameCounter {
            bits,
            zero_is_invalid,
            last_raw: None,
            unwrapped: 0,
        }
    }

    /// Forgets the previous id (after a restart the device counter may start over).
    pub fn reset(&mut self) {
        self.last_raw = None;
    }

    /// Feeds the next raw id; returns `(unwrapped_id, frames_missing_before)`. A repeated or
    /// backwards id (device restart) is treated as a new start with no known gap.
    pub fn next(&mut self, raw: u64) -> (u64, u64) {
        let mask = if self.bits == 64 {
            u64::MAX
        } else {
            (1u64 << self.bits) - 1
        };
        let raw = raw & mask;
        let Some(last) = self.last_raw else {
            self.last_raw = Some(raw);
            self.unwrapped = raw;
            return (raw, 0);
        };
        let mut step = raw.wrapping_sub(last) & mask;
        if self.zero_is_invalid && raw < last && step > 0 {
            step -= 1; // the wrap skipped id 0
        }
        // More than half the counter range forward is really a backwards jump (restart).
        if step == 0 || step > mask / 2 {
            self.last_raw = Some(raw);
            self.unwrapped += 1;
            return (self.unwrapped, 0);
        }
        self.last_raw = Some(raw);
        self.unwrapped += step;
        (self.unwrapped, step - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contiguous_ids_report_no_gap() {
        let mut c = FrameCounter::new(32, false);
        assert_eq!(c.next(10), (10, 0));
        assert_eq!(c.next(11), (11, 0));
        assert_eq!(c.next(14), (14, 2));
    }

    #[test]
    fn gev_16_bit_block_ids_wrap_over_zero() {
        let mut c = FrameCounter::new(16, true);
        assert_eq!(c.next(65534), (65534, 0));
        assert_eq!(c.next(65535), (65535, 0));
        assert_eq!(
            c.next(1),
            (65536, 0),
            "65535 -> 1 is contiguous when 0 is skipped"
        );
        assert_eq!(c.next(3), (65538, 1));
    }

    #[test]
    fn v4l2_32_bit_sequence_wraps() {
        let mut c = FrameCounter::new(32, false);
        c.next(u32::MAX as u64);
        assert_eq!(c.next(0), (u32::MAX as u64 + 1, 0));
        assert_eq!(c.next(2), (u32::MAX as u64 + 3, 1));
    }

    #[test]
    fn a_backwards_jump_is_a_restart_not_a_huge_gap() {
        let mut c = FrameCounter::new(16, true);
        c.next(500);
        assert_eq!(c.next(1), (501, 0));
        assert_eq!(c.next(2), (502, 0));
    }
}
