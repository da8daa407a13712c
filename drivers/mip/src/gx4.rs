//! The 3DM-GX4-25 serial driver: open, configure, stream [`ImuSample`]s, reopen, stop.
//!
//! ```no_run
//! use vidslam_mip::gx4::Gx4;
//! use vidslam_mip::descriptor::imu;
//! let mut dev = Gx4::open("/dev/ttyACM0", 921_600)?;
//! dev.configure(200, &[imu::SCALED_ACCEL, imu::SCALED_GYRO, imu::GPS_TIMESTAMP])?;
//! let sample = dev.next_sample()?;
//! dev.stop()?;
//! # Ok::<(), vidslam_mip::gx4::Gx4Error>(())
//! ```
//!
//! Failure handling: a read error (unplug: the tty returns EIO/hang-up), end of file, or no IMU
//! packet for [`Gx4Options::stream_timeout`] while streaming closes the port and reopens the same
//! path (a udev `/dev/serial/by-id/...` link follows a re-enumerated device) until
//! [`Gx4Options::reopen_timeout`]; the last configuration is applied again. Each event is
//! counted in [`Gx4Counters`]. Garbage on the line is skipped by the decoder and counted.

use crate::command::{Command, DescriptorRate, DescriptorRates, Function, STREAM_IMU};
use crate::decoder::{Decoder, DecoderStats};
use crate::descriptor::imu as imu_desc;
use crate::imu::{ImuData, packet_len_for};
use crate::reply::{AckCode, DeviceInfo, Reply, ReplyData};
use crate::sample::{ImuSample, SampleTimer, TimePreference, host_monotonic_ns};
use crate::wire::MAX_PACKET_LEN;
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::time::{Duration, Instant};
use vidslam_timesync::{ClockModel, ClockModelConfig};

/// Standard UART rates the GX4 supports, bit/s.
pub const STANDARD_BAUDS: [u32; 4] = [115_200, 230_400, 460_800, 921_600];

/// Bits on the line per byte with 8N1 framing (start + 8 data + stop).
pub const BITS_PER_BYTE_8N1: u64 = 10;

/// Driver tuning. The defaults suit a GX4 on USB or a 921600-baud UART.
#[derive(Clone, Debug)]
pub struct Gx4Options {
    /// How long to wait for each command's ACK/NACK.
    pub command_timeout: Duration,
    /// Extra attempts after a command got no reply.
    pub command_retries: u32,
    /// Granularity of blocking reads.
    pub read_timeout: Duration,
    /// No IMU packet for this long while streaming counts as a failure (then reopen).
    pub stream_timeout: Duration,
    /// Reopen automatically after a failure while streaming.
    pub auto_reopen: bool,
    /// Keep trying to reopen this long before giving up.
    pub reopen_timeout: Duration,
    /// Device timestamp to use.
    pub time_preference: TimePreference,
    /// Device → host clock model parameters.
    pub clock: ClockModelConfig,
}

impl Default for Gx4Options {
    fn default() -> Self {
        Gx4Options {
            command_timeout: Duration::from_millis(250),
            command_retries: 3,
            read_timeout: Duration::from_millis(20),
            stream_timeout: Duration::from_secs(1),
            auto_reopen: true,
            reopen_timeout: Duration::from_secs(10),
            time_preference: TimePreference::Auto,
            clock: ClockModelConfig::default(),
        }
    }
}

/// The stream format applied by [`Gx4::configure`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StreamFormat {
    pub rate_hz: u32,
    pub base_rate_hz: u16,
    pub decimation: u16,
    pub fields: Vec<u8>,
    /// Bytes per IMU packet.
    pub packet_len: usize,
}

/// Event counters; they only grow (decoder counters accumulate over reopens).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Gx4Counters {
    pub samples: u64,
    /// IMU packets that did not make a sample (missing field, NaN, malformed).
    pub bad_imu_packets: u64,
    /// Valid packets that are neither IMU data nor a reply we waited for.
    pub other_packets: u64,
    pub command_retries: u64,
    pub stream_timeouts: u64,
    pub io_errors: u64,
    pub reopens: u64,
    pub decoder: DecoderStats,
}

