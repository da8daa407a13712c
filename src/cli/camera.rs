//! `vidslam camera`: list devices, describe one, record frames losslessly.

use anyhow::{Context, bail};
use clap::{Args, Subcommand, ValueEnum};
use std::path::PathBuf;
use std::time::{Duration, Instant};
use vidslam_camera::{
    Acquisition, CameraConfig, CameraError, Exposure, Gain, Pacing, PixelFormat, Recorder,
    TimestampLatch,
};

/// Camera drivers: list devices, show one, record frames.
///
/// Device names: as Aravis lists them (or an IP address), `Fake_1` for Aravis's in-process fake
/// camera, `v4l2:/dev/videoN` for V4L2, `replay:PATH` for an ASL/EuRoC folder or a recording.
#[derive(Args, Debug)]
pub struct CameraArgs {
    #[command(subcommand)]
    pub command: CameraCommand,
}

#[derive(Subcommand, Debug)]
pub enum CameraCommand {
    /// List the cameras the enabled backends can see.
    List {
        /// Also enable and list Aravis's in-process fake camera (`Fake_1`).
        #[arg(long)]
        fake: bool,
    },
    /// Show a device's vendor, model, serial, pixel formats and notable features.
    Info {
        /// Device name (see `vidslam camera --help`).
        #[arg(long)]
        device: String,
    },
    /// Record frames losslessly: PNGs in the ASL layout (`OUT/mav0/cam0/data/*.png`,
    /// `data.csv`) plus `frames.csv` with device time, host time, exposure and flags.
    Record(RecordArgs),
}

/// Which instant the device timestamp marks.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LatchArg {
    /// Start of exposure (GigE/USB3 Vision cameras).
    Start,
    /// End of exposure / frame (Aravis fake cameras, EOF-stamping V4L2 drivers).
    End,
}

/// How a `replay:` device releases frames.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum PacingArg {
    /// At the recorded rate.
    Realtime,
    /// As fast as they can be written.
    Fast,
}

#[derive(Args, Debug)]
pub struct RecordArgs {
    /// Device name (see `vidslam camera --help`).
    #[arg(long)]
    pub device: String,
    /// How long to record, seconds (host clock). A replay also stops at its end.
    #[arg(long)]
    pub seconds: f64,
    /// Output folder; `OUT/mav0/cam0/` is created (an existing recording is never overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Image width, pixels.
    #[arg(long, default_value_t = 752)]
    pub width_px: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 480)]
    pub height_px: u32,
    /// Pixel format: Mono8 or Mono16.
    #[arg(long, default_value = "Mono8")]
    pub pixel_format: PixelFormat,
    /// Free-running frame rate, Hz (with --trigger: the expected trigger rate).
    #[arg(long, default_value_t = 20.0)]
    pub rate_hz: f64,
    /// Trigger each exposure from this input (e.g. Line0, Line1, Software) instead of
    /// free-running.
    #[arg(long)]
    pub trigger: Option<String>,
    /// Manual exposure time, microseconds.
    #[arg(long, default_value_t = 5000.0, conflicts_with = "auto_exposure")]
    pub exposure_us: f64,
    /// Use the device's auto-exposure, within --auto-exposure-min-us..--auto-exposure-max-us.
    #[arg(long)]
    pub auto_exposure: bool,
    /// Lower auto-exposure limit, microseconds.
    #[arg(long, default_value_t = 100.0)]
    pub auto_exposure_min_us: f64,
    /// Upper auto-exposure limit, microseconds (keep below the frame period).
    #[arg(long, default_value_t = 20000.0)]
    pub auto_exposure_max_us: f64,
    /// Manual gain in the device's unit (dB for SFNC `Gain`, counts for `GainRaw`).
    #[arg(long, default_value_t = 0.0, conflicts_with = "auto_gain")]
    pub gain: f64,
    /// Use the device's auto gain instead of --gain.
    #[arg(long)]
    pub auto_gain: bool,
    /// Instant of the exposure the device timestamp marks (the frame time is the midpoint).
    #[arg(long, value_enum, default_value_t = LatchArg::Start)]
    pub latch: LatchArg,
    /// Pacing of `replay:` devices.
    #[arg(long, value_enum, default_value_t = PacingArg::Realtime)]
    pub replay_pacing: PacingArg,
}

