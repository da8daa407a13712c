//! The record of every in-flight keyframe adjustment that came back (`OUT/adjustments.csv`): how
//! late it was and what it changed, for finding the adjustments that throw a flight.

use crate::time::TimeNs;

/// What became of one keyframe adjustment that came back (`OUT/adjustments.csv`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdjustmentOutcome {
    /// Installed, and tracking continued from its last view.
    Applied,
    /// Moved its last view's velocity by more than `[keyframe_bundle] max_velocity_change_m_s`:
    /// the keyframe was installed as the mapper built it.
    Rejected,
    /// Came back without a finite result: installed as the mapper built it.
    Failed,
    /// Its keyframe was no longer the one tracked or waited for (lost meanwhile).
    Discarded,
}

impl AdjustmentOutcome {
    pub fn as_str(self) -> &'static str {
        match self {
            AdjustmentOutcome::Applied => "applied",
            AdjustmentOutcome::Rejected => "rejected",
            AdjustmentOutcome::Failed => "failed",
            AdjustmentOutcome::Discarded => "discarded",
        }
    }
}

/// One in-flight keyframe adjustment as it came back (real time: how late, and what it would
/// have changed), for finding the adjustments that throw a flight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdjustmentRecord {
    /// The adjusted keyframe's time.
    pub keyframe_t: TimeNs,
    /// The last frame processed before it was taken (it is applied before the next one is
    /// tracked).
    pub taken_after_t: TimeNs,
    /// Frames between the frame it was sent at and the one it was taken at.
    pub frames_late: u64,
    /// A keyframe tracked with guessed depths (its depths rescaled by it), not a new one.
    pub guessed: bool,
    /// Adjusted together with the keyframe tracked when it was started, that one the gauge
    /// (`[keyframe_bundle] previous_host`); false when it had no such keyframe (a stored one, one
    /// of guesses, not the keyframe window's newest) or no result.
    pub with_previous: bool,
    /// Adjusted with the keyframe before: the time from it to the first frame after it in the
    /// adjustment's chain (the IMU alone across it), s; NaN otherwise. One frame interval when the
    /// frames tracked since that keyframe's time are kept for it — also those of the wait for its
    /// own adjustment (real time), moved by that adjustment.
    pub chain_imu_gap_s: f64,
    /// Change of its last view's velocity from the state tracking had, m/s (NaN: no result).
    pub velocity_change_m_s: f64,
    /// Change of the accelerometer bias from the tracker's, m/s² (NaN: no result).
    pub accel_bias_jump_m_s2: f64,
    /// Median relative inverse-depth change of the map (NaN: no result).
    pub depth_change: f64,
    /// Its wall time on the refinement thread, s.
    pub time_s: f64,
    pub outcome: AdjustmentOutcome,
}

/// `adjustments.csv`: one row per keyframe adjustment that came back.
pub fn adjustments_csv(rows: &[AdjustmentRecord]) -> String {
    let mut s = String::from(
        "keyframe_t_ns,taken_after_t_ns,frames_late,guessed,with_previous,chain_imu_gap_s,\
         velocity_change_m_s,accel_bias_jump_m_s2,depth_change,time_ms,outcome\n",
    );
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{},{},{:.3},{:.4},{:.4},{:.4},{:.1},{}\n",
            r.keyframe_t.0,
            r.taken_after_t.0,
            r.frames_late,
            u8::from(r.guessed),
            u8::from(r.with_previous),
            r.chain_imu_gap_s,
            r.velocity_change_m_s,
            r.accel_bias_jump_m_s2,
            r.depth_change,
            r.time_s * 1e3,
            r.outcome.as_str()
        ));
    }
    s
}
