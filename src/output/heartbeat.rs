//! HEARTBEAT (#0) of the VIO component, with a MAV_STATE that follows tracking health.
//!
//! | situation                                                         | MAV_STATE          |
//! |-------------------------------------------------------------------|--------------------|
//! | no sample received yet (estimator initialising)                   | STANDBY            |
//! | last sample tracking                                              | ACTIVE             |
//! | failed (health `Failed` or a non-finite sample) for < `terminate_after` | CRITICAL     |
//! | failed for >= `terminate_after`, or no sample for >= `terminate_after`, or shut down | FLIGHT_TERMINATION |
//!
//! FLIGHT_TERMINATION tells the FC the VIO stream is gone for good, so it can fail over without
//! waiting for its own heartbeat timeout.

use crate::output::sample::TrackingHealth;
use crate::time::TimeNs;
use mavlink::dialects::common::{HEARTBEAT_DATA, MavAutopilot, MavModeFlag, MavState, MavType};

/// Tracks health over time for the heartbeat. Times are host monotonic (arrival times).
#[derive(Clone, Debug)]
pub struct HealthMonitor {
    terminate_after_ns: i64,
    last_sample_at: Option<TimeNs>,
    failed_since: Option<TimeNs>,
    shut_down: bool,
}

impl HealthMonitor {
    pub fn new(terminate_after_ns: i64) -> Self {
        HealthMonitor {
            terminate_after_ns,
            last_sample_at: None,
            failed_since: None,
            shut_down: false,
        }
    }

    /// Records a sample that arrived at `now`; `health` is `Failed` for non-finite samples.
    pub fn on_sample(&mut self, now: TimeNs, health: TrackingHealth) {
        self.last_sample_at = Some(now);
        match health {
            TrackingHealth::Failed => {
                self.failed_since.get_or_insert(now);
            }
            TrackingHealth::Tracking { .. } => self.failed_since = None,
        }
    }

    /// Records that the estimator stopped (the sender is finishing).
    pub fn on_shutdown(&mut self) {
        self.shut_down = true;
    }

    /// The state to report at `now`.
    pub fn state(&self, now: TimeNs) -> MavState {
        if self.shut_down {
            return MavState::MAV_STATE_FLIGHT_TERMINATION;
        }
        let Some(last) = self.last_sample_at else {
            return MavState::MAV_STATE_STANDBY;
        };
        if now.ns_since(last) >= self.terminate_after_ns {
            return MavState::MAV_STATE_FLIGHT_TERMINATION;
        }
        match self.failed_since {
            None => MavState::MAV_STATE_ACTIVE,
            Some(t) if now.ns_since(t) >= self.terminate_after_ns => {
                MavState::MAV_STATE_FLIGHT_TERMINATION
            }
            Some(_) => MavState::MAV_STATE_CRITICAL,
        }
    }
}

/// The heartbeat of an onboard VIO component in `state`.
pub fn heartbeat(state: MavState) -> HEARTBEAT_DATA {
    HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: state,
        mavlink_version: 3,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: i64 = 1_000_000_000;

    #[test]
    fn states_follow_health_and_time() {
        let mut m = HealthMonitor::new(2 * S);
        assert_eq!(m.state(TimeNs(0)), MavState::MAV_STATE_STANDBY);
        m.on_sample(
            TimeNs(S),
            TrackingHealth::Tracking {
                quality_percent: 80,
            },
        );
        assert_eq!(m.state(TimeNs(S)), MavState::MAV_STATE_ACTIVE);
        m.on_sample(TimeNs(2 * S), TrackingHealth::Failed);
        m.on_sample(TimeNs(3 * S), TrackingHealth::Failed);
        assert_eq!(m.state(TimeNs(3 * S)), MavState::MAV_STATE_CRITICAL);
        assert_eq!(
            m.state(TimeNs(4 * S)),
            MavState::MAV_STATE_FLIGHT_TERMINATION
        );
        m.on_sample(
            TimeNs(4 * S),
            TrackingHealth::Tracking {
                quality_percent: 10,
            },
        );
        assert_eq!(m.state(TimeNs(4 * S)), MavState::MAV_STATE_ACTIVE);
        // Stalled estimator: no sample for terminate_after.
        assert_eq!(m.state(TimeNs(6 * S - 1)), MavState::MAV_STATE_ACTIVE);
        assert_eq!(
            m.state(TimeNs(6 * S)),
            MavState::MAV_STATE_FLIGHT_TERMINATION
        );
        m.on_shutdown();
        assert_eq!(
            m.state(TimeNs(4 * S)),
            MavState::MAV_STATE_FLIGHT_TERMINATION
        );
    }

    #[test]
    fn heartbeat_identifies_an_onboard_component() {
        let h = heartbeat(MavState::MAV_STATE_CRITICAL);
        assert_eq!(h.mavtype, MavType::MAV_TYPE_ONBOARD_CONTROLLER);
        assert_eq!(h.autopilot, MavAutopilot::MAV_AUTOPILOT_INVALID);
        assert_eq!(h.system_status, MavState::MAV_STATE_CRITICAL);
    }
}
