//! Scheduling priority of the odometry's threads.
//!
//! The tracking thread must finish every frame within its budget; the mapper and the refinement
//! may take as long as they need, at the price of latency. On two cores the three compete, and
//! under the default scheduler the tracker's p99 grows by the time slices the others take. A
//! background thread therefore lowers its own priority (raises its nice value) when it starts:
//! the kernel then gives the tracker the core more often whenever it is runnable. Raising one's
//! own nice value needs no privilege. But a nice value only weighs the share: the refinement's
//! pool at nice 2 still held the tracking thread off its core for 1.5–3.3 ms of its slowest
//! frames (`frame_tail.cpu_ms` against `total_ms`). In real time the tracking thread therefore
//! also takes a fixed real-time priority ([`RealtimeGuard::fifo`], `SCHED_FIFO`) where the process
//! may (root, `CAP_SYS_NICE` or an `RLIMIT_RTPRIO`, as a systemd unit's
//! `AmbientCapabilities=CAP_SYS_NICE` or `LimitRTPRIO=` grants): it then runs whenever it is
//! runnable, ahead of every ordinary thread. Threads it starts do not inherit it
//! (`SCHED_RESET_ON_FORK`). Linux only (elsewhere a no-op); the result never depends on it, only
//! the timing.

/// Raises the calling thread's nice value by `increment` (0: nothing done). Returns whether the
/// priority was changed.
pub fn lower_current_thread(increment: i32) -> bool {
    if increment <= 0 {
        return false;
    }
    lower(increment)
}

/// Lowers the calling (background) thread's priority by `increment` and runs `f` on it; with
/// `with_pool`, inside a `lowered_pool` named `name`, so that `f`'s data-parallel work is as low
/// in priority as the thread (should the pool fail to start, `f` runs on rayon's global pool; a
/// result never depends on the pool, only the timing).
pub fn run_lowered<R: Send>(
    name: &'static str,
    increment: i32,
    with_pool: bool,
    f: impl FnOnce() -> R + Send,
) -> R {
    // The pool first: a new thread inherits its creator's nice value, and each pool thread
    // raises its own by `increment` — built after this thread is lowered, it would be lowered twice.
    let pool = with_pool.then(|| lowered_pool(name, increment)).flatten();
    lower_current_thread(increment);
    match pool {
        Some(pool) => pool.install(f),
        None => f(),
    }
}

/// A rayon pool (rayon's default thread count) whose threads are named `{name}-{i}` and raise
/// their nice value by `increment` when they start: the data-parallel work of a background thread,
/// kept as low in priority as the thread itself (rayon's global pool would run at the tracker's).
/// `None` if the pool cannot start (the caller then runs on rayon's global pool). The threads
/// inherit the creating thread's nice value first: create it from a thread not yet lowered.
fn lowered_pool(name: &'static str, increment: i32) -> Option<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .thread_name(move |i| format!("{name}-{i}"))
        .start_handler(move |_| {
            lower_current_thread(increment);
        })
        .build()
        .ok()
}

/// The calling thread at a real-time priority (`SCHED_FIFO`) until dropped, when its previous
/// policy and priority are restored.
pub struct RealtimeGuard {
    #[cfg(target_os = "linux")]
    previous: (libc::c_int, libc::sched_param),
}

impl RealtimeGuard {
    /// Puts the calling thread under `SCHED_FIFO` at `priority` (1–99), with threads it starts
    /// from now on under the default policy (`SCHED_RESET_ON_FORK`). The error (no privilege:
    /// `EPERM`; a priority out of range: `EINVAL`; not Linux) leaves the thread as it was.
    pub fn fifo(priority: i32) -> std::io::Result<Self> {
        fifo(priority)
    }
}

#[cfg(target_os = "linux")]
fn fifo(priority: i32) -> std::io::Result<RealtimeGuard> {
    // SAFETY: sched_getscheduler/sched_getparam/sched_setscheduler with pid 0 address the calling
    // thread and read or write only the `sched_param` passed, which lives on this stack.
    unsafe {
        let policy = libc::sched_getscheduler(0);
        let mut param: libc::sched_param = std::mem::zeroed();
        if policy == -1 || libc::sched_getparam(0, &mut param) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        let fifo = libc::sched_param {
            sched_priority: priority,
        };
        if libc::sched_setscheduler(0, libc::SCHED_FIFO | libc::SCHED_RESET_ON_FORK, &fifo) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(RealtimeGuard {
            previous: (policy, param),
        })
    }
}

