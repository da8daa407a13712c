//! The host clock every driver stamps with: `CLOCK_MONOTONIC`, nanoseconds (the clock V4L2
//! buffers and the IMU driver use too).

/// Host `CLOCK_MONOTONIC` now, nanoseconds.
pub fn monotonic_now_ns() -> i64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

/// Host `CLOCK_REALTIME` now, nanoseconds since the Unix epoch.
pub fn realtime_now_ns() -> i64 {
    clock_ns(libc::CLOCK_REALTIME)
}

/// Converts a recent `CLOCK_REALTIME` stamp (Aravis stamps buffer arrival with
/// `g_get_real_time`) to `CLOCK_MONOTONIC`, using the offset between the two clocks now. The
/// result is clamped to "now": a realtime step (NTP) between stamping and conversion can then
/// only make the stamp late, never in the future.
pub fn realtime_to_monotonic_ns(realtime_ns: i64) -> i64 {
    let mono_before = monotonic_now_ns();
    let real = realtime_now_ns();
    let mono_after = monotonic_now_ns();
    let mono_now = mono_before + (mono_after - mono_before) / 2;
    (realtime_ns - (real - mono_now)).min(mono_after)
}

// `time_t`/`c_long` are i32 on 32-bit ARM companion computers: keep the widening.
#[allow(clippy::useless_conversion)]
fn clock_ns(clock: libc::clockid_t) -> i64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; both clocks exist on every Linux kernel.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime({clock}) failed");
    i64::from(ts.tv_sec) * 1_000_000_000 + i64::from(ts.tv_nsec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realtime_stamp_maps_onto_the_monotonic_clock() {
        let mono0 = monotonic_now_ns();
        let real = realtime_now_ns();
        let mono1 = monotonic_now_ns();
        let mapped = realtime_to_monotonic_ns(real);
        // The mapped stamp lies between the monotonic reads around the realtime read, up to the
        // time the conversion itself took (bounded by a second read of the monotonic clock).
        let slack = monotonic_now_ns() - mono0;
        assert!(
            mapped >= mono0 - slack && mapped <= mono1 + slack,
            "{mono0} {mapped} {mono1}"
        );
        // A stamp from the future is clamped to now.
        assert!(realtime_to_monotonic_ns(real + 10_000_000_000) <= monotonic_now_ns());
    }
}
