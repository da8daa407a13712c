//! The fake GigE Vision camera (`arv-fake-gv-camera-0.8`) over real UDP on loopback, inside a
//! private network namespace this test creates (discovery broadcasts on every interface, so the
//! host's interfaces must not see it). Same checks as the in-process fake, through the network
//! stack, plus: the camera process is killed mid-stream → the driver reports the loss, and
//! reconnects once the camera is back.
//!
//! Needs root (`ip netns`) and Debian's `aravis-tools`; skips with a message otherwise.
#![cfg(feature = "aravis")]

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use vidslam_camera::aravis_backend::AravisCamera;
use vidslam_camera::{Acquisition, Camera, CameraConfig, CameraError, PixelFormat, TimestampLatch};

const FAKE_GV: &str = "arv-fake-gv-camera-0.8";
const SERIAL: &str = "VSGV1";

/// A network namespace with loopback up; deleted on drop (also when the test panics).
struct Netns {
    name: String,
}

impl Netns {
    fn create(tag: &str) -> Result<Self, String> {
        let name = format!("vidslam-cam-{}-{tag}", std::process::id());
        run("ip", &["netns", "add", &name])?;
        let ns = Netns { name };
        run(
            "ip",
            &["netns", "exec", &ns.name, "ip", "link", "set", "lo", "up"],
        )?;
        Ok(ns)
    }

    /// Moves the calling thread into the namespace. Sockets it (and threads it spawns, such as
    /// Aravis's stream and heartbeat threads) creates from now on live there.
    fn enter_this_thread(&self) -> Result<(), String> {
        let path = format!("/run/netns/{}", self.name);
        let file = std::fs::File::open(&path).map_err(|e| format!("{path}: {e}"))?;
        use std::os::fd::AsRawFd;
        // SAFETY: a valid namespace fd; affects only the calling thread.
        let rc = unsafe { libc::setns(file.as_raw_fd(), libc::CLONE_NEWNET) };
        if rc != 0 {
            return Err(format!("setns {path}: {}", std::io::Error::last_os_error()));
        }
        Ok(())
    }

    /// Starts the fake GigE camera listening on 127.0.0.1 in the namespace.
    fn start_camera(&self, extra_args: &[&str]) -> Result<FakeGv, String> {
        let child = Command::new("ip")
            .args([
                "netns",
                "exec",
                &self.name,
                FAKE_GV,
                "-i",
                "127.0.0.1",
                "-s",
                SERIAL,
            ])
            .args(extra_args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("spawn {FAKE_GV}: {e}"))?;
        Ok(FakeGv { child: Some(child) })
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = run("ip", &["netns", "del", &self.name]);
    }
}

/// The fake camera process (`ip netns exec` execs into it, so this is the camera's PID).
struct FakeGv {
    child: Option<Child>,
}