/// What went wrong, with the port path and what the driver was doing.
#[derive(Debug, thiserror::Error)]
pub enum Gx4Error {
    #[error("cannot open {path} at {baud} baud: {source}")]
    Open {
        path: String,
        baud: u32,
        source: serialport::Error,
    },
    #[error("I/O error on {path} while {doing}: {source}")]
    Io {
        path: String,
        doing: &'static str,
        source: std::io::Error,
    },
    #[error("{path}: no reply to {command:?} after {attempts} attempts of {timeout_ms} ms each")]
    NoReply {
        path: String,
        command: Command,
        attempts: u32,
        timeout_ms: u128,
    },
    #[error("{path}: device refused {command:?}: NACK code {code} ({meaning})")]
    Nack {
        path: String,
        command: Command,
        code: u8,
        meaning: &'static str,
    },
    #[error("{path}: the reply to {command:?} lacks the expected data field")]
    BadReply { path: String, command: Command },
    #[error(
        "{packet_len}-byte IMU packets at {rate_hz} Hz need {needed_bps} bit/s on the line \
         (8N1: 10 bits per byte) but {baud} baud carries only {baud} bit/s; {advice}"
    )]
    LineRate {
        packet_len: usize,
        rate_hz: u32,
        needed_bps: u64,
        baud: u32,
        advice: String,
    },
    #[error("{path}: {rate_hz} Hz cannot be made from the {base_rate_hz} Hz IMU base rate ({why})")]
    BadRate {
        path: String,
        rate_hz: u32,
        base_rate_hz: u16,
        why: &'static str,
    },
    #[error("invalid field list {fields:02x?}: {why}")]
    BadFields { fields: Vec<u8>, why: &'static str },
    #[error("{path}: no IMU data for {waited_ms} ms while streaming")]
    StreamTimeout { path: String, waited_ms: u128 },
    #[error("{path}: lost the device ({cause}); could not reopen it within {waited_ms} ms: {last}")]
    Disconnected {
        path: String,
        cause: String,
        waited_ms: u128,
        last: String,
    },
    #[error("{path}: {what}")]
    Protocol {
        path: String,
        what: crate::wire::Error,
    },
}

/// Refuses a baud/rate/field combination whose packets cannot fit the line rate.
pub fn check_line_rate(baud: u32, rate_hz: u32, fields: &[u8]) -> Result<(), Gx4Error> {
    let packet_len = packet_len_for(fields);
    let needed_bps = packet_len as u64 * BITS_PER_BYTE_8N1 * rate_hz as u64;
    if needed_bps <= baud as u64 {
        return Ok(());
    }
    let advice = match STANDARD_BAUDS.iter().find(|&&b| b as u64 >= needed_bps) {
        Some(b) => format!("use at least {b} baud or a lower rate"),
        None => format!(
            "no standard baud rate suffices (max {}); lower the rate or the field list",
            STANDARD_BAUDS.last().copied().unwrap_or(0)
        ),
    };
    Err(Gx4Error::LineRate {
        packet_len,
        rate_hz,
        needed_bps,
        baud,
        advice,
    })
}

/// A 3DM-GX4-25 on a serial port. See the module docs.
pub struct Gx4 {
    path: String,
    baud: u32,
    opts: Gx4Options,
    port: Option<Box<dyn serialport::SerialPort>>,
    decoder: Decoder,
    /// Decoder counters of ports closed before.
    decoder_before: DecoderStats,
    timer: SampleTimer,
    counters: Gx4Counters,
    samples: VecDeque<ImuSample>,
    replies: VecDeque<Reply>,
    format: Option<(u32, Vec<u8>)>,
    streaming: bool,
    last_data: Instant,
    read_buf: Vec<u8>,
    raw_sink: Option<Box<dyn Write + Send>>,
}

