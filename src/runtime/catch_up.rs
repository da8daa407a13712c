//! The frames tracked while a keyframe adjustment was under way, tracked again against the
//! adjusted keyframe on the refinement thread (`[keyframe_bundle] catch_up_on_refinement_thread`).
//!
//! An adjustment comes back several frames after it was sent (in real time on S-V101 with
//! `previous_host` 9–11 frames p50, up to 19). The frames of the wait were tracked against the
//! keyframe before, whose map the adjustment may have rescaled: moved rigidly by the last view's
//! correction ([`super::keyframe_bundle::carry_correction`]) their positions, velocities and the
//! next keyframe's chain keep the old map's scale, and offline at `lag_frames = 10 / 13` S-V101
//! seed 1 runs away (210 m / 1.2 km; tracking only the newest again, 8 m / 280 m), while tracking
//! all of them again holds (0.14 / 0.12 m; docs/odometry-log.md, *The frames of a late adjustment's
//! wait tracked again on the refinement thread*). On the tracking thread that is ~4 ms a frame,
//! 30–35 ms in the frame the result comes back. Here the refinement thread does it after the
//! adjustment, from the last view's adjusted state, with the frames and their IMU handed over as
//! they are tracked; the tracking thread then tracks again only those that arrived after the last
//! one done here.
//!
//! The IMU of each frame is preintegrated from the frame before (eq. 1–6, the gyro turned as the
//! keyframe window read it when the frame was tracked) and the frame tracked photometrically
//! jointly with it (eq. 16–22), exactly as on the tracking thread.

use crate::image::Image;
use crate::imu::misalignment::preintegrate_turned;
use crate::imu::{FrameState, ImuNoise, ImuSample, Matrix15};
use crate::time::TimeNs;
use crate::tracking::{Keyframe, Tracker};
use crossbeam_channel::{Receiver, RecvTimeoutError};
use nalgebra::{Isometry3, Vector3};
use std::sync::Arc;
use std::time::Duration;

/// What the tracking thread hands over while an adjustment is under way.
pub enum CatchUpMessage {
    /// A frame tracked against the keyframe before, for the adjustment `seq`.
    Frame(Box<CatchUpFrame>),
    /// No more frames for the adjustment `seq` (offline: the tracking thread now waits for it).
    End(u64),
}

/// A frame of the wait with what tracking it needs.
pub struct CatchUpFrame {
    /// The adjustment it belongs to.
    pub seq: u64,
    pub t: TimeNs,
    pub image: Arc<Image<u8>>,
    /// IMU samples bracketing the interval from the frame before (or the last view) to `t`.
    pub imu: Vec<ImuSample>,
    /// The gyro's turn against the body frame the frame was tracked with, rad.
    pub gyro_turn_rad: Vector3<f64>,
}

/// One frame tracked again against the adjusted keyframe.
#[derive(Clone, Copy, Debug)]
pub struct CaughtUpFrame {
    pub t: TimeNs,
    pub state: FrameState,
    pub t_world_cam: Isometry3<f64>,
}

/// The frames of the wait tracked again, oldest first, with the tracker's covariance and
/// brightness after the newest.
#[derive(Clone, Debug, Default)]
pub struct CaughtUp {
    pub frames: Vec<CaughtUpFrame>,
    pub covariance: Matrix15,
    pub brightness: (f64, f64),
}

/// How the catch-up is started: from the adjustment's last view, with the tracking thread's
/// covariance and brightness when the adjustment was sent.
#[derive(Clone, Copy, Debug)]
pub struct CatchUpStart {
    pub covariance: Matrix15,
    pub brightness: (f64, f64),
    /// Offline: wait for [`CatchUpMessage::End`] (the frames of the lag, deterministically). Real
    /// time: take the frames there are and return.
    pub wait_for_end: bool,
}

/// How long the thread waits for the tracking thread's next frame offline before it gives up
/// (the tracking thread stopped: a replay that ends while an adjustment is out).
const OFFLINE_WAIT: Duration = Duration::from_secs(30);