impl FakeGv {
    fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

impl Drop for FakeGv {
    fn drop(&mut self) {
        self.kill();
    }
}

fn run(cmd: &str, args: &[&str]) -> Result<(), String> {
    let out = Command::new(cmd)
        .args(args)
        .output()
        .map_err(|e| format!("{cmd}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{cmd} {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    Ok(())
}

fn have(cmd: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {cmd}")])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Opens the camera by IP, retrying while the process starts up.
fn open_when_up(deadline: Duration) -> AravisCamera {
    let start = Instant::now();
    loop {
        match AravisCamera::open("127.0.0.1") {
            Ok(cam) => return cam,
            Err(e) if start.elapsed() < deadline => {
                let _ = e;
                std::thread::sleep(Duration::from_millis(200));
            }
            Err(e) => panic!("fake GV camera did not come up within {deadline:?}: {e}"),
        }
    }
}

/// The tests of this file run one at a time: three fake cameras pushing 360 KB frames on two
/// cores would starve each other's pacing threads.
static SERIAL_TESTS: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Creates a namespace for this test, moves the test thread into it and starts the camera;
/// `None` (after printing why) where the peer cannot run. Holds the serialising lock.
fn setup(
    tag: &str,
    extra_args: &[&str],
) -> Option<(std::sync::MutexGuard<'static, ()>, Netns, FakeGv)> {
    let guard = SERIAL_TESTS.lock().unwrap_or_else(|e| e.into_inner());
    if !have(FAKE_GV) || !have("ip") {
        eprintln!("SKIP: {FAKE_GV} or ip(8) not installed (Debian: aravis-tools iproute2)");
        return None;
    }
    let ns = match Netns::create(tag) {
        Ok(ns) => ns,
        Err(e) => {
            eprintln!("SKIP: cannot create a network namespace (needs root): {e}");
            return None;
        }
    };
    ns.enter_this_thread().expect("enter namespace");
    let fake = ns.start_camera(extra_args).expect("start fake camera");
    Some((guard, ns, fake))
}

#[test]
fn fake_gige_camera_over_udp_streams_survives_a_kill_and_reconnects() {
    let Some((_serial, ns, mut fake)) = setup("kill", &[]) else {
        return;
    };
    let mut cam = open_when_up(Duration::from_secs(10));
    let info = cam.info().clone();
    eprintln!("info: {info:?}");
    assert_eq!(info.protocol, "GigEVision");
    assert_eq!(info.model, "Fake");

    // Stamped when the fake fills the buffer: end latch.
    let config = CameraConfig {
        timestamp_latch: TimestampLatch::ExposureEnd,
        ..CameraConfig::default()
    };
    let applied = cam
        .configure(&config)
        .expect("configure 752x480 Mono8 20 Hz");
    eprintln!("applied: {applied:?}");
    assert_eq!(
        (applied.width_px, applied.height_px, applied.pixel_format),
        (752, 480, PixelFormat::Mono8)
    );
    cam.start().unwrap();

    let mut device_ns = Vec::new();
    while device_ns.len() < 45 {
        let f = cam
            .next_frame(Duration::from_secs(3))
            .unwrap_or_else(|e| panic!("frame {}: {e}", device_ns.len()));
        assert_eq!(f.pixels().len(), 752 * 480);
        assert!(!f.meta.flags.incomplete);
        device_ns.push(f.meta.device_ns);
    }
    assert!(
        device_ns.windows(2).all(|w| w[1] > w[0]),
        "device timestamps strictly increase"
    );
    // Rate from the median frame interval on the device clock: the fake GigE camera paces its
    // frames with a sleeping thread, so on a loaded machine it occasionally skips a slot; the
    // median is the configured period unless most frames are late. The mean is printed too.
    let mut periods_ns: Vec<i64> = device_ns.windows(2).map(|w| w[1] - w[0]).collect();
    periods_ns.sort_unstable();
    let median_rate_hz = 1e9 / periods_ns[periods_ns.len() / 2] as f64;
    let mean_rate_hz = 44.0 / ((device_ns[44] - device_ns[0]) as f64 * 1e-9);
    let stats = cam.stats();
    eprintln!(
        "GigE fake: 45 frames, device-clock rate {median_rate_hz:.3} Hz (median interval), \
         {mean_rate_hz:.3} Hz (mean), stats {stats:?}"
    );
    assert!(
        (median_rate_hz - 20.0).abs() <= 1.0,
        "measured {median_rate_hz} Hz, configured 20 Hz (±5 %)"
    );

    // Kill the camera mid-stream: the driver must say so, not hang or hand on garbage.
    fake.kill();
    let killed_at = Instant::now();
    let lost = loop {
        match cam.next_frame(Duration::from_millis(500)) {
            Ok(_) => assert!(
                killed_at.elapsed() < Duration::from_secs(1),
                "frames after the kill"
            ),
            Err(CameraError::Timeout { .. }) => {}
            Err(e @ CameraError::Lost { .. }) => break e,
            Err(e) => panic!("unexpected error after kill: {e}"),
        }
        assert!(
            killed_at.elapsed() < Duration::from_secs(15),
            "loss not detected"
        );
    };
    eprintln!("after kill ({:?}): {lost}", killed_at.elapsed());
    assert!(
        lost.to_string().contains("127.0.0.1"),
        "the error names the device: {lost}"
    );
    // While the camera is away, reconnection attempts fail with a clear error.
    let err = cam.next_frame(Duration::from_millis(600)).unwrap_err();
    assert!(matches!(err, CameraError::Reconnecting { .. }), "{err}");

    // The camera returns: the driver reopens and streams again.
    let _fake2 = ns.start_camera(&[]).expect("restart fake camera");
    let back_at = Instant::now();
    let frame = loop {
        match cam.next_frame(Duration::from_millis(600)) {
            Ok(f) => break f,
            Err(e) if e.is_transient() => {
                assert!(
                    back_at.elapsed() < Duration::from_secs(20),
                    "no reconnect: {e}"
                );
            }
            Err(e) => panic!("{e}"),
        }
    };
    eprintln!(
        "reconnected after {:?}, first frame {:?}",
        back_at.elapsed(),
        frame.meta.flags
    );
    assert!(
        frame.meta.flags.dropped_before > 0,
        "frames lost during the outage are reported"
    );
    for _ in 0..5 {
        cam.next_frame(Duration::from_secs(3))
            .expect("frames after reconnect");
    }
    let stats = cam.stats();
    // One kill, so at least one loss, and every loss was followed by a reconnect. On a loaded
    // machine a >1 s scheduling stall during the outage can be declared a second loss of the
    // same outage (seen once with five developers building on 2 cores), hence `>=`.
    assert!(
        stats.lost >= 1 && stats.reconnects == stats.lost,
        "{stats:?}"
    );

    // Stream on past the old device's heartbeat window (its `control-lost` comes at most ~8.5 s
    // after the kill in libaravis-0.8, while the driver still holds that device to release it
    // safely): the late signal must not mark the new connection lost, and the old device's
    // release must not take the process down.
    let streaming_since = Instant::now();
    while killed_at.elapsed() < Duration::from_secs(12) {
        cam.next_frame(Duration::from_secs(3))
            .unwrap_or_else(|e| panic!("{:?} after the reconnect: {e}", streaming_since.elapsed()));
    }
    let after = cam.stats();
    eprintln!("{:?} after the kill: {after:?}", killed_at.elapsed());
    assert_eq!(
        (after.lost, after.reconnects),
        (stats.lost, stats.reconnects),
        "the old device's late control-lost was taken for a loss of the new connection"
    );
    cam.stop().unwrap();
}

#[test]
fn lost_packets_without_resend_make_incomplete_frames_that_are_counted_never_delivered() {
    // The fake drops 0.3 % of its GVSP packets; with resend off those frames stay incomplete.
    let Some((_serial, _ns, _fake)) = setup("loss", &["-r", "3"]) else {
        return;
    };
    let mut cam = open_when_up(Duration::from_secs(10));
    cam.set_gige_packet_resend(false);
    let config = CameraConfig {
        timestamp_latch: TimestampLatch::ExposureEnd,
        ..CameraConfig::default()
    };
    cam.configure(&config).unwrap();
    cam.start().unwrap();
    let mut reported_drops = 0u64;
    let mut good = 0;
    let started = Instant::now();
    while good < 15 {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "too few complete frames: {:?}",
            cam.stats()
        );
        match cam.next_frame(Duration::from_secs(3)) {
            Ok(f) => {
                assert!(
                    !f.meta.flags.incomplete,
                    "incomplete frames are not delivered by default"
                );
                // Drops before the first frame are reported on it too, so totals compare.
                reported_drops += f.meta.flags.dropped_before as u64;
                good += 1;
            }
            Err(CameraError::Timeout { .. }) => {}
            Err(e) => panic!("{e}"),
        }
    }
    let s = cam.stats();
    eprintln!("0.3 % packet loss, no resend: {s:?}");
    assert!(
        s.incomplete > 0,
        "some frames must have lost packets: {s:?}"
    );
    assert_eq!(s.delivered, 15);
    assert_eq!(s.pool_exhausted, 0);
    assert_eq!(
        reported_drops,
        s.incomplete + s.missing,
        "every lost frame is reported on a delivered one"
    );
    cam.stop().unwrap();
}

#[test]
fn software_trigger_gives_one_frame_per_trigger_and_silence_is_not_a_loss() {
    let Some((_serial, _ns, _fake)) = setup("trig", &[]) else {
        return;
    };
    let mut cam = open_when_up(Duration::from_secs(10));
    let config = CameraConfig {
        acquisition: Acquisition::ExternalTrigger {
            source: "Software".into(),
            expected_rate_hz: 20.0,
        },
        timestamp_latch: TimestampLatch::ExposureEnd,
        ..CameraConfig::default()
    };
    let applied = cam.configure(&config).unwrap();
    eprintln!("trigger mode: {applied:?}");
    cam.start().unwrap();
    // No trigger, no frame.
    let err = cam.next_frame(Duration::from_millis(500)).unwrap_err();
    assert!(matches!(err, CameraError::Timeout { .. }), "{err}");
    let mut ids = Vec::new();
    for _ in 0..3 {
        cam.software_trigger().unwrap();
        let f = cam
            .next_frame(Duration::from_secs(3))
            .expect("a frame per trigger");
        assert_eq!(f.pixels().len(), 752 * 480);
        ids.push(f.meta.frame_id);
    }
    assert!(
        ids.windows(2).all(|w| w[1] == w[0] + 1),
        "consecutive frames: {ids:?}"
    );
    // Silent for longer than the free-running loss timeout (1 s): not a loss in trigger mode.
    let err = cam.next_frame(Duration::from_millis(1500)).unwrap_err();
    assert!(matches!(err, CameraError::Timeout { .. }), "{err}");
    assert_eq!(cam.stats().lost, 0);
    cam.stop().unwrap();
}