impl std::fmt::Debug for Gx4 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gx4")
            .field("path", &self.path)
            .field("baud", &self.baud)
            .field("streaming", &self.streaming)
            .field("counters", &self.counters())
            .finish_non_exhaustive()
    }
}

fn open_port(
    path: &str,
    baud: u32,
    read_timeout: Duration,
) -> Result<Box<dyn serialport::SerialPort>, Gx4Error> {
    serialport::new(path, baud)
        .timeout(read_timeout)
        .open()
        .map_err(|source| Gx4Error::Open {
            path: path.to_string(),
            baud,
            source,
        })
}

impl Gx4 {
    /// Opens the port (8N1, no flow control) with default [`Gx4Options`]. Does not talk to the
    /// device yet.
    pub fn open(path: &str, baud: u32) -> Result<Self, Gx4Error> {
        Self::open_with_options(path, baud, Gx4Options::default())
    }

    /// [`Gx4::open`] with explicit options.
    pub fn open_with_options(path: &str, baud: u32, opts: Gx4Options) -> Result<Self, Gx4Error> {
        let port = open_port(path, baud, opts.read_timeout)?;
        Ok(Gx4 {
            path: path.to_string(),
            baud,
            timer: SampleTimer::new(opts.time_preference, opts.clock),
            opts,
            port: Some(port),
            decoder: Decoder::new(),
            decoder_before: DecoderStats::default(),
            counters: Gx4Counters::default(),
            samples: VecDeque::new(),
            replies: VecDeque::new(),
            format: None,
            streaming: false,
            last_data: Instant::now(),
            read_buf: vec![0; 4096],
            raw_sink: None,
        })
    }

    /// Port path.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Every byte read from the port from now on is also written to `sink` (for recordings).
    pub fn set_raw_sink(&mut self, sink: Box<dyn Write + Send>) {
        self.raw_sink = Some(sink);
    }

    /// Counters so far.
    pub fn counters(&self) -> Gx4Counters {
        let mut c = self.counters;
        let d = self.decoder.stats();
        let b = &self.decoder_before;
        c.decoder = DecoderStats {
            bytes_in: b.bytes_in + d.bytes_in,
            packets: b.packets + d.packets,
            bytes_skipped: b.bytes_skipped + d.bytes_skipped,
            checksum_failures: b.checksum_failures + d.checksum_failures,
            malformed_packets: b.malformed_packets + d.malformed_packets,
            unknown_sets: b.unknown_sets + d.unknown_sets,
            unknown_fields: b.unknown_fields + d.unknown_fields,
        };
        c
    }

    /// The device → host clock model.
    pub fn clock(&self) -> &ClockModel {
        self.timer.clock()
    }

    /// Sends a command and waits for its ACK (with timeout and retries); returns the reply.
    pub fn command(&mut self, command: &Command) -> Result<Reply, Gx4Error> {
        let mut buf = [0u8; MAX_PACKET_LEN];
        let n = command.emit(&mut buf).map_err(|what| self.protocol(what))?;
        let attempts = self.opts.command_retries + 1;
        for attempt in 0..attempts {
            if attempt > 0 {
                self.counters.command_retries += 1;
            }
            self.replies.clear();
            self.write(buf.get(..n).unwrap_or(&[]), "sending a command")?;
            let deadline = Instant::now() + self.opts.command_timeout;
            while Instant::now() < deadline {
                let set = command.descriptor_set();
                let field = command.field_descriptor();
                if let Some(reply) = self
                    .replies
                    .iter()
                    .position(|r| r.descriptor_set == set && r.ack.command == field)
                    .and_then(|i| self.replies.remove(i))
                {
                    if reply.ack.code != AckCode::Ok {
                        return Err(Gx4Error::Nack {
                            path: self.path.clone(),
                            command: command.clone(),
                            code: reply.ack.code.to_u8(),
                            meaning: reply.ack.code.describe(),
                        });
                    }
                    return Ok(reply);
                }
                self.read_some("waiting for a command reply")?;
            }
        }
        Err(Gx4Error::NoReply {
            path: self.path.clone(),
            command: command.clone(),
            attempts,
            timeout_ms: self.opts.command_timeout.as_millis(),
        })
    }

