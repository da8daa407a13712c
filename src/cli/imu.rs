//! `vidslam imu`: decode MIP recordings, record a GX4, encode EuRoC IMU data as a GX4 recording.

use crate::dataset::gx4_recording::encode_gx4_recording;
use crate::dataset::read_imu_csv;
use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vidslam_mip::descriptor::imu as imu_desc;
use vidslam_mip::gx4::Gx4;
use vidslam_mip::imu::ImuData;
use vidslam_mip::sample::{SampleTimer, TimePreference};
use vidslam_mip::{Decoder, DecoderStats};

/// Microstrain 3DM-GX4-25 IMU (MIP protocol): decode, record, make test recordings.
#[derive(Args, Debug)]
pub struct ImuArgs {
    #[command(subcommand)]
    pub command: ImuCommand,
}

#[derive(Subcommand, Debug)]
pub enum ImuCommand {
    /// Decode a raw MIP byte stream: packets per descriptor set and field, checksum failures,
    /// bytes skipped, time span and rate of the IMU packets.
    Decode(DecodeArgs),
    /// Configure a GX4 and record its raw bytes to a file (flushed as they arrive, so a killed
    /// recording keeps everything received).
    Record(RecordArgs),
    /// Encode a EuRoC IMU CSV as the byte stream a GX4 would send (replay fixture).
    EncodeEuroc(EncodeEurocArgs),
}

#[derive(Args, Debug)]
pub struct DecodeArgs {
    /// Raw MIP recording (e.g. from `vidslam imu record`).
    pub file: PathBuf,
    /// Print the report as JSON (keys: packets, checksum_failures, bytes_skipped, per_set, ...).
    #[arg(long)]
    pub json: bool,
}

#[derive(Args, Debug)]
pub struct RecordArgs {
    /// Serial port of the GX4 (e.g. /dev/ttyACM0 or /dev/serial/by-id/...).
    #[arg(long)]
    pub port: String,
    /// UART baud rate, bit/s (the USB port ignores it).
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// IMU packet rate, Hz; must divide the 1000 Hz base rate.
    #[arg(long, default_value_t = 200)]
    pub rate_hz: u32,
    /// Output file for the raw bytes (overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many seconds (default: record until killed).
    #[arg(long)]
    pub seconds: Option<f64>,
}

#[derive(Args, Debug)]
pub struct EncodeEurocArgs {
    /// EuRoC IMU file (`mav0/imu0/data.csv`).
    #[arg(long)]
    pub csv: PathBuf,
    /// Seconds of data to encode from the start of the file.
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// Output file for the GX4-format bytes (overwritten).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs an `imu` subcommand.
pub fn run(args: ImuArgs) -> anyhow::Result<()> {
    match args.command {
        ImuCommand::Decode(a) => decode(&a),
        ImuCommand::Record(a) => record(&a),
        ImuCommand::EncodeEuroc(a) => encode_euroc(&a),
    }
}

/// Counts of one descriptor set.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SetReport {
    pub packets: u64,
    /// Field descriptor ("0x04") → occurrences.
    pub fields: BTreeMap<String, u64>,
}

/// What `imu decode` reports.
#[derive(Clone, Debug, Serialize)]
pub struct DecodeReport {
    pub file: String,
    pub bytes: u64,
    pub packets: u64,
    pub checksum_failures: u64,
    pub bytes_skipped: u64,
    pub malformed_packets: u64,
    pub unknown_sets: u64,
    pub unknown_fields: u64,
    /// Descriptor set ("0x80") → counts.
    pub per_set: BTreeMap<String, SetReport>,
    /// IMU packets (set 0x80) that carry a device timestamp.
    pub timed_imu_packets: u64,
    /// "gps" or "internal_ticks" (the first timed packet's), null without timestamps.
    pub time_source: Option<String>,
    /// Last minus first device time of the IMU packets, s.
    pub time_span_s: Option<f64>,
    /// (timed packets − 1) / time span, Hz.
    pub rate_hz: Option<f64>,
}

