//! A fake 3DM-GX4-25 behind a pseudo-terminal pair (openpty). The driver under test opens a
//! stable symlink to the slave side (like udev's `/dev/serial/by-id/...`); the fake thread owns
//! the master side: it answers commands per the protocol (ACK/NACK + reply data) and, once
//! configured and resumed, streams recorded IMU packets in real time (paced by their GPS
//! timestamps). Optional: garbage between packets, and a disconnect (master closed, a new pty
//! appears behind the same symlink) after a given packet.

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::openpty;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use vidslam_mip::command::{Command, Function};
use vidslam_mip::descriptor::imu as imu_desc;
use vidslam_mip::imu::ImuData;
use vidslam_mip::reply::{Ack, AckCode, DeviceInfo, Reply, ReplyData};
use vidslam_mip::{Decoder, Packet};

/// What the fake does.
#[derive(Clone, Debug, Default)]
pub struct Script {
    /// IMU packets (complete, checksummed) streamed after Resume.
    pub packets: Vec<Vec<u8>>,
    /// Inject a garbage burst after every n-th packet.
    pub garbage_every: Option<usize>,
    /// Close the pty after this many packets and come back on a new one.
    pub disconnect_after: Option<usize>,
}

/// What the fake saw and did.
#[derive(Clone, Debug, Default)]
pub struct Log {
    pub commands: Vec<Command>,
    pub connections: usize,
    pub packets_sent: usize,
    pub garbage_bytes: usize,
}

pub struct FakeGx4 {
    pub link: PathBuf,
    dir: PathBuf,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Log>>,
}

struct Pty {
    master: File,
    _slave: OwnedFd,
}

fn new_pty(link: &Path) -> Pty {
    let pty = openpty(None, None).expect("openpty");
    let mut t = tcgetattr(&pty.slave).expect("tcgetattr");
    cfmakeraw(&mut t);
    tcsetattr(&pty.slave, SetArg::TCSANOW, &t).expect("tcsetattr");
    let name = nix::unistd::ttyname(&pty.slave).expect("ttyname");
    // Atomic re-point of the link, as udev does.
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&name, &tmp).expect("symlink");
    std::fs::rename(&tmp, link).expect("rename symlink");
    Pty {
        master: File::from(pty.master),
        _slave: pty.slave,
    }
}

/// Deterministic garbage: random bytes, a fake header with a long length, stray sync bytes.
fn garbage(seed: &mut u64) -> Vec<u8> {
    let mut next = || {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 33) as u8
    };
    let mut g = Vec::new();
    for _ in 0..(next() % 7) {
        g.push(next());
    }
    g.extend_from_slice(&[0x75, 0x65, 0x80, 0x40 + next() % 0x80]);
    for _ in 0..(next() % 11) {
        g.push(next());
    }
    g.push(0x75);
    g
}

impl FakeGx4 {
    pub fn start(script: Script) -> Self {
        static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "vidslam-fake-gx4-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let link = dir.join("ttyGX4");
        let pty = new_pty(&link);
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let link2 = link.clone();
        let handle = std::thread::spawn(move || run(script, pty, &link2, &stop2));
        FakeGx4 {
            link,
            dir,
            stop,
            handle: Some(handle),
        }
    }

    pub fn path(&self) -> &str {
        self.link.to_str().unwrap()
    }

    /// Stops the fake and returns its log.
    pub fn finish(mut self) -> Log {
        self.stop.store(true, Ordering::Relaxed);
        self.handle.take().unwrap().join().unwrap()
    }
}