    /// Ping: is the device there?
    pub fn ping(&mut self) -> Result<(), Gx4Error> {
        self.command(&Command::Ping).map(|_| ())
    }

    /// Model, serial number and firmware version.
    pub fn device_info(&mut self) -> Result<DeviceInfo, Gx4Error> {
        match self.command(&Command::GetDeviceInfo)?.data {
            Some(ReplyData::DeviceInfo(info)) => Ok(info),
            _ => Err(self.bad_reply(Command::GetDeviceInfo)),
        }
    }

    /// The IMU base rate, Hz (1000 on the GX4-25).
    pub fn imu_base_rate_hz(&mut self) -> Result<u16, Gx4Error> {
        match self.command(&Command::GetImuBaseRate)?.data {
            Some(ReplyData::ImuBaseRate { rate_hz }) => Ok(rate_hz),
            _ => Err(self.bad_reply(Command::GetImuBaseRate)),
        }
    }

    /// Configures and starts the IMU stream: idle → read base rate → message format with the
    /// decimation for `rate_hz` → enable the IMU stream → resume. Each step waits for its ACK.
    /// Refuses combinations the line rate cannot carry before talking to the device.
    pub fn configure(&mut self, rate_hz: u32, fields: &[u8]) -> Result<StreamFormat, Gx4Error> {
        if fields.is_empty() || fields.len() > crate::command::MAX_FORMAT_DESCRIPTORS {
            return Err(Gx4Error::BadFields {
                fields: fields.to_vec(),
                why: "between 1 and 16 IMU field descriptors are needed",
            });
        }
        if let Some(&f) = fields
            .iter()
            .find(|&&f| !crate::descriptor::is_known_field(imu_desc::SET, f))
        {
            return Err(Gx4Error::BadFields {
                fields: fields.to_vec(),
                why: if f == 0 {
                    "descriptor 0 is not an IMU field"
                } else {
                    "contains a descriptor this driver does not decode"
                },
            });
        }
        check_line_rate(self.baud, rate_hz, fields)?;
        self.streaming = false;
        self.command(&Command::SetIdle)?;
        let base_rate_hz = self.imu_base_rate_hz()?;
        let bad_rate = |why| Gx4Error::BadRate {
            path: self.path.clone(),
            rate_hz,
            base_rate_hz,
            why,
        };
        if rate_hz == 0 || rate_hz > base_rate_hz as u32 {
            return Err(bad_rate("the rate must be between 1 Hz and the base rate"));
        }
        if base_rate_hz as u32 % rate_hz != 0 {
            return Err(bad_rate("the rate must divide the base rate evenly"));
        }
        let decimation = (base_rate_hz as u32 / rate_hz) as u16;
        let mut descriptors = DescriptorRates::new();
        for &descriptor in fields {
            // Capacity checked above.
            let _ = descriptors.push(DescriptorRate {
                descriptor,
                decimation,
            });
        }
        self.command(&Command::ImuMessageFormat {
            function: Function::Apply,
            descriptors,
        })?;
        self.command(&Command::EnableStream {
            function: Function::Apply,
            device: STREAM_IMU,
            enable: true,
        })?;
        self.command(&Command::Resume)?;
        self.format = Some((rate_hz, fields.to_vec()));
        self.streaming = true;
        self.last_data = Instant::now();
        Ok(StreamFormat {
            rate_hz,
            base_rate_hz,
            decimation,
            fields: fields.to_vec(),
            packet_len: packet_len_for(fields),
        })
    }

    /// The next IMU sample, blocking. While streaming, failures (unplug, timeout) trigger a
    /// reopen + reconfigure if [`Gx4Options::auto_reopen`]; only a failed reopen is returned.
    pub fn next_sample(&mut self) -> Result<ImuSample, Gx4Error> {
        loop {
            if let Some(s) = self.next_sample_until(None)? {
                return Ok(s);
            }
        }
    }

