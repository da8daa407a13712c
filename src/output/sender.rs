//! The MAVLink sender: a bounded queue from the tracking thread to a sender thread, and a receiver
//! thread that answers TIMESYNC at once.
//!
//! ```text
//!  tracking thread --push()--> [bounded queue, oldest dropped] --> sender thread --+--> UDP
//!   (never blocks)                                                 rate, frames,   |
//!                                                                  HEARTBEAT 1 Hz  |
//!                                                 receiver thread <----------------+
//!                                                 TIMESYNC replies (and our offset estimate)
//! ```
//!
//! The sender thread drops and counts samples with any NaN/Inf (and the next message then carries
//! quality -1, the heartbeat turns CRITICAL), decimates to `rate_hz` on the samples' own
//! timestamps, increments `reset_counter` whenever [`OdometrySample::reset_epoch`] changes, and
//! stamps `time_usec` in the configured [`TimeBase`].

use crate::output::OutputError;
use crate::output::endpoint::Endpoint;
use crate::output::heartbeat::{HealthMonitor, heartbeat};
use crate::output::link::{Link, Sent, decode_datagram};
use crate::output::odometry::{MessageConfig, MessageSet, WireStamp};
use crate::output::sample::{OdometrySample, TrackingHealth};
use crate::output::timesync::{ReplyVerdict, TimeOffsetEstimator, reply_to, request};
use crate::time::host_monotonic_now;
use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError, bounded};
use mavlink::dialects::common::MavMessage;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// Clock of the `time_usec` we send (see [`crate::output::timesync`] for why the default is
/// right for PX4 and ArduPilot).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum TimeBase {
    /// Host monotonic clock; the FC converts with its own TIMESYNC estimate (PX4, ArduPilot).
    #[default]
    Companion,
    /// The FC's clock, once our TIMESYNC estimate has converged (host monotonic before that).
    #[value(name = "fc")]
    FlightController,
}

/// Sender settings. [`SenderConfig::new`] gives the defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct SenderConfig {
    pub endpoint: Endpoint,
    /// Our system id: normally the vehicle's (the FC's) system id.
    pub system_id: u8,
    /// 197 = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY.
    pub component_id: u8,
    /// The FC's component id (TIMESYNC requests go to it, replies are accepted only from it).
    pub fc_component_id: u8,
    pub messages: MessageConfig,
    /// Maximum pose message rate; faster input is decimated on its timestamps.
    pub rate_hz: f64,
    /// Samples waiting for the sender thread; when full the oldest is dropped.
    pub queue_capacity: usize,
    pub time_base: TimeBase,
    /// Rate of our TIMESYNC requests ([`TimeBase::FlightController`] only).
    pub timesync_request_hz: f64,
    /// TIMESYNC replies with a longer round trip are ignored.
    pub timesync_max_rtt_ns: i64,
    /// Accepted TIMESYNC samples before the FC time base is used.
    pub timesync_min_samples: usize,
    /// Failed (or silent) for this long: heartbeat MAV_STATE_FLIGHT_TERMINATION.
    pub terminate_after_ns: i64,
}

impl SenderConfig {
    /// Defaults: system 1, component 197, FC component 1, ODOMETRY at 30 Hz in LOCAL_FRD,
    /// queue of 8, companion time base, TIMESYNC requests at 10 Hz with RTT <= 10 ms and 5
    /// samples, FLIGHT_TERMINATION after 2 s failed.
    pub fn new(endpoint: Endpoint) -> Self {
        SenderConfig {
            endpoint,
            system_id: 1,
            component_id: 197,
            fc_component_id: 1,
            messages: MessageConfig::default(),
            rate_hz: 30.0,
            queue_capacity: 8,
            time_base: TimeBase::Companion,
            timesync_request_hz: 10.0,
            timesync_max_rtt_ns: 10_000_000,
            timesync_min_samples: 5,
            terminate_after_ns: 2_000_000_000,
        }
    }