pub fn run(args: CameraArgs) -> anyhow::Result<()> {
    match args.command {
        CameraCommand::List { fake } => {
            let (devices, notes) = vidslam_camera::list(fake);
            if devices.is_empty() {
                println!("no cameras found");
            }
            for d in devices {
                println!("{}\t{}", d.name, d.description);
            }
            for n in notes {
                eprintln!("note: {n}");
            }
            Ok(())
        }
        CameraCommand::Info { device } => {
            let cam = vidslam_camera::open(&device, Pacing::AsFastAsConsumed)?;
            let i = cam.info();
            println!("device: {}", i.device);
            println!("vendor: {}", i.vendor);
            println!("model: {}", i.model);
            println!("serial: {}", i.serial);
            println!("protocol: {}", i.protocol);
            println!("pixel formats: {}", i.pixel_formats.join(" "));
            for (k, v) in &i.features {
                println!("{k}: {v}");
            }
            Ok(())
        }
        CameraCommand::Record(args) => record(args),
    }
}

fn config(args: &RecordArgs) -> CameraConfig {
    CameraConfig {
        width_px: args.width_px,
        height_px: args.height_px,
        pixel_format: args.pixel_format,
        acquisition: match &args.trigger {
            Some(source) => Acquisition::ExternalTrigger {
                source: source.clone(),
                expected_rate_hz: args.rate_hz,
            },
            None => Acquisition::FreeRunning {
                rate_hz: args.rate_hz,
            },
        },
        exposure: if args.auto_exposure {
            Exposure::Auto {
                min_us: args.auto_exposure_min_us,
                max_us: args.auto_exposure_max_us,
            }
        } else {
            Exposure::Manual {
                exposure_us: args.exposure_us,
            }
        },
        gain: if args.auto_gain {
            Gain::Auto
        } else {
            Gain::Manual { gain: args.gain }
        },
        timestamp_latch: match args.latch {
            LatchArg::Start => TimestampLatch::ExposureStart,
            LatchArg::End => TimestampLatch::ExposureEnd,
        },
        ..CameraConfig::default()
    }
}

fn record(args: RecordArgs) -> anyhow::Result<()> {
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        bail!("--seconds {} must be a positive number", args.seconds);
    }
    let pacing = match args.replay_pacing {
        PacingArg::Realtime => Pacing::RealTime,
        PacingArg::Fast => Pacing::AsFastAsConsumed,
    };
    let mut cam = vidslam_camera::open(&args.device, pacing)?;
    let applied = cam.configure(&config(&args))?;
    for note in &applied.notes {
        eprintln!("note: {}: {note}", args.device);
    }
    let mut recorder = Recorder::create(&args.out)?;
    eprintln!(
        "recording {} ({}x{} {}) for {} s into {}",
        args.device,
        applied.width_px,
        applied.height_px,
        applied.pixel_format,
        args.seconds,
        recorder.cam0().display()
    );
    let frame_timeout = Duration::from_secs_f64((3.0 / args.rate_hz).max(0.5));
    cam.start()?;
    let start = Instant::now();
    let duration = Duration::from_secs_f64(args.seconds);
    let mut first_last_t: Option<(i64, i64)> = None;
    while start.elapsed() < duration {
        match cam.next_frame(
            frame_timeout.min(
                duration
                    .saturating_sub(start.elapsed())
                    .max(Duration::from_millis(1)),
            ),
        ) {
            Ok(frame) => {
                let m = frame.meta;
                if m.flags.dropped_before > 0 {
                    eprintln!(
                        "frame {}: {} frame(s) dropped before it",
                        m.frame_id, m.flags.dropped_before
                    );
                }
                if recorder
                    .write(&frame)
                    .with_context(|| format!("writing frame {}", m.frame_id))?
                {
                    let t = m.frame_time_ns.unwrap_or(m.host_receive_ns);
                    first_last_t = Some(first_last_t.map_or((t, t), |(f, _)| (f, t)));
                }
            }
            Err(CameraError::EndOfStream { .. }) => break,
            Err(CameraError::Timeout { .. }) => {}
            Err(e) if e.is_transient() => eprintln!("warning: {e}"),
            Err(e) => return Err(e.into()),
        }
    }
    cam.stop()?;
    let s = cam.stats();
    let written = recorder.written();
    let rate = first_last_t
        .filter(|(f, l)| l > f && written > 1)
        .map_or(String::from("n/a"), |(f, l)| {
            format!("{:.3} Hz", (written - 1) as f64 / ((l - f) as f64 * 1e-9))
        });
    println!(
        "{written} frames written to {} ({rate}); dropped {} (incomplete {}, missing {}, pool exhausted {}); \
         device lost {} time(s), reconnected {}; non-monotonic skipped {}",
        recorder.cam0().display(),
        s.dropped_total(),
        s.incomplete,
        s.missing,
        s.pool_exhausted,
        s.lost,
        s.reconnects,
        recorder.skipped_non_monotonic()
    );
    Ok(())
}