    /// Like [`Gx4::next_sample`], but returns `Ok(None)` once `deadline` has passed without a
    /// sample (checked at every read timeout, so at most [`Gx4Options::read_timeout`] late, plus
    /// the time of a reopen in progress).
    pub fn next_sample_before(&mut self, deadline: Instant) -> Result<Option<ImuSample>, Gx4Error> {
        self.next_sample_until(Some(deadline))
    }

    fn next_sample_until(
        &mut self,
        deadline: Option<Instant>,
    ) -> Result<Option<ImuSample>, Gx4Error> {
        loop {
            if let Some(s) = self.samples.pop_front() {
                return Ok(Some(s));
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Ok(None);
            }
            let failure = match self.read_some("reading the IMU stream") {
                Ok(true) => None,
                Ok(false) => {
                    let waited = self.last_data.elapsed();
                    if self.streaming && waited > self.opts.stream_timeout {
                        self.counters.stream_timeouts += 1;
                        Some(Gx4Error::StreamTimeout {
                            path: self.path.clone(),
                            waited_ms: waited.as_millis(),
                        })
                    } else {
                        None
                    }
                }
                Err(e) => {
                    self.counters.io_errors += 1;
                    Some(e)
                }
            };
            if let Some(e) = failure {
                if self.opts.auto_reopen && self.format.is_some() {
                    self.reopen(e)?;
                } else {
                    return Err(e);
                }
            }
        }
    }

    /// Samples already decoded and waiting (no I/O).
    pub fn take_queued(&mut self) -> Option<ImuSample> {
        self.samples.pop_front()
    }

    /// Stops the stream (set idle, acknowledged); samples still queued are kept.
    pub fn stop(&mut self) -> Result<(), Gx4Error> {
        self.streaming = false;
        self.format = None;
        self.command(&Command::SetIdle).map(|_| ())
    }

    /// Closes the port and opens the same path again until it works or the reopen timeout
    /// passes; reapplies the stream format.
    fn reopen(&mut self, cause: Gx4Error) -> Result<(), Gx4Error> {
        let started = Instant::now();
        let mut backoff = Duration::from_millis(20);
        loop {
            self.port = None;
            self.retire_decoder();

            let attempt = open_port(&self.path, self.baud, self.opts.read_timeout).and_then(|p| {
                self.port = Some(p);
                self.counters.reopens += 1;
                match self.format.clone() {
                    Some((rate_hz, fields)) => self.configure(rate_hz, &fields).map(|_| ()),
                    None => Ok(()),
                }
            });
            let last = match attempt {
                Ok(()) => return Ok(()),
                Err(e) => e,
            };
            if started.elapsed() > self.opts.reopen_timeout {
                return Err(Gx4Error::Disconnected {
                    path: self.path.clone(),
                    cause: cause.to_string(),
                    waited_ms: started.elapsed().as_millis(),
                    last: last.to_string(),
                });
            }
            std::thread::sleep(backoff);
            backoff = (backoff * 2).min(Duration::from_millis(500));
        }
    }