/// Tracks the frames of adjustment `seq` handed over on `rx` with `tracker` (the refinement
/// thread's own, made once) against `keyframe` from `last_view` (the adjusted state of the
/// newest frame the adjustment saw), stopping at the first frame that is not tracked (flagged,
/// or not finite). Frames of other adjustments are dropped. `noise`: the odometry's
/// preintegration noise when the adjustment was sent.
pub fn catch_up(
    tracker: &mut Tracker,
    (rx, seq): (&Receiver<CatchUpMessage>, u64),
    (keyframe, last_view): (&Keyframe, &FrameState),
    start: &CatchUpStart,
    noise: &ImuNoise,
) -> CaughtUp {
    tracker.set_keyframe(keyframe.clone());
    tracker.reset_state(*last_view, start.covariance);
    tracker.set_brightness(start.brightness);
    let mut out = CaughtUp {
        frames: Vec::new(),
        covariance: start.covariance,
        brightness: start.brightness,
    };
    let mut last_t = last_view.nav.t;
    let mut failed = false;
    while let Some(f) = next_frame(rx, seq, start.wait_for_end) {
        // (Offline the frames after a failure are still read, up to the end marker.)
        if failed || f.t <= last_t {
            continue;
        }
        let bias = tracker.state().bias;
        let pre = preintegrate_turned(&f.imu, (last_t, f.t), bias, noise, &f.gyro_turn_rad);
        let r = tracker.track(f.t, &f.image, &pre);
        if r.flag.is_some() || !r.state.is_finite() {
            failed = true;
            continue;
        }
        last_t = f.t;
        out.frames.push(CaughtUpFrame {
            t: f.t,
            state: r.state,
            t_world_cam: tracker.t_world_cam(),
        });
        out.covariance = *tracker.covariance();
        out.brightness = tracker.brightness();
    }
    out
}

/// Reads the frames of adjustment `seq` without tracking them (the adjustment failed).
pub fn skip_frames(rx: &Receiver<CatchUpMessage>, seq: u64, start: &CatchUpStart) {
    while next_frame(rx, seq, start.wait_for_end).is_some() {}
}

/// The next frame of adjustment `seq` (those of others dropped); `None` at its end marker
/// (`wait`: offline), when none is queued (real time), or when the odometry is gone.
fn next_frame(rx: &Receiver<CatchUpMessage>, seq: u64, wait: bool) -> Option<Box<CatchUpFrame>> {
    loop {
        let msg = if wait {
            match rx.recv_timeout(OFFLINE_WAIT) {
                Ok(m) => m,
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return None,
            }
        } else {
            rx.try_recv().ok()?
        };
        match msg {
            CatchUpMessage::End(s) if s == seq => return None,
            CatchUpMessage::Frame(f) if f.seq == seq => return Some(f),
            _ => {} // another adjustment's
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crossbeam_channel::bounded;

    fn frame(seq: u64, t_ns: i64) -> CatchUpMessage {
        CatchUpMessage::Frame(Box::new(CatchUpFrame {
            seq,
            t: TimeNs(t_ns),
            image: Arc::new(Image::from_fn(4, 4, |_, _| 0u8)),
            imu: Vec::new(),
            gyro_turn_rad: Vector3::zeros(),
        }))
    }

    fn times(rx: &Receiver<CatchUpMessage>, seq: u64, wait: bool) -> Vec<i64> {
        std::iter::from_fn(|| next_frame(rx, seq, wait))
            .map(|f| f.t.0)
            .collect()
    }

    #[test]
    fn an_adjustment_takes_its_own_frames_up_to_its_end_marker() {
        let (tx, rx) = bounded(16);
        // A superseded adjustment's frames and end marker are still queued before this one's.
        for m in [
            frame(1, 10),
            CatchUpMessage::End(1),
            frame(2, 20),
            frame(1, 25),
            frame(2, 30),
            CatchUpMessage::End(2),
            frame(3, 40),
        ] {
            tx.send(m).unwrap();
        }
        // Offline: up to its end marker, the next adjustment's frame left queued.
        assert_eq!(times(&rx, 2, true), vec![20, 30]);
        assert_eq!(times(&rx, 3, false), vec![40]);
        // Real time: what is queued, then done.
        tx.send(frame(4, 50)).unwrap();
        assert_eq!(times(&rx, 4, false), vec![50]);
        assert!(times(&rx, 4, false).is_empty());
        // Offline with the odometry gone: done at once, not after the wait.
        tx.send(frame(5, 60)).unwrap();
        drop(tx);
        let started = std::time::Instant::now();
        assert_eq!(times(&rx, 5, true), vec![60]);
        assert!(started.elapsed() < OFFLINE_WAIT / 2);
    }

    #[test]
    fn a_failed_adjustment_reads_its_frames_without_tracking_them() {
        let (tx, rx) = bounded(16);
        for m in [
            frame(7, 10),
            frame(7, 20),
            CatchUpMessage::End(7),
            frame(8, 30),
        ] {
            tx.send(m).unwrap();
        }
        let start = CatchUpStart {
            covariance: Matrix15::identity(),
            brightness: (0.0, 0.0),
            wait_for_end: true,
        };
        skip_frames(&rx, 7, &start);
        assert_eq!(times(&rx, 8, false), vec![30]);
    }
}