/// Decodes a whole file in 64 KiB chunks.
pub fn decode_file(path: &Path) -> anyhow::Result<DecodeReport> {
    let mut file =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut decoder = Decoder::new();
    let mut per_set: BTreeMap<String, SetReport> = BTreeMap::new();
    let mut timer = SampleTimer::new(TimePreference::Auto, Default::default());
    let mut times = (None::<i64>, None::<i64>, 0u64, None::<String>);
    let mut on_packet = |p: vidslam_mip::Packet<&[u8]>| {
        let set = per_set
            .entry(format!("{:#04x}", p.descriptor_set()))
            .or_default();
        set.packets += 1;
        for f in p.fields().map_while(Result::ok) {
            *set.fields
                .entry(format!("{:#04x}", f.descriptor()))
                .or_default() += 1;
        }
        if p.descriptor_set() == imu_desc::SET
            && let Ok(data) = ImuData::parse(&p)
            && let Some((t_ns, source)) = timer.device_time_ns(&data)
        {
            times.0.get_or_insert(t_ns);
            times.1 = Some(t_ns);
            times.2 += 1;
            times.3.get_or_insert_with(|| match source {
                vidslam_mip::sample::DeviceTimeSource::Gps => "gps".into(),
                vidslam_mip::sample::DeviceTimeSource::InternalTicks => "internal_ticks".into(),
            });
        }
    };
    let mut buf = vec![0u8; 64 * 1024];
    loop {
        let n = file
            .read(&mut buf)
            .with_context(|| format!("cannot read {}", path.display()))?;
        if n == 0 {
            break;
        }
        decoder.feed(&buf[..n], &mut on_packet);
    }
    decoder.finish(&mut on_packet);
    let s: DecoderStats = *decoder.stats();
    let span_s = match (times.0, times.1) {
        (Some(a), Some(b)) if times.2 > 1 => Some((b - a) as f64 * 1e-9),
        _ => None,
    };
    Ok(DecodeReport {
        file: path.display().to_string(),
        bytes: s.bytes_in,
        packets: s.packets,
        checksum_failures: s.checksum_failures,
        bytes_skipped: s.bytes_skipped,
        malformed_packets: s.malformed_packets,
        unknown_sets: s.unknown_sets,
        unknown_fields: s.unknown_fields,
        per_set,
        timed_imu_packets: times.2,
        time_source: times.3,
        time_span_s: span_s,
        rate_hz: span_s
            .filter(|&s| s > 0.0)
            .map(|s| (times.2 - 1) as f64 / s),
    })
}

fn decode(a: &DecodeArgs) -> anyhow::Result<()> {
    let r = decode_file(&a.file)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(());
    }
    println!("{}: {} bytes", r.file, r.bytes);
    println!(
        "packets {}  checksum failures {}  bytes skipped {}  malformed {}  unknown sets {}  unknown fields {}",
        r.packets,
        r.checksum_failures,
        r.bytes_skipped,
        r.malformed_packets,
        r.unknown_sets,
        r.unknown_fields
    );
    for (set, s) in &r.per_set {
        let fields: Vec<String> = s.fields.iter().map(|(f, n)| format!("{f}:{n}")).collect();
        println!(
            "  set {set}: {} packets; fields {}",
            s.packets,
            fields.join(" ")
        );
    }
    match (r.time_span_s, r.rate_hz, &r.time_source) {
        (Some(span), Some(rate), Some(src)) => println!(
            "IMU time ({src}): {} timed packets over {span:.6} s = {rate:.3} Hz",
            r.timed_imu_packets
        ),
        _ => println!("IMU time: no GX4 timestamps (0x80,0x12 or 0x80,0x0E) in this stream"),
    }
    Ok(())
}

fn record(a: &RecordArgs) -> anyhow::Result<()> {
    if let Some(s) = a.seconds
        && !(s.is_finite() && s > 0.0)
    {
        bail!("--seconds must be a positive number, got {s}");
    }
    let out = std::fs::File::create(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut dev = Gx4::open(&a.port, a.baud)?;
    let fields = [
        imu_desc::SCALED_ACCEL,
        imu_desc::SCALED_GYRO,
        imu_desc::INTERNAL_TIMESTAMP,
        imu_desc::GPS_TIMESTAMP,
    ];
    dev.set_raw_sink(Box::new(out));
    let format = dev.configure(a.rate_hz, &fields)?;
    eprintln!(
        "recording {} at {} Hz ({}-byte packets, decimation {} of {} Hz) to {}",
        a.port,
        format.rate_hz,
        format.packet_len,
        format.decimation,
        format.base_rate_hz,
        a.out.display()
    );
    match a.seconds {
        Some(s) => {
            let deadline = Instant::now() + Duration::from_secs_f64(s);
            while dev.next_sample_before(deadline)?.is_some() {}
        }
        None => loop {
            dev.next_sample()?;
        },
    }
    dev.stop()?;
    let c = dev.counters();
    eprintln!(
        "done: {} samples, {} bytes, {} bytes skipped, {} checksum failures, {} reopens",
        c.samples,
        c.decoder.bytes_in,
        c.decoder.bytes_skipped,
        c.decoder.checksum_failures,
        c.reopens
    );
    Ok(())
}

fn encode_euroc(a: &EncodeEurocArgs) -> anyhow::Result<()> {
    if !(a.seconds.is_finite() && a.seconds > 0.0) {
        bail!("--seconds must be a positive number, got {}", a.seconds);
    }
    let rows = read_imu_csv(&a.csv)?;
    if rows.is_empty() {
        bail!("{}: no IMU rows", a.csv.display());
    }
    let bytes = encode_gx4_recording(&rows, a.seconds);
    std::fs::write(&a.out, &bytes).with_context(|| format!("cannot write {}", a.out.display()))?;
    eprintln!("wrote {} bytes to {}", bytes.len(), a.out.display());
    Ok(())
}
