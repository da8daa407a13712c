//! TIMESYNC (#111): answering the flight controller's requests, and estimating its clock.
//!
//! Protocol: a request has `tc1 = 0` and `ts1 =` the requester's time (ns); the reply copies
//! `ts1` and sets `tc1 =` the responder's time (ns), addressed back to the requester. The
//! requester then knows `offset = tc1 - (ts1 + t_receive) / 2` (symmetric delay assumed) with an
//! error bounded by half the round trip time.
//!
//! Time base of the timestamps we send. PX4 (`Timesync::sync_stamp`) and ArduPilot (jitter
//! correction) both expect `time_usec` in the *companion's* clock and convert it themselves —
//! PX4 from its own TIMESYNC requests, which is why answering them matters. So by default the
//! sender stamps with the host monotonic clock ([`crate::output::TimeBase::Companion`]). For
//! receivers that use the stamp as-is, [`crate::output::TimeBase::FlightController`] sends our own
//! requests to the FC and, once [`TimeOffsetEstimator`] has converged, stamps in the FC's clock
//! (before convergence: host monotonic).

use crate::time::TimeNs;
use mavlink::MavHeader;
use mavlink::dialects::common::TIMESYNC_DATA;
use std::collections::VecDeque;

/// The reply to `request` from `from`, if it is a request (tc1 == 0) addressed to us
/// (`target_system` 0 or ours, `target_component` 0 or ours; both 0 for senders without the
/// MAVLink 2 extension fields).
pub fn reply_to(
    request: &TIMESYNC_DATA,
    from: &MavHeader,
    own: &MavHeader,
    now: TimeNs,
) -> Option<TIMESYNC_DATA> {
    let for_us = (request.target_system == 0 || u32::from(request.target_system) == own.system_id)
        && (request.target_component == 0 || request.target_component == own.component_id);
    (request.tc1 == 0 && for_us).then(|| TIMESYNC_DATA {
        tc1: now.0,
        ts1: request.ts1,
        target_system: u8::try_from(from.system_id).unwrap_or(0),
        target_component: from.component_id,
    })
}

/// A request stamped `now`, addressed to the FC (`target_system`, `target_component`).
pub fn request(now: TimeNs, target_system: u8, target_component: u8) -> TIMESYNC_DATA {
    TIMESYNC_DATA {
        tc1: 0,
        ts1: now.0,
        target_system,
        target_component,
    }
}

/// What became of one reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyVerdict {
    /// Used: `offset_ns` = FC clock - our clock, measured with round trip `rtt_ns`.
    Accepted { offset_ns: i64, rtt_ns: i64 },
    /// Round trip longer than the configured maximum: too imprecise, ignored.
    RttTooHigh { rtt_ns: i64 },
    /// Not a reply to a request of ours still in flight (another requester's, or a duplicate).
    NotOurs,
}

/// Estimates `FC clock - host monotonic clock` from replies to our requests.
///
/// Keeps the last `WINDOW` accepted samples and uses the one with the smallest round trip (its
/// error bound is the tightest). Converged once `min_samples` samples are in the window. A run of
/// `MAX_DEVIATING` consecutive samples more than `max_deviation_ns` away from the estimate (the FC
/// rebooted or its clock jumped) restarts the estimate.
#[derive(Clone, Debug)]
pub struct TimeOffsetEstimator {
    max_rtt_ns: i64,
    max_deviation_ns: i64,
    min_samples: usize,
    in_flight: VecDeque<i64>,
    window: VecDeque<(i64, i64)>,
    deviating: usize,
}

impl TimeOffsetEstimator {
    const WINDOW: usize = 32;
    const IN_FLIGHT: usize = 32;
    const MAX_DEVIATING: usize = 5;

    /// `max_rtt_ns`: replies with a longer round trip are ignored (PX4 uses 10 ms);
    /// `min_samples`: accepted samples needed before [`Self::offset_ns`] answers.
    pub fn new(max_rtt_ns: i64, min_samples: usize) -> Self {
        TimeOffsetEstimator {
            max_rtt_ns,
            max_deviation_ns: max_rtt_ns.max(10_000_000),
            min_samples: min_samples.clamp(1, Self::WINDOW),
            in_flight: VecDeque::new(),
            window: VecDeque::new(),
            deviating: 0,
        }
    }

    /// Records a request we sent with `ts1`.
    pub fn on_request_sent(&mut self, ts1: i64) {
        if self.in_flight.len() == Self::IN_FLIGHT {
            self.in_flight.pop_front();
        }
        self.in_flight.push_back(ts1);
    }