impl Drop for FakeGx4 {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[derive(Default)]
struct DeviceState {
    format_set: bool,
    stream_enabled: bool,
    resumed: bool,
}

fn answer(cmd: &Command, state: &mut DeviceState) -> Reply {
    let ok = |data| Reply {
        descriptor_set: cmd.descriptor_set(),
        ack: Ack {
            command: cmd.field_descriptor(),
            code: AckCode::Ok,
        },
        data,
    };
    let nack = |code| Reply {
        descriptor_set: cmd.descriptor_set(),
        ack: Ack {
            command: cmd.field_descriptor(),
            code,
        },
        data: None,
    };
    match cmd {
        Command::SetIdle => {
            state.resumed = false;
            ok(None)
        }
        Command::Resume => {
            state.resumed = true;
            ok(None)
        }
        Command::GetDeviceInfo => {
            let mut info = DeviceInfo {
                firmware_version: 1102,
                ..Default::default()
            };
            info.model_name.push_str("3DM-GX4-25").unwrap();
            info.serial_number.push_str("FAKE-0001").unwrap();
            ok(Some(ReplyData::DeviceInfo(info)))
        }
        Command::GetImuBaseRate => ok(Some(ReplyData::ImuBaseRate { rate_hz: 1000 })),
        Command::ImuMessageFormat {
            function: Function::Apply,
            descriptors,
        } => {
            let valid = descriptors.iter().all(|d| {
                d.decimation > 0
                    && vidslam_mip::descriptor::is_known_field(imu_desc::SET, d.descriptor)
            });
            if valid {
                state.format_set = true;
                ok(None)
            } else {
                nack(AckCode::InvalidParameter)
            }
        }
        Command::EnableStream { enable, device, .. } => {
            state.stream_enabled = *enable;
            ok(Some(ReplyData::StreamEnabled {
                device: *device,
                enabled: *enable,
            }))
        }
        Command::UartBaud {
            function: Function::Apply,
            baud,
        } if ![115_200, 230_400, 460_800, 921_600].contains(baud) => {
            nack(AckCode::InvalidParameter)
        }
        _ => ok(None),
    }
}

fn gps_ns(packet: &[u8]) -> i64 {
    let p = Packet::new_checked(packet).unwrap();
    ImuData::parse(&p)
        .unwrap()
        .gps_time
        .unwrap()
        .gps_ns()
        .unwrap()
}

fn run(script: Script, mut pty: Pty, link: &Path, stop: &AtomicBool) -> Log {
    let mut log = Log {
        connections: 1,
        ..Default::default()
    };
    let mut state = DeviceState::default();
    let mut decoder = Decoder::new();
    let mut next = 0usize;
    let mut seed = 0x5EED_u64;
    let mut disconnected = false;
    // Real-time pacing: packet i goes out at stream_start + (t_i − t_first).
    let mut stream_start: Option<(Instant, i64)> = None;
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        // Commands.
        let readable = {
            let mut fds = [PollFd::new(pty.master.as_fd(), PollFlags::POLLIN)];
            poll(&mut fds, PollTimeout::from(1u8)).unwrap_or(0) > 0
                && fds[0]
                    .revents()
                    .is_some_and(|r| r.contains(PollFlags::POLLIN))
        };
        if readable && let Ok(n) = pty.master.read(&mut buf) {
            let mut replies = Vec::new();
            decoder.feed(&buf[..n], |p| {
                if let Ok(cmd) = Command::parse(&p) {
                    replies.push(answer(&cmd, &mut state));
                    log.commands.push(cmd);
                }
            });
            for r in replies {
                let mut out = [0u8; 261];
                let n = r.emit(&mut out).unwrap();
                pty.master.write_all(&out[..n]).unwrap();
            }
        }
        let streaming = state.resumed && state.stream_enabled && state.format_set;
        if !streaming {
            stream_start = None;
            continue;
        }
        // Data, paced.
        while next < script.packets.len() {
            let t = gps_ns(&script.packets[next]);
            let (t0_host, t0_dev) = *stream_start.get_or_insert((Instant::now(), t));
            let due = t0_host + Duration::from_nanos((t - t0_dev).max(0) as u64);
            if Instant::now() < due {
                break;
            }
            pty.master.write_all(&script.packets[next]).unwrap();
            next += 1;
            log.packets_sent += 1;
            if let Some(k) = script.garbage_every
                && next % k == 0
                && next + 4 < script.packets.len()
            {
                let g = garbage(&mut seed);
                pty.master.write_all(&g).unwrap();
                log.garbage_bytes += g.len();
            }
            if script.disconnect_after == Some(next) && !disconnected {
                disconnected = true;
                // Let the driver drain what is in flight, then unplug: both ends of the old pty
                // close, and a new one appears behind the link a little later.
                std::thread::sleep(Duration::from_millis(300));
                drop(pty);
                std::thread::sleep(Duration::from_millis(150));
                pty = new_pty(link);
                log.connections += 1;
                state = DeviceState::default();
                decoder = Decoder::new();
                stream_start = None;
                break;
            }
        }
    }
    log
}