    /// One read with the port timeout; decodes what arrived. `Ok(false)` on timeout.
    fn read_some(&mut self, doing: &'static str) -> Result<bool, Gx4Error> {
        let port = self.port.as_mut().ok_or_else(|| Gx4Error::Io {
            path: self.path.clone(),
            doing,
            source: std::io::Error::new(std::io::ErrorKind::NotConnected, "port is closed"),
        })?;
        let n = match port.read(&mut self.read_buf) {
            Ok(0) => {
                return Err(Gx4Error::Io {
                    path: self.path.clone(),
                    doing,
                    source: std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        "end of file (device gone)",
                    ),
                });
            }
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return Ok(false),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return Ok(false),
            Err(source) => {
                return Err(Gx4Error::Io {
                    path: self.path.clone(),
                    doing,
                    source,
                });
            }
        };
        let host_receive_ns = host_monotonic_ns();
        let bytes = self.read_buf.get(..n).unwrap_or(&[]);
        if let Some(sink) = self.raw_sink.as_mut() {
            sink.write_all(bytes)
                .and_then(|()| sink.flush())
                .map_err(|source| Gx4Error::Io {
                    path: self.path.clone(),
                    doing: "writing the raw recording",
                    source,
                })?;
        }
        let mut input = bytes;
        while let Some(packet) = self.decoder.pull(&mut input) {
            if packet.descriptor_set() == imu_desc::SET {
                match ImuData::parse(&packet)
                    .ok()
                    .and_then(|d| self.timer.sample(&d, host_receive_ns).ok())
                {
                    Some(s) => {
                        self.counters.samples += 1;
                        self.samples.push_back(s);
                        self.last_data = Instant::now();
                    }
                    None => self.counters.bad_imu_packets += 1,
                }
            } else if let Ok(reply) = Reply::parse(&packet) {
                if self.replies.len() >= 16 {
                    self.replies.pop_front();
                }
                self.replies.push_back(reply);
            } else {
                self.counters.other_packets += 1;
            }
        }
        Ok(true)
    }

    fn write(&mut self, bytes: &[u8], doing: &'static str) -> Result<(), Gx4Error> {
        let path = &self.path;
        let port = self.port.as_mut().ok_or_else(|| Gx4Error::Io {
            path: path.clone(),
            doing,
            source: std::io::Error::new(std::io::ErrorKind::NotConnected, "port is closed"),
        })?;
        port.write_all(bytes)
            .and_then(|()| port.flush())
            .map_err(|source| Gx4Error::Io {
                path: path.clone(),
                doing,
                source,
            })
    }

    /// Adds the decoder's counters (a partial packet counts as skipped) to the totals and starts
    /// a fresh decoder for a new connection.
    fn retire_decoder(&mut self) {
        self.decoder.reset();
        let d = *self.decoder.stats();
        let b = &mut self.decoder_before;
        b.bytes_in += d.bytes_in;
        b.packets += d.packets;
        b.bytes_skipped += d.bytes_skipped;
        b.checksum_failures += d.checksum_failures;
        b.malformed_packets += d.malformed_packets;
        b.unknown_sets += d.unknown_sets;
        b.unknown_fields += d.unknown_fields;
        self.decoder = Decoder::new();
    }

    fn bad_reply(&self, command: Command) -> Gx4Error {
        Gx4Error::BadReply {
            path: self.path.clone(),
            command,
        }
    }

    fn protocol(&self, what: crate::wire::Error) -> Gx4Error {
        Gx4Error::Protocol {
            path: self.path.clone(),
            what,
        }
    }
}

impl Drop for Gx4 {
    /// Best effort: leave the device idle (no wait for the ACK).
    fn drop(&mut self) {
        if self.streaming {
            let mut buf = [0u8; MAX_PACKET_LEN];
            if let Ok(n) = Command::SetIdle.emit(&mut buf)
                && let Some(port) = self.port.as_mut()
            {
                let _ = port.write_all(buf.get(..n).unwrap_or(&[]));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_rate_check_refuses_1khz_at_460800() {
        let fields = [
            imu_desc::SCALED_ACCEL,
            imu_desc::SCALED_GYRO,
            imu_desc::GPS_TIMESTAMP,
        ];
        assert_eq!(packet_len_for(&fields), 48);
        let e = check_line_rate(460_800, 1000, &fields).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("48-byte IMU packets at 1000 Hz need 480000 bit/s"),
            "{msg}"
        );
        assert!(msg.contains("use at least 921600 baud"), "{msg}");
        assert!(check_line_rate(921_600, 1000, &fields).is_ok());
        assert!(check_line_rate(115_200, 200, &fields).is_ok());
        // All six GX4 fields: 82 B × 10 bit × 1 kHz = 820 kbit/s fits 921600 baud.
        assert!(check_line_rate(921_600, 1000, &[4, 5, 7, 8, 0x0E, 0x12]).is_ok());
        assert!(
            check_line_rate(921_600, 1000, &[4; 12])
                .unwrap_err()
                .to_string()
                .contains("no standard baud rate suffices")
        );
    }
}
