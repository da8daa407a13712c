//! `vidslam eval`: compares an estimated trajectory with ground truth (ATE, RPE, scale).

use crate::dataset::Trajectory;
use crate::eval::{Alignment, EvalOptions, evaluate, plot_report};
use anyhow::Context as _;
use clap::{Args, ValueEnum};
use std::path::PathBuf;

/// Below this matched ground-truth path length, m, a warning says the alignment is ill-conditioned.
const SHORT_PATH_M: f64 = 1.0;

/// Compare an estimated trajectory with ground truth: ATE, rotation error, RPE over 1 m and 10 m,
/// and the Sim3 scale error. Prints a table; optionally writes JSON and a PNG plot.
#[derive(Args, Debug, Clone)]
pub struct EvalArgs {
    /// Ground-truth trajectory: TUM (`t_s tx ty tz qx qy qz qw`) or EuRoC CSV
    /// (`t_ns,px,py,pz,qw,qx,qy,qz,...`), detected from the first data line.
    #[arg(long, value_name = "FILE")]
    pub gt: PathBuf,
    /// Estimated trajectory (t_world_body), TUM or EuRoC CSV, on the ground truth's clock.
    #[arg(long, value_name = "FILE")]
    pub est: PathBuf,
    /// Alignment of the estimate onto the ground truth before computing errors (Umeyama). The
    /// Sim3 scale is reported whichever is chosen.
    #[arg(long, value_enum, default_value_t = AlignArg::Se3)]
    pub align: AlignArg,
    /// Ground truth is interpolated at each estimate time only between two samples at most this
    /// far apart, ms; estimate poses outside the ground truth or in longer gaps are not matched.
    #[arg(long, value_name = "MS", default_value_t = 10.0)]
    pub max_dt_ms: f64,
    /// Write the figures as a flat JSON object (keys such as `ate_rmse_m`, `scale_error_pct`).
    #[arg(long, value_name = "OUT.json")]
    pub json: Option<PathBuf>,
    /// Draw a PNG: top view of both trajectories and the ATE over time.
    #[arg(long, value_name = "OUT.png")]
    pub plot: Option<PathBuf>,
    /// Also print the ATE RMSE of each time segment these cut times (s since the first matched
    /// pose, increasing, comma-separated) divide the run into, under the one alignment — e.g. the
    /// built-in demo's phases from `1.5,4.5,32.5,35.5` (idle, take-off, laps, hover turn, landing)
    /// — with its mean heading error (about the ground truth world's z axis) and RMS tilt error
    /// once the constant world rotation and body offset are removed, degrees.
    #[arg(long, value_name = "S,S,...", value_delimiter = ',')]
    pub segments_s: Vec<f64>,
}

/// `--align` values.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlignArg {
    /// Rotation and translation (as `evo_ape -a`).
    Se3,
    /// Rotation, translation and scale (as `evo_ape -as`), for monocular estimates.
    Sim3,
    /// No alignment: the estimate is already in the ground-truth world frame.
    None,
}

impl From<AlignArg> for Alignment {
    fn from(a: AlignArg) -> Alignment {
        match a {
            AlignArg::Se3 => Alignment::Se3,
            AlignArg::Sim3 => Alignment::Sim3,
            AlignArg::None => Alignment::None,
        }
    }
}

/// Runs `vidslam eval`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    if !(args.max_dt_ms.is_finite() && args.max_dt_ms > 0.0) {
        anyhow::bail!(
            "--max-dt-ms must be a positive number of milliseconds, got {}",
            args.max_dt_ms
        );
    }
    let cuts = &args.segments_s;
    let valid =
        cuts.iter().all(|c| c.is_finite() && *c > 0.0) && cuts.windows(2).all(|w| w[0] < w[1]);
    if !valid {
        anyhow::bail!(
            "--segments-s must be positive, finite, increasing seconds since the first matched \
             pose, got {cuts:?}"
        );
    }
    let (gt, _) = Trajectory::read(&args.gt).context("reading the ground truth (--gt)")?;
    let (est, _) = Trajectory::read(&args.est).context("reading the estimate (--est)")?;
    let opts = EvalOptions {
        align: args.align.into(),
        max_dt_ns: (args.max_dt_ms * 1e6).round() as i64,
    };
    let report = evaluate(&gt, &est, &opts).with_context(|| {
        format!(
            "evaluating {} against {}",
            args.est.display(),
            args.gt.display()
        )
    })?;
    print!("{}", report.to_table());
    if !cuts.is_empty() {
        for seg in report.segment_errors(cuts) {
            print!("{}", seg.to_row());
        }
    }
    if report.gt_path_m < SHORT_PATH_M {
        eprintln!(
            "warning: the matched ground truth travels only {:.3} m: alignment and scale are \
             poorly conditioned",
            report.gt_path_m
        );
    }
    if let Some(path) = &args.json {
        report.write_json(path).context("writing --json")?;
    }
    if let Some(path) = &args.plot {
        plot_report(&report, path).context("writing --plot")?;
    }
    Ok(())
}
