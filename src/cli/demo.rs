//! `vidslam demo`: simulate the built-in flight, run the full odometry over it, evaluate.

use super::mavlink::MavlinkOutputArgs;
use super::replay::{DepthArg, LoopEdgesArg, MappingPosesArg, ReplayArgs, StartArg, run_with};
use crate::runtime::Config;
use crate::sim::{ImuSource, SimConfig, TrajectorySource, generate};
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;

/// Renders the built-in 41 s flight (2 s on the pad with the rotors running, take-off, three
/// figure-eights, landing) with its IMU, then replays it through the full pipeline (rest
/// detection, IMU bootstrap, semidense mapping thread, joint visual-inertial tracking) and prints
/// accuracy against ground truth and timing. Exits non-zero only if the pipeline fails.
/// `--trajectory` / `--imu` render another flight instead, e.g. S-V101 (the EuRoC V1_01 path with
/// its real IMU): `--trajectory ../shared/data/euroc/V1_01_easy_micro/mav0/state_groundtruth_estimate0/data.csv
/// --imu ../shared/data/euroc/V1_01_easy_micro/mav0/imu0/data.csv --seeds 1-6`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Working folder: the dataset goes to OUT/data, the replay's files to OUT/replay.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Simulator seed (scene, textures, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run several seeds (e.g. `1-8` or `1,3,5`) into OUT/seed-N and print the distribution of
    /// the accuracy: the closed loop is chaotic (one run is one sample), so compare changes on
    /// the median and the worst of several seeds. Writes OUT/seeds.json.
    #[arg(long, value_name = "LIST", value_parser = parse_seed_list, conflicts_with = "seed")]
    pub seeds: Option<SeedList>,
    /// The flight: `builtin:NAME` (available: demo) or an EuRoC ground-truth CSV / TUM trajectory
    /// file, as `vidslam sim --trajectory`.
    #[arg(long, default_value = "builtin:demo")]
    pub trajectory: TrajectorySource,
    /// Its IMU: `synth` (simulated along the flight) or a real EuRoC imu0/data.csv covering it,
    /// as `vidslam sim --imu`.
    #[arg(long, default_value = "synth")]
    pub imu: ImuSource,
    /// Simulate only the first S seconds of the flight.
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// TOML configuration for the odometry (see config/vidslam.toml).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Replay paced at the camera's timestamps, as on the vehicle (`vidslam replay --realtime`):
    /// the mapper and the keyframe adjustment then arrive as late as this machine makes them, so
    /// two runs of one seed differ. With `--seeds` the seeds run one after the other and the
    /// table adds the adjustments applied and discarded and the views the mapper skipped.
    #[arg(long)]
    pub realtime: bool,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
}

/// Seeds of `--seeds`, in the order given.
#[derive(Clone, Debug, PartialEq)]
pub struct SeedList(pub Vec<u64>);

/// `1-4,7` → `[1, 2, 3, 4, 7]`.
pub fn parse_seed_list(s: &str) -> Result<SeedList, String> {
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let num = |t: &str| {
            t.trim()
                .parse::<u64>()
                .map_err(|_| format!("'{t}' in '{s}' is not a seed (expected e.g. 1-8 or 1,3,5)"))
        };
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (num(a)?, num(b)?);
                if b < a || b - a >= 1000 {
                    return Err(format!(
                        "seed range '{part}' must be ascending and < 1000 long"
                    ));
                }
                out.extend(a..=b);
            }
            None => out.push(num(part)?),
        }
    }
    if out.is_empty() {
        return Err("empty seed list".into());
    }
    Ok(SeedList(out))
}

/// One seed's figures in OUT/seeds.json.
#[derive(serde::Serialize)]
struct SeedRow {
    seed: u64,
    ate_rmse_m: Option<f64>,
    /// ATE of the first 20 s alone (aligned on its own).
    ate_rmse_first_20s_m: Option<f64>,
    scale_error_pct: Option<f64>,
    /// The estimated accelerometer bias's distance from the one the ground truth implies, m/s².
    accel_bias_error_m_s2: Option<f64>,
    /// The rotation fixed in the body frame between estimate and truth (`eval`'s
    /// `rot_body_offset_deg`), body axes, degrees.
    rot_body_offset_deg: Option<[f64; 3]>,
    resets: u32,
    tracking_ms_p99: f64,
    frame_ms_p99: f64,
    non_finite_poses: usize,
    keyframe_adjustments: usize,
    refinements_discarded: usize,
    mapping_views_skipped: usize,
}

pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    let cfg = Config::read_or_default(a.config.as_deref())?;
    let Some(SeedList(seeds)) = &a.seeds else {
        return run_one(&a, &cfg, a.seed, &a.out).map(|_| ());
    };
    let mut rows = Vec::new();
    for (k, &seed) in seeds.iter().enumerate() {
        println!("== seed {seed} ({}/{})", k + 1, seeds.len());
        let r = run_one(&a, &cfg, seed, &a.out.join(format!("seed-{seed}")))?;
        rows.push(SeedRow {
            seed,
            ate_rmse_m: r.eval.as_ref().map(|e| e.ate_rmse_m),
            ate_rmse_first_20s_m: r
                .scale_error_over_time
                .iter()
                .find(|s| (s.t_s - 20.0).abs() < 1e-6)
                .map(|s| s.ate_rmse_m),
            scale_error_pct: r.eval.as_ref().map(|e| e.scale_error_pct),
            accel_bias_error_m_s2: r.accel_bias_error_m_s2,
            rot_body_offset_deg: r.eval.as_ref().and_then(|e| e.rot_body_offset_deg),
            resets: r.resets,
            tracking_ms_p99: r.tracking_ms_p99,
            frame_ms_p99: r.frame_ms_p99,
            non_finite_poses: r.non_finite_poses,
            keyframe_adjustments: r.keyframe_bundles,
            refinements_discarded: r.refinements_discarded,
            mapping_views_skipped: r.mapping_views_skipped,
        });
    }
    let realtime_columns = if a.realtime {
        "   adjusted / discarded   views skipped"
    } else {
        ""
    };
    println!(
        "\nseed   ATE RMSE (SE3)   ATE first 20 s   scale error   accel bias off   body offset   resets   tracking p99   frame p99{realtime_columns}"
    );
    for r in &rows {
        let f = |v: Option<f64>, unit: &str| v.map_or("n/a".into(), |v| format!("{v:.3} {unit}"));
        // The offset's angle: its axis is in seeds.json.
        let body = r
            .rot_body_offset_deg
            .map(|[x, y, z]| (x * x + y * y + z * z).sqrt());
        print!(
            "{:<6} {:>14}   {:>14}   {:>11}   {:>14}   {:>11}   {:>6}   {:>9.2} ms   {:>6.2} ms",
            r.seed,
            f(r.ate_rmse_m, "m"),
            f(r.ate_rmse_first_20s_m, "m"),
            f(r.scale_error_pct, "%"),
            f(r.accel_bias_error_m_s2, "m/s²"),
            f(body, "deg"),
            r.resets,
            r.tracking_ms_p99,
            r.frame_ms_p99
        );
        if a.realtime {
            print!(
                "   {:>8} / {:<9}   {:>13}",
                r.keyframe_adjustments, r.refinements_discarded, r.mapping_views_skipped
            );
        }
        println!();
    }
    let mut ate: Vec<f64> = rows.iter().filter_map(|r| r.ate_rmse_m).collect();
    ate.sort_by(f64::total_cmp);
    let median = |v: &[f64]| match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    };
    let (med, worst, best) = (
        median(&ate),
        ate.last().copied().unwrap_or(f64::NAN),
        ate.first().copied().unwrap_or(f64::NAN),
    );
    println!(
        "ATE over {} seeds: median {med:.3} m, best {best:.3} m, worst {worst:.3} m; {} within \
         0.1 m, {} beyond 1 m",
        ate.len(),
        ate.iter().filter(|&&e| e <= 0.1).count(),
        ate.iter().filter(|&&e| e > 1.0).count()
    );
    let mut first: Vec<f64> = rows.iter().filter_map(|r| r.ate_rmse_first_20s_m).collect();
    first.sort_by(f64::total_cmp);
    let med_first = median(&first);
    if !first.is_empty() {
        println!("ATE of the first 20 s: median {med_first:.3} m");
    }
    let json = serde_json::json!({
        "realtime": a.realtime,
        "seeds": rows,
        "ate_rmse_m_median": med,
        "ate_rmse_first_20s_m_median": med_first,
        "ate_rmse_m_best": best,
        "ate_rmse_m_worst": worst,
    });
    std::fs::create_dir_all(&a.out)?;
    let path = a.out.join("seeds.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}

fn run_one(
    a: &DemoArgs,
    cfg: &Config,
    seed: u64,
    out: &std::path::Path,
) -> anyhow::Result<crate::runtime::ReplayReport> {
    let data = out.join("data");
    let flight = match &a.trajectory {
        TrajectorySource::Builtin(name) => format!("the built-in flight '{name}'"),
        TrajectorySource::File(f) => format!("the flight of {}", f.display()),
    };
    let imu = match &a.imu {
        ImuSource::Synth => "its simulated IMU".to_string(),
        ImuSource::File(f) => format!("the IMU of {}", f.display()),
    };
    println!("1/2 simulating {flight} with {imu} into {}", data.display());
    let mut sim = SimConfig::new(data.clone(), a.trajectory.clone(), a.imu.clone());
    sim.seed = seed;
    sim.seconds = a.seconds;
    sim.force = true;
    sim.progress = !a.quiet;
    generate(&sim).with_context(|| format!("simulating {flight} with {imu}"))?;
    println!(
        "2/2 replaying it through the odometry into {}",
        out.join("replay").display()
    );
    let args = ReplayArgs {
        dir: data,
        depth: DepthArg::Semidense,
        mapping_poses: MappingPosesArg::Tracked,
        loop_edges: LoopEdgesArg::Measured,
        start: StartArg::Static,
        realtime: a.realtime,
        out: out.join("replay"),
        config: a.config.clone(),
        max_seconds: None,
        no_vision: false,
        cover_lens: Vec::new(),
        uncover_s: 0.0,
        quiet: a.quiet,
        mavlink: None,
        mavlink_output: MavlinkOutputArgs::default(),
    };
    let started = std::time::Instant::now();
    let report = run_with(&args, cfg)?;
    let wall_s = started.elapsed().as_secs_f64();
    println!(
        "replay took {wall_s:.1} s of wall time for {:.1} s of data ({:.1}x real time)",
        report.duration_s,
        report.duration_s / wall_s.max(1e-9)
    );
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::parse_seed_list;
    use crate::cli::{Cli, Command};
    use crate::sim::{ImuSource, TrajectorySource};
    use clap::Parser;

    #[test]
    fn demo_renders_the_built_in_flight_unless_given_another_one() {
        let Command::Demo(d) = Cli::try_parse_from(["vidslam", "demo"]).unwrap().command else {
            panic!("not the demo");
        };
        assert_eq!(d.trajectory, TrajectorySource::Builtin("demo".into()));
        assert_eq!(d.imu, ImuSource::Synth);
        let Command::Demo(d) = Cli::try_parse_from([
            "vidslam",
            "demo",
            "--trajectory",
            "gt/data.csv",
            "--imu",
            "imu0/data.csv",
            "--seeds",
            "1-2",
        ])
        .unwrap()
        .command
        else {
            panic!("not the demo");
        };
        assert_eq!(d.trajectory, TrajectorySource::File("gt/data.csv".into()));
        assert_eq!(d.imu, ImuSource::File("imu0/data.csv".into()));
        assert_eq!(d.seeds.unwrap().0, vec![1, 2]);
        let e = Cli::try_parse_from(["vidslam", "demo", "--trajectory", "builtin:"]).unwrap_err();
        assert!(e.to_string().contains("builtin:demo"), "{e}");
    }

    #[test]
    fn seed_lists_parse_and_errors_say_what_is_wrong() {
        assert_eq!(parse_seed_list("1-4,7").unwrap().0, vec![1, 2, 3, 4, 7]);
        assert_eq!(parse_seed_list(" 3 ").unwrap().0, vec![3]);
        assert!(parse_seed_list("4-1").unwrap_err().contains("ascending"));
        assert!(parse_seed_list("1,x").unwrap_err().contains("'x'"));
        assert!(parse_seed_list(",").unwrap_err().contains("empty"));
    }
}