    fn validate(&self) -> Result<(), OutputError> {
        let bad = |m: String| Err(OutputError::Config(m));
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return bad(format!("rate_hz must be > 0, got {}", self.rate_hz));
        }
        if !(self.timesync_request_hz.is_finite() && self.timesync_request_hz > 0.0) {
            return bad(format!(
                "timesync_request_hz must be > 0, got {}",
                self.timesync_request_hz
            ));
        }
        if self.queue_capacity == 0 {
            return bad("queue_capacity must be >= 1".into());
        }
        let c = &self.messages.covariance;
        for (name, v) in [
            ("position_std_m", c.position_std_m),
            ("attitude_std_rad", c.attitude_std_rad),
            ("velocity_std_m_s", c.velocity_std_m_s),
            ("angular_rate_std_rad_s", c.angular_rate_std_rad_s),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return bad(format!("{name} must be finite and >= 0, got {v}"));
            }
        }
        Ok(())
    }
}

/// Counters since start. Every sample pushed ends in exactly one of `pose_samples_sent`,
/// `dropped_queue_full`, `dropped_non_finite`, `decimated`, `failed_not_sent` (legacy mode),
/// `not_sent_no_peer`, `send_errors` or `dropped_sender_gone`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SenderStats {
    pub samples_in: u64,
    pub pose_samples_sent: u64,
    pub dropped_queue_full: u64,
    pub dropped_non_finite: u64,
    pub decimated: u64,
    pub failed_not_sent: u64,
    pub not_sent_no_peer: u64,
    pub dropped_sender_gone: u64,
    /// Socket errors on any send (pose, heartbeat, TIMESYNC).
    pub send_errors: u64,
    pub heartbeats_sent: u64,
    pub timesync_replies_sent: u64,
    pub timesync_requests_sent: u64,
    pub timesync_samples_accepted: u64,
    pub timesync_samples_rejected_rtt: u64,
    pub rx_datagrams: u64,
    pub rx_messages: u64,
    /// Received bytes that were not part of a CRC-valid common-dialect message.
    pub rx_bytes_skipped: u64,
    pub rx_errors: u64,
    /// Current MAVLink `reset_counter`.
    pub reset_counter: u8,
    /// FC clock - host monotonic clock, ns, when our TIMESYNC estimate has converged.
    pub fc_time_offset_ns: Option<i64>,
}

impl SenderStats {
    /// One line for logs: what was sent, what was dropped and why.
    pub fn summary(&self) -> String {
        format!(
            "{} pose samples sent ({} in; dropped: {} non-finite, {} queue full, {} decimated, \
             {} without peer, {} failed in legacy mode, {} after stop; {} send errors); \
             {} HEARTBEAT, {} TIMESYNC replies, {} TIMESYNC requests ({} samples accepted{}); \
             reset_counter {}; received {} messages, {} corrupt or unknown bytes skipped",
            self.pose_samples_sent,
            self.samples_in,
            self.dropped_non_finite,
            self.dropped_queue_full,
            self.decimated,
            self.not_sent_no_peer,
            self.failed_not_sent,
            self.dropped_sender_gone,
            self.send_errors,
            self.heartbeats_sent,
            self.timesync_replies_sent,
            self.timesync_requests_sent,
            self.timesync_samples_accepted,
            self.fc_time_offset_ns
                .map_or(String::new(), |o| format!(", FC clock offset {o} ns")),
            self.reset_counter,
            self.rx_messages,
            self.rx_bytes_skipped,
        )
    }
}

#[derive(Default)]
struct Counters {
    samples_in: AtomicU64,
    pose_samples_sent: AtomicU64,
    dropped_queue_full: AtomicU64,
    dropped_non_finite: AtomicU64,
    decimated: AtomicU64,
    failed_not_sent: AtomicU64,
    not_sent_no_peer: AtomicU64,
    dropped_sender_gone: AtomicU64,
    send_errors: AtomicU64,
    heartbeats_sent: AtomicU64,
    timesync_replies_sent: AtomicU64,
    timesync_requests_sent: AtomicU64,
    timesync_samples_accepted: AtomicU64,
    timesync_samples_rejected_rtt: AtomicU64,
    rx_datagrams: AtomicU64,
    rx_messages: AtomicU64,
    rx_bytes_skipped: AtomicU64,
    rx_errors: AtomicU64,
    reset_counter: AtomicI64,
}

