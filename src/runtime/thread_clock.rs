//! The calling thread's CPU time: set against a span's wall time it tells work from waiting for
//! a core (a frame that took 12 ms of wall time on 4 ms of CPU was preempted, not slow).

/// CPU time the calling thread has used since it started, s (`CLOCK_THREAD_CPUTIME_ID`); `None`
/// where the platform has no such clock.
pub fn thread_cpu_time_s() -> Option<f64> {
    cpu_time_s()
}

#[cfg(target_os = "linux")]
fn cpu_time_s() -> Option<f64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec, which `ts` is, and nothing else.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (rc == 0).then_some(ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9)
}

#[cfg(not(target_os = "linux"))]
fn cpu_time_s() -> Option<f64> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn a_busy_thread_uses_cpu_time_and_a_sleeping_one_does_not() {
        let t0 = thread_cpu_time_s().unwrap();
        // Busy until it has used 5 ms of CPU (however long that takes the loaded machine, within
        // a bound the clock not advancing would hit).
        let started = std::time::Instant::now();
        let mut x = 0u64;
        let mut t1 = t0;
        while t1 - t0 < 0.005 && started.elapsed().as_secs_f64() < 10.0 {
            for _ in 0..10_000 {
                x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
            }
            t1 = thread_cpu_time_s().unwrap();
        }
        assert!(t1 - t0 >= 0.005, "busy 10 s: {} s of CPU", t1 - t0);
        std::thread::sleep(std::time::Duration::from_millis(50));
        let t2 = thread_cpu_time_s().unwrap();
        assert!(t2 - t1 < 0.025, "asleep 50 ms: {} s of CPU", t2 - t1);
        assert!(t2 >= t1 && t1 >= t0);
    }
}
