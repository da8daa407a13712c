//! `[tracking] keyframe_max_velocity_divergence_m_s`: the tracked velocity against the IMU's
//! dead reckoning from the keyframe window's newest keyframe (eq. 1–3 from the window's solved
//! state and bias at it). The keyframe window reads the IMU against the map's scale only when a
//! keyframe is started; between two, the tracker's velocity is the joint solution of one frame's
//! photometric term and one frame's IMU prior (eq. 16), and a map of the wrong scale pulls it
//! along a little at every frame. The difference from the dead reckoning is the sum of those
//! pulls since the keyframe: when it exceeds the limit, a new keyframe is asked for, so that the
//! window reads the map while the frames tracked against it are still few.

use super::*;
use crate::tracking::TrackResult;

/// The IMU integrated from the window's newest keyframe (the state it was solved at), extended
/// frame by frame.
pub(super) struct DeadReckoning {
    from: FrameState,
    pre: Preintegration,
}

impl Odometry {
    /// `|v_tracked − v_IMU|` at `result`'s frame, m/s: the tracked velocity against the IMU
    /// integrated from the window's newest keyframe (its solved state and bias). `None` without
    /// a window, while a stored keyframe is tracked, or when the IMU since the newest keyframe is
    /// no longer buffered.
    pub(super) fn velocity_divergence_m_s(&mut self, result: &TrackResult) -> Option<f64> {
        if !self.cfg.window.enabled || self.reusing {
            return None;
        }
        let (_, from) = self.window.newest()?;
        let from = *from;
        if result.t <= from.nav.t || !self.imu_buffered_since(&from) {
            return None;
        }
        let fresh = match &self.dead_reckoning {
            Some(d) => d.from != from || d.pre.t_end > result.t,
            None => true,
        };
        if fresh {
            self.dead_reckoning = Some(DeadReckoning {
                from,
                pre: Preintegration::new(from.nav.t, from.bias),
            });
        }
        let d = self.dead_reckoning.as_mut()?;
        d.pre.integrate(self.imu.make_contiguous(), result.t, None);
        let predicted = d.pre.predict(&d.from.nav, &d.from.bias);
        let divergence_m_s = (result.state.nav.v_world_m_s - predicted.v_world_m_s).norm();
        divergence_m_s.is_finite().then_some(divergence_m_s)
    }
}