#[cfg(not(target_os = "linux"))]
fn fifo(_priority: i32) -> std::io::Result<RealtimeGuard> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

impl Drop for RealtimeGuard {
    fn drop(&mut self) {
        #[cfg(target_os = "linux")]
        // SAFETY: as in `fifo`; the policy and parameters are the thread's own from before.
        unsafe {
            let (policy, param) = self.previous;
            libc::sched_setscheduler(0, policy, &param);
        }
    }
}

#[cfg(target_os = "linux")]
fn lower(increment: i32) -> bool {
    // SAFETY: gettid and getpriority/setpriority take plain integers and touch no memory of ours.
    // On Linux, PRIO_PROCESS with a thread id addresses that thread alone.
    unsafe {
        let tid = libc::gettid() as libc::id_t;
        *libc::__errno_location() = 0;
        let now = libc::getpriority(libc::PRIO_PROCESS, tid);
        if now == -1 && *libc::__errno_location() != 0 {
            return false;
        }
        let target = (now + increment).min(19);
        libc::setpriority(libc::PRIO_PROCESS, tid, target) == 0
    }
}

#[cfg(not(target_os = "linux"))]
fn lower(_increment: i32) -> bool {
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    fn own_nice() -> i32 {
        // SAFETY: as in `lower`.
        unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) }
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_background_thread_lowers_only_its_own_priority() {
        let before = own_nice();
        let inside = std::thread::spawn(|| {
            let before = own_nice();
            assert!(lower_current_thread(5));
            (before, own_nice())
        })
        .join()
        .unwrap();
        assert_eq!(inside.1, (inside.0 + 5).min(19), "{inside:?}");
        assert_eq!(own_nice(), before, "the spawning thread keeps its priority");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_lowered_pool_runs_every_task_at_the_lowered_priority() {
        let before = own_nice();
        let pool = lowered_pool("vidslam-test", 4).expect("pool");
        let nices: Vec<i32> = pool.install(|| {
            use rayon::prelude::*;
            (0..64)
                .into_par_iter()
                .map(|_| {
                    if rayon::current_thread_index().is_some() {
                        own_nice()
                    } else {
                        i32::MIN
                    }
                })
                .collect()
        });
        assert!(
            nices.iter().all(|&n| n == (before + 4).min(19)),
            "{nices:?}"
        );
        assert_eq!(own_nice(), before, "the calling thread keeps its priority");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn run_lowered_runs_on_the_lowered_thread_inside_its_pool_only_if_asked() {
        for with_pool in [false, true] {
            let (outer, inner) = std::thread::spawn(move || {
                let outer = own_nice();
                let inner = run_lowered("vidslam-test", 3, with_pool, || {
                    (rayon::current_thread_index().is_some(), own_nice())
                });
                (outer, inner)
            })
            .join()
            .unwrap();
            assert_eq!(inner, (with_pool, (outer + 3).min(19)), "pool {with_pool}");
        }
    }

    /// Where the process may (root here), the thread runs under `SCHED_FIFO` while the guard
    /// lives, a thread it starts meanwhile does not, and its policy is restored after; where it
    /// may not, the error leaves it as it was. A priority out of range is refused either way.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_realtime_guard_holds_the_thread_at_fifo_and_restores_it() {
        std::thread::spawn(|| {
            // SAFETY: sched_getscheduler(0) reads the calling thread's policy.
            let policy = || unsafe { libc::sched_getscheduler(0) } & !libc::SCHED_RESET_ON_FORK;
            let before = policy();
            assert_eq!(before, libc::SCHED_OTHER);
            assert!(RealtimeGuard::fifo(100).is_err(), "out of range");
            assert_eq!(policy(), before);
            match RealtimeGuard::fifo(10) {
                Ok(guard) => {
                    assert_eq!(policy(), libc::SCHED_FIFO);
                    let child = std::thread::spawn(policy).join().unwrap();
                    assert_eq!(
                        child,
                        libc::SCHED_OTHER,
                        "started threads do not inherit it"
                    );
                    drop(guard);
                    assert_eq!(policy(), before);
                }
                Err(e) => {
                    assert_eq!(e.raw_os_error(), Some(libc::EPERM), "{e}");
                    assert_eq!(policy(), before);
                }
            }
        })
        .join()
        .unwrap();
    }

    #[test]
    fn zero_changes_nothing() {
        assert!(!lower_current_thread(0));
        assert!(!lower_current_thread(-3));
    }
}