    /// Feeds a reply (`tc1 != 0`) received at `t_receive`.
    pub fn on_reply(&mut self, ts1: i64, tc1: i64, t_receive: TimeNs) -> ReplyVerdict {
        let Some(pos) = self.in_flight.iter().position(|&t| t == ts1) else {
            return ReplyVerdict::NotOurs;
        };
        self.in_flight.remove(pos);
        let rtt_ns = t_receive.0 - ts1;
        if rtt_ns < 0 {
            return ReplyVerdict::NotOurs;
        }
        if rtt_ns > self.max_rtt_ns {
            return ReplyVerdict::RttTooHigh { rtt_ns };
        }
        // ts1 + rtt/2 without overflow for any i64 clock.
        let offset_ns = tc1 - (ts1 + rtt_ns / 2);
        if let Some(est) = self.offset_ns()
            && (offset_ns - est).abs() > self.max_deviation_ns
        {
            self.deviating += 1;
            if self.deviating < Self::MAX_DEVIATING {
                return ReplyVerdict::Accepted { offset_ns, rtt_ns };
            }
            self.window.clear();
        }
        self.deviating = 0;
        if self.window.len() == Self::WINDOW {
            self.window.pop_front();
        }
        self.window.push_back((rtt_ns, offset_ns));
        ReplyVerdict::Accepted { offset_ns, rtt_ns }
    }

    /// FC clock minus host monotonic clock, once converged.
    pub fn offset_ns(&self) -> Option<i64> {
        if self.window.len() < self.min_samples {
            return None;
        }
        self.window
            .iter()
            .min_by_key(|(rtt, _)| *rtt)
            .map(|&(_, off)| off)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;

    fn hdr(system_id: u32, component_id: u8) -> MavHeader {
        MavHeader {
            system_id,
            component_id,
            sequence: 0,
        }
    }

    #[test]
    fn replies_only_to_requests_for_us() {
        let own = hdr(1, 197);
        let fc = hdr(1, 1);
        let req = request(TimeNs(123), 0, 0);
        let r = reply_to(&req, &fc, &own, TimeNs(999)).unwrap();
        assert_eq!(
            (r.tc1, r.ts1, r.target_system, r.target_component),
            (999, 123, 1, 1)
        );
        let to_other = TIMESYNC_DATA {
            target_component: 191,
            ..req
        };
        assert!(reply_to(&to_other, &fc, &own, TimeNs(999)).is_none());
        let to_us = TIMESYNC_DATA {
            target_system: 1,
            target_component: 197,
            ..req
        };
        assert!(reply_to(&to_us, &fc, &own, TimeNs(999)).is_some());
        // A reply is not a request.
        assert!(reply_to(&r, &fc, &own, TimeNs(1000)).is_none());
    }

    /// Simulates requests at `t`, a reply `d_up` later from an FC clock `offset` ahead, received
    /// `d_down` after that.
    fn exchange(
        e: &mut TimeOffsetEstimator,
        t: i64,
        offset: i64,
        d_up: i64,
        d_down: i64,
    ) -> ReplyVerdict {
        e.on_request_sent(t);
        e.on_reply(t, t + d_up + offset, TimeNs(t + d_up + d_down))
    }

    #[test]
    fn converges_to_the_min_rtt_offset() {
        let offset = 1_000_000 * MS + 123_456; // FC ahead by 1000 s
        let mut e = TimeOffsetEstimator::new(10 * MS, 3);
        assert_eq!(
            exchange(&mut e, 0, offset, MS, MS),
            ReplyVerdict::Accepted {
                offset_ns: offset,
                rtt_ns: 2 * MS
            }
        );
        assert_eq!(e.offset_ns(), None);
        // Asymmetric delays bias the sample by (up - down) / 2.
        exchange(&mut e, 100 * MS, offset, 3 * MS, MS);
        assert_eq!(e.offset_ns(), None);
        exchange(&mut e, 200 * MS, offset, 400_000, 200_000);
        // Min RTT (0.6 ms) sample: bias (0.4 - 0.2) / 2 = 0.1 ms.
        assert_eq!(e.offset_ns(), Some(offset + 100_000));
    }

    #[test]
    fn rejects_high_rtt_and_foreign_replies() {
        let mut e = TimeOffsetEstimator::new(10 * MS, 1);
        assert_eq!(
            exchange(&mut e, 0, 5, 6 * MS, 6 * MS),
            ReplyVerdict::RttTooHigh { rtt_ns: 12 * MS }
        );
        assert_eq!(e.on_reply(777, 1, TimeNs(800)), ReplyVerdict::NotOurs);
        assert_eq!(e.offset_ns(), None);
        // A duplicate reply to an answered request is not used twice.
        assert!(matches!(
            exchange(&mut e, 10, 5, 1, 1),
            ReplyVerdict::Accepted { .. }
        ));
        assert_eq!(e.on_reply(10, 16, TimeNs(12)), ReplyVerdict::NotOurs);
    }

    #[test]
    fn restarts_after_a_clock_jump() {
        let mut e = TimeOffsetEstimator::new(10 * MS, 2);
        for k in 0..4 {
            exchange(&mut e, k * 100 * MS, 50 * MS, MS, MS);
        }
        assert_eq!(e.offset_ns(), Some(50 * MS));
        // FC reboots: its clock now is 2 s behind ours.
        for k in 4..8 {
            exchange(&mut e, k * 100 * MS, -2000 * MS, MS, MS);
            assert_eq!(
                e.offset_ns(),
                Some(50 * MS),
                "sample {k} must not move the estimate yet"
            );
        }
        exchange(&mut e, 800 * MS, -2000 * MS, MS, MS);
        assert_eq!(e.offset_ns(), None, "restarted, needs 2 samples");
        exchange(&mut e, 900 * MS, -2000 * MS, MS, MS);
        assert_eq!(e.offset_ns(), Some(-2000 * MS));
    }
}