fn inc(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SendFail {
    NoPeer,
    Socket,
}

struct Shared {
    link: Link,
    counters: Counters,
    estimator: Mutex<TimeOffsetEstimator>,
    last_send_error: Mutex<Option<String>>,
    stop_receiver: AtomicBool,
}

impl Shared {
    /// Sends one message; socket errors are counted and remembered here.
    fn send(&self, msg: &MavMessage) -> Result<(), SendFail> {
        match self.link.send(msg) {
            Ok(Sent::Yes) => Ok(()),
            Ok(Sent::NoPeer) => Err(SendFail::NoPeer),
            Err(e) => {
                inc(&self.counters.send_errors);
                *self
                    .last_send_error
                    .lock()
                    .unwrap_or_else(|p| p.into_inner()) = Some(e.to_string());
                Err(SendFail::Socket)
            }
        }
    }

    fn estimator(&self) -> std::sync::MutexGuard<'_, TimeOffsetEstimator> {
        self.estimator.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// A bounded single-consumer queue whose producer never blocks: when full, the oldest item is
/// dropped.
struct DropOldestQueue<T> {
    tx: Sender<T>,
    /// The producer's handle on the consumer end, used only to pop the oldest item.
    rx: Receiver<T>,
}

/// Outcome of [`DropOldestQueue::push`].
#[derive(Debug, PartialEq, Eq)]
enum Pushed {
    Queued { dropped_oldest: u64 },
    ConsumerGone,
}

impl<T> DropOldestQueue<T> {
    fn new(capacity: usize) -> (Self, Receiver<T>) {
        let (tx, rx) = bounded(capacity);
        (DropOldestQueue { tx, rx: rx.clone() }, rx)
    }

    fn push(&self, item: T) -> Pushed {
        let mut item = item;
        let mut dropped_oldest = 0;
        loop {
            match self.tx.try_send(item) {
                Ok(()) => return Pushed::Queued { dropped_oldest },
                Err(TrySendError::Full(back)) => {
                    if self.rx.try_recv().is_ok() {
                        dropped_oldest += 1;
                    }
                    item = back;
                }
                Err(TrySendError::Disconnected(_)) => return Pushed::ConsumerGone,
            }
        }
    }
}

/// Admits samples at most at `rate_hz` on their timestamps, on a fixed grid (so 200 Hz input
/// gives 30 Hz on average, and jittery 30 Hz input is not halved).
#[derive(Clone, Debug)]
struct Pacer {
    period_ns: i64,
    tolerance_ns: i64,
    next_due_ns: Option<i64>,
    last_ns: i64,
}

impl Pacer {
    fn new(rate_hz: f64) -> Self {
        let period_ns = (1e9 / rate_hz).round().max(1.0) as i64;
        Pacer {
            period_ns,
            tolerance_ns: period_ns / 4,
            next_due_ns: None,
            last_ns: i64::MIN,
        }
    }

    fn admit(&mut self, t_ns: i64) -> bool {
        let admitted = match self.next_due_ns {
            Some(due) if t_ns >= self.last_ns && t_ns + self.tolerance_ns < due => false,
            Some(due) if t_ns >= self.last_ns => {
                let next = due + self.period_ns;
                self.next_due_ns = Some(if t_ns + self.tolerance_ns >= next {
                    t_ns + self.period_ns
                } else {
                    next
                });
                true
            }
            // First sample, or time went backwards: re-anchor.
            _ => {
                self.next_due_ns = Some(t_ns + self.period_ns);
                true
            }
        };
        if admitted {
            self.last_ns = t_ns;
        }
        admitted
    }
}

/// Streams [`OdometrySample`]s to the flight controller. Create with [`MavlinkSender::start`],
/// feed with [`MavlinkSender::push`] from the tracking thread, end with
/// [`MavlinkSender::finish`] (or drop it).
pub struct MavlinkSender {
    queue: Option<DropOldestQueue<OdometrySample>>,
    shared: Arc<Shared>,
    sender_thread: Option<JoinHandle<()>>,
    receiver_thread: Option<JoinHandle<()>>,
}

impl MavlinkSender {
    /// Opens the endpoint and starts the sender and receiver threads. The first heartbeat goes out
    /// at once.
    pub fn start(config: SenderConfig) -> Result<Self, OutputError> {
        config.validate()?;
        let open = config.endpoint.open()?;
        let endpoint_text = config.endpoint.to_string();
        let io_err = |what: &'static str| {
            let endpoint = endpoint_text.clone();
            move |source| OutputError::Io {
                endpoint,
                what,
                source,
            }
        };
        let link = Link::new(
            open,
            config.system_id,
            config.component_id,
            Duration::from_millis(50),
        )
        .map_err(io_err("setting the socket read timeout"))?;
        let shared = Arc::new(Shared {
            link,
            counters: Counters::default(),
            estimator: Mutex::new(TimeOffsetEstimator::new(
                config.timesync_max_rtt_ns,
                config.timesync_min_samples,
            )),
            last_send_error: Mutex::new(None),
            stop_receiver: AtomicBool::new(false),
        });
        let (queue, rx) = DropOldestQueue::new(config.queue_capacity);
        let fc_component = config.fc_component_id;
        let receiver_thread = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("mavlink-rx".into())
                .spawn(move || receive_loop(&shared, fc_component))
                .map_err(io_err("spawning the receiver thread"))?
        };
        let sender_thread = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("mavlink-tx".into())
                .spawn(move || send_loop(&shared, &config, &rx))
                .map_err(io_err("spawning the sender thread"))?
        };
        Ok(MavlinkSender {
            queue: Some(queue),
            shared,
            sender_thread: Some(sender_thread),
            receiver_thread: Some(receiver_thread),
        })
    }

    /// Queues a sample; never blocks. When the queue is full the oldest sample is dropped and
    /// counted (`dropped_queue_full`).
    pub fn push(&self, sample: OdometrySample) {
        let c = &self.shared.counters;
        inc(&c.samples_in);
        match self.queue.as_ref().map(|q| q.push(sample)) {
            Some(Pushed::Queued { dropped_oldest }) => {
                c.dropped_queue_full
                    .fetch_add(dropped_oldest, Ordering::Relaxed);
            }
            Some(Pushed::ConsumerGone) | None => inc(&c.dropped_sender_gone),
        }
    }

    /// Queues a sample, waiting for room: for offline producers (trajectory playback, replay as
    /// fast as possible) that must not lose samples. Never call it from the tracking thread.
    pub fn push_blocking(&self, sample: OdometrySample) {
        let c = &self.shared.counters;
        inc(&c.samples_in);
        let sent = self.queue.as_ref().map(|q| q.tx.send(sample).is_ok());
        if sent != Some(true) {
            inc(&c.dropped_sender_gone);
        }
    }

    /// The local address of our UDP socket.
    pub fn local_addr(&self) -> std::io::Result<std::net::SocketAddr> {
        self.shared.link.local_addr()
    }

    /// The last socket error message, if any send failed.
    pub fn last_send_error(&self) -> Option<String> {
        self.shared
            .last_send_error
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> SenderStats {
        let c = &self.shared.counters;
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        SenderStats {
            samples_in: g(&c.samples_in),
            pose_samples_sent: g(&c.pose_samples_sent),
            dropped_queue_full: g(&c.dropped_queue_full),
            dropped_non_finite: g(&c.dropped_non_finite),
            decimated: g(&c.decimated),
            failed_not_sent: g(&c.failed_not_sent),
            not_sent_no_peer: g(&c.not_sent_no_peer),
            dropped_sender_gone: g(&c.dropped_sender_gone),
            send_errors: g(&c.send_errors),
            heartbeats_sent: g(&c.heartbeats_sent),
            timesync_replies_sent: g(&c.timesync_replies_sent),
            timesync_requests_sent: g(&c.timesync_requests_sent),
            timesync_samples_accepted: g(&c.timesync_samples_accepted),
            timesync_samples_rejected_rtt: g(&c.timesync_samples_rejected_rtt),
            rx_datagrams: g(&c.rx_datagrams),
            rx_messages: g(&c.rx_messages),
            rx_bytes_skipped: g(&c.rx_bytes_skipped),
            rx_errors: g(&c.rx_errors),
            reset_counter: c.reset_counter.load(Ordering::Relaxed) as u8,
            fc_time_offset_ns: self.shared.estimator().offset_ns(),
        }
    }

    /// Sends what is queued, a last heartbeat (MAV_STATE_FLIGHT_TERMINATION: the stream ends),
    /// stops both threads and returns the final counters.
    pub fn finish(mut self) -> SenderStats {
        self.stop();
        self.stats()
    }

    fn stop(&mut self) {
        self.queue = None; // disconnects the channel: the sender thread drains it and exits
        if let Some(t) = self.sender_thread.take() {
            let _ = t.join();
        }
        self.shared.stop_receiver.store(true, Ordering::Relaxed);
        if let Some(t) = self.receiver_thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for MavlinkSender {
    fn drop(&mut self) {
        self.stop();
    }
}

fn send_loop(shared: &Shared, cfg: &SenderConfig, rx: &Receiver<OdometrySample>) {
    const HEARTBEAT_PERIOD_NS: i64 = 1_000_000_000;
    let c = &shared.counters;
    let mut health = HealthMonitor::new(cfg.terminate_after_ns);
    let mut pacer = Pacer::new(cfg.rate_hz);
    let timesync_period_ns = (1e9 / cfg.timesync_request_hz).round().max(1.0) as i64;
    let requests = cfg.time_base == TimeBase::FlightController;
    let mut last_epoch: Option<u32> = None;
    let mut reset_counter: u8 = 0;
    let mut after_invalid = false;
    let start = host_monotonic_now();
    let mut next_heartbeat = start;
    let mut next_request = start;
    let send_heartbeat = |health: &HealthMonitor| {
        let msg = MavMessage::HEARTBEAT(heartbeat(health.state(host_monotonic_now())));
        if shared.send(&msg).is_ok() {
            inc(&c.heartbeats_sent);
        }
    };
    loop {
        let now = host_monotonic_now();
        if now >= next_heartbeat {
            send_heartbeat(&health);
            next_heartbeat = next_heartbeat.add_ns(HEARTBEAT_PERIOD_NS).max(now);
        }
        if requests && now >= next_request {
            let t = host_monotonic_now();
            shared.estimator().on_request_sent(t.0);
            let msg = MavMessage::TIMESYNC(request(t, cfg.system_id, cfg.fc_component_id));
            if shared.send(&msg).is_ok() {
                inc(&c.timesync_requests_sent);
            }
            next_request = next_request.add_ns(timesync_period_ns).max(now);
        }
        let deadline = if requests {
            next_heartbeat.min(next_request)
        } else {
            next_heartbeat
        };
        let wait = Duration::from_nanos(deadline.ns_since(host_monotonic_now()).max(0) as u64);
        let s = match rx.recv_timeout(wait) {
            Ok(s) => s,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let arrived = host_monotonic_now();
        if !s.is_finite() || s.t.0 < 0 {
            inc(&c.dropped_non_finite);
            health.on_sample(arrived, TrackingHealth::Failed);
            after_invalid = true;
            continue;
        }
        health.on_sample(arrived, s.health);
        if last_epoch.is_some_and(|e| e != s.reset_epoch) {
            reset_counter = reset_counter.wrapping_add(1);
            c.reset_counter
                .store(i64::from(reset_counter), Ordering::Relaxed);
        }
        last_epoch = Some(s.reset_epoch);
        if !pacer.admit(s.t.0) {
            inc(&c.decimated);
            continue;
        }
        let quality = if after_invalid {
            -1
        } else {
            s.health.mavlink_quality()
        };
        after_invalid = false;
        let offset_ns = match cfg.time_base {
            TimeBase::Companion => 0,
            TimeBase::FlightController => shared.estimator().offset_ns().unwrap_or(0),
        };
        let Ok(time_usec) = u64::try_from(s.t.0.saturating_add(offset_ns) / 1000) else {
            inc(&c.dropped_non_finite);
            continue;
        };
        if cfg.messages.message_set == MessageSet::Legacy && quality < 0 {
            inc(&c.failed_not_sent);
            continue;
        }
        let stamp = WireStamp {
            time_usec,
            reset_counter,
            quality,
        };
        let Some(msgs) = cfg.messages.messages(&s, stamp) else {
            inc(&c.dropped_non_finite);
            continue;
        };
        let mut outcome = Ok(());
        for m in &msgs {
            outcome = outcome.and(shared.send(m));
        }
        match outcome {
            Ok(()) => inc(&c.pose_samples_sent),
            Err(SendFail::NoPeer) => inc(&c.not_sent_no_peer),
            Err(SendFail::Socket) => {} // counted in send_errors
        }
    }
    health.on_shutdown();
    send_heartbeat(&health);
}

fn receive_loop(shared: &Shared, fc_component: u8) {
    let c = &shared.counters;
    let own = shared.link.own_header();
    let mut buf = vec![0u8; 65_536];
    while !shared.stop_receiver.load(Ordering::Relaxed) {
        let n = match shared.link.recv(&mut buf) {
            Ok(Some((n, _from))) => n,
            Ok(None) => continue,
            Err(_) => {
                inc(&c.rx_errors);
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let t_receive = host_monotonic_now();
        inc(&c.rx_datagrams);
        let (msgs, skipped) = decode_datagram(&buf[..n]);
        c.rx_bytes_skipped
            .fetch_add(skipped as u64, Ordering::Relaxed);
        for (header, msg) in msgs {
            inc(&c.rx_messages);
            let MavMessage::TIMESYNC(ts) = msg else {
                continue;
            };
            if ts.tc1 == 0 {
                if let Some(r) = reply_to(&ts, &header, &own, host_monotonic_now())
                    && shared.send(&MavMessage::TIMESYNC(r)).is_ok()
                {
                    inc(&c.timesync_replies_sent);
                }
                continue;
            }
            let from_fc = header.system_id == own.system_id && header.component_id == fc_component;
            let to_us = (ts.target_system == 0 || u32::from(ts.target_system) == own.system_id)
                && (ts.target_component == 0 || ts.target_component == own.component_id);
            if !(from_fc && to_us) {
                continue;
            }
            match shared.estimator().on_reply(ts.ts1, ts.tc1, t_receive) {
                ReplyVerdict::Accepted { .. } => inc(&c.timesync_samples_accepted),
                ReplyVerdict::RttTooHigh { .. } => inc(&c.timesync_samples_rejected_rtt),
                ReplyVerdict::NotOurs => {}
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::link::decode_datagram;
    use crate::time::TimeNs;
    use nalgebra::{Isometry3, Vector3};
    use std::net::UdpSocket;

    #[test]
    fn queue_drops_the_oldest_when_full() {
        let (q, rx) = DropOldestQueue::new(2);
        assert_eq!(q.push(1), Pushed::Queued { dropped_oldest: 0 });
        assert_eq!(q.push(2), Pushed::Queued { dropped_oldest: 0 });
        assert_eq!(q.push(3), Pushed::Queued { dropped_oldest: 1 });
        assert_eq!(rx.try_iter().collect::<Vec<_>>(), vec![2, 3]);
        drop(rx);
        // The producer's own receiver handle keeps the channel open; the real consumer leaving
        // is signalled by the sender thread ending, covered by `dropped_sender_gone`.
    }

    #[test]
    fn pacer_decimates_fast_input_and_keeps_jittery_input() {
        let ms = 1_000_000;
        let mut p = Pacer::new(30.0);
        let admitted = (0..200).filter(|k| p.admit(k * 5 * ms)).count(); // 1 s at 200 Hz
        assert!((29..=31).contains(&admitted), "{admitted}");
        let mut p = Pacer::new(30.0);
        let jitter = [0, 5, -5, 3, -3];
        let all = (0..30).all(|k: i64| p.admit(k * 33_333_333 + jitter[k as usize % 5] * ms));
        assert!(all, "30 Hz input with 5 ms jitter must all pass");
        let mut p = Pacer::new(30.0);
        assert!(p.admit(10 * ms) && p.admit(100 * ms));
        assert!(p.admit(50 * ms), "time going backwards re-anchors");
    }

    fn sample(k: i64) -> OdometrySample {
        OdometrySample::new(
            TimeNs(1_000_000_000 + k * 40_000_000),
            Isometry3::new(Vector3::new(k as f64, 0.0, 1.0), Vector3::zeros()),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::zeros(),
        )
    }

    /// Everything the peer socket received until the sender finished.
    fn drain(peer: &UdpSocket) -> Vec<MavMessage> {
        peer.set_nonblocking(true).unwrap();
        let mut buf = [0u8; 2048];
        let mut out = Vec::new();
        while let Ok(n) = peer.recv(&mut buf) {
            let (msgs, skipped) = decode_datagram(&buf[..n]);
            assert_eq!(skipped, 0);
            out.extend(msgs.into_iter().map(|(_, m)| m));
        }
        out
    }

    #[test]
    fn nan_pose_is_dropped_counted_and_flagged_on_the_wire() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let port = peer.local_addr().unwrap().port();
        let mut cfg = SenderConfig::new(format!("udpout:127.0.0.1:{port}").parse().unwrap());
        cfg.rate_hz = 25.0;
        let sender = MavlinkSender::start(cfg).unwrap();
        for k in 0..6 {
            let mut s = sample(k);
            if k == 2 {
                s.t_world_body.translation.vector.x = f64::NAN;
            }
            if k >= 4 {
                s.reset_epoch = 1;
            }
            sender.push_blocking(s);
        }
        let stats = sender.finish();
        assert_eq!(stats.samples_in, 6);
        assert_eq!(stats.dropped_non_finite, 1);
        assert_eq!(stats.pose_samples_sent, 5);
        assert_eq!(stats.reset_counter, 1);
        let odo: Vec<_> = drain(&peer)
            .into_iter()
            .filter_map(|m| match m {
                MavMessage::ODOMETRY(o) => Some(o),
                _ => None,
            })
            .collect();
        let xs: Vec<f32> = odo.iter().map(|o| o.x).collect();
        assert_eq!(
            xs,
            vec![0.0, 1.0, 3.0, 4.0, 5.0],
            "the NaN pose never reaches the wire"
        );
        let quality: Vec<i8> = odo.iter().map(|o| o.quality).collect();
        assert_eq!(quality, vec![100, 100, -1, 100, 100]);
        let resets: Vec<u8> = odo.iter().map(|o| o.reset_counter).collect();
        assert_eq!(resets, vec![0, 0, 0, 1, 1]);
        assert_eq!(odo[0].time_usec, 1_000_000);
    }

    #[test]
    fn heartbeats_and_final_flight_termination() {
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let port = peer.local_addr().unwrap().port();
        let cfg = SenderConfig::new(format!("udpout:127.0.0.1:{port}").parse().unwrap());
        let sender = MavlinkSender::start(cfg).unwrap();
        sender.push_blocking(sample(0));
        let stats = sender.finish();
        let states: Vec<_> = drain(&peer)
            .into_iter()
            .filter_map(|m| match m {
                MavMessage::HEARTBEAT(h) => Some(h.system_status),
                _ => None,
            })
            .collect();
        assert_eq!(states.len() as u64, stats.heartbeats_sent);
        assert_eq!(
            states.first(),
            Some(&mavlink::dialects::common::MavState::MAV_STATE_STANDBY)
        );
        assert_eq!(
            states.last(),
            Some(&mavlink::dialects::common::MavState::MAV_STATE_FLIGHT_TERMINATION)
        );
    }

    #[test]
    fn udpin_waits_for_a_peer_then_answers_timesync() {
        // Find a free port, then listen on it.
        let probe = UdpSocket::bind("127.0.0.1:0").unwrap();
        let port = probe.local_addr().unwrap().port();
        drop(probe);
        let cfg = SenderConfig::new(format!("udpin:127.0.0.1:{port}").parse().unwrap());
        let sender = MavlinkSender::start(cfg).unwrap();
        sender.push_blocking(sample(0)); // nobody to send to yet
        // Wait until the sender thread has handled it (no peer yet), without a time limit.
        while sender.stats().not_sent_no_peer == 0 {
            std::thread::yield_now();
        }
        let fc = UdpSocket::bind("127.0.0.1:0").unwrap();
        // Only so that a missing reply fails the test instead of hanging it.
        fc.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let mut buf = Vec::new();
        let req = mavlink::dialects::common::TIMESYNC_DATA {
            tc1: 0,
            ts1: 777,
            ..Default::default()
        };
        let h = mavlink::MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        mavlink::write_v2_msg(&mut buf, h, &MavMessage::TIMESYNC(req)).unwrap();
        buf.extend_from_slice(b"\xfd\x00garbage");
        fc.send_to(&buf, ("127.0.0.1", port)).unwrap();
        let mut rbuf = [0u8; 512];
        let reply = loop {
            let n = fc.recv(&mut rbuf).unwrap();
            let (msgs, _) = decode_datagram(&rbuf[..n]);
            if let Some(t) = msgs.into_iter().find_map(|(h, m)| match m {
                MavMessage::TIMESYNC(t) => Some((h, t)),
                _ => None,
            }) {
                break t;
            }
        };
        let (h, t) = reply;
        assert_eq!((h.system_id, h.component_id), (1, 197));
        assert_eq!((t.ts1, t.target_system, t.target_component), (777, 1, 1));
        assert!(t.tc1 > 0);
        sender.push_blocking(sample(1));
        let stats = sender.finish();
        assert_eq!(stats.not_sent_no_peer, 1);
        assert_eq!(stats.pose_samples_sent, 1);
        assert_eq!(stats.timesync_replies_sent, 1);
        assert_eq!(stats.rx_bytes_skipped, 9);
    }
}
