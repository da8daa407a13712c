//! PNG plot of an evaluation: top view of both trajectories, and the ATE and the heading error
//! over time.
//!
//! Text is rendered by plotters' pure-Rust `ab_glyph` backend with DejaVu Sans embedded from the
//! `dejavu` crate, so no system font library (fontconfig/freetype) is needed.

use super::report::EvalReport;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Image size, pixels.
const WIDTH_PX: u32 = 1600;
const HEIGHT_PX: u32 = 760;
const GT_COLOR: RGBColor = RGBColor(30, 90, 200);
const EST_COLOR: RGBColor = RGBColor(220, 60, 30);
const HEADING_COLOR: RGBColor = RGBColor(30, 150, 70);

/// Why a plot could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{path}: nothing to plot (no matched poses)")]
    Empty { path: PathBuf },
    #[error("embedded font could not be registered: {0}")]
    Font(String),
    #[error("{path}: drawing failed: {msg}")]
    Draw { path: PathBuf, msg: String },
}

/// Registers the embedded font as plotters' `sans-serif` family, once per process.
fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
                .map_err(|_| "DejaVu Sans is not a valid TrueType font".to_string())
        })
        .clone()
        .map_err(PlotError::Font)
}

/// Range `[lo, hi]` of `values`, padded by `pad` of its span (and at least `min_span`).
fn padded_range(values: impl Iterator<Item = f64>, pad: f64, min_span: f64) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
        (l.min(v), h.max(v))
    });
    let span = (hi - lo).max(min_span);
    let mid = 0.5 * (lo + hi);
    (
        mid - 0.5 * span * (1.0 + 2.0 * pad),
        mid + 0.5 * span * (1.0 + 2.0 * pad),
    )
}

/// Keeps the first point, then each point at least `min_step` from the last kept one, with `y`
/// weighted by `y_weight` (to measure both axes in pixels), and the last point. plotters draws
/// wide strokes of (near) zero-length segments as stray spikes; this also bounds the work.
fn decimate(
    points: impl Iterator<Item = (f64, f64)>,
    min_step: f64,
    y_weight: f64,
) -> Vec<(f64, f64)> {
    let mut kept: Vec<(f64, f64)> = Vec::new();
    let mut last_seen = None;
    for (x, y) in points {
        last_seen = Some((x, y));
        match kept.last() {
            Some(&(kx, ky)) if (x - kx).hypot((y - ky) * y_weight) < min_step => {}
            _ => kept.push((x, y)),
        }
    }
    if let Some(p) = last_seen
        && kept.last() != Some(&p)
    {
        kept.push(p);
    }
    kept
}

/// Draws `report`'s per-pose data to a PNG at `png_path`: left, the top view (x-y, m, equal axes)
/// of the ground truth and the aligned estimate; right, the ATE (m) against time since the first
/// matched pose (s) and, on a second axis, the heading error (deg, [`super::PoseError`]) when it
/// is known. The title carries the headline figures.
pub fn plot_report(report: &EvalReport, png_path: &Path) -> Result<(), PlotError> {
    if report.per_pose.is_empty() {
        return Err(PlotError::Empty {
            path: png_path.to_path_buf(),
        });
    }
    ensure_font()?;
    let draw_err = |e: &dyn std::fmt::Display| PlotError::Draw {
        path: png_path.to_path_buf(),
        msg: e.to_string(),
    };

    let root = BitMapBackend::new(png_path, (WIDTH_PX, HEIGHT_PX)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(&e))?;
    let title = format!(
        "ATE RMSE {:.4} m ({} aligned), rotation RMSE {:.3} deg, Sim3 scale {:.5} ({:.3} %), {} poses",
        report.ate_rmse_m,
        report.align,
        report.rot_rmse_deg,
        report.scale,
        report.scale_error_pct,
        report.matched_poses
    );
    let root = root
        .titled(&title, ("sans-serif", 26))
        .map_err(|e| draw_err(&e))?;
    let (left, right) = root.split_horizontally(WIDTH_PX / 2);

    // Top view with equal axis scales: widen the narrower range to the panel's plot-area aspect.
    let (x_label_px, y_label_px, margin_px, caption_px) = (60u32, 80u32, 20u32, 40u32);
    let (panel_w, panel_h) = left.dim_in_pixel();
    let area_w = f64::from(panel_w - y_label_px - 2 * margin_px);
    let area_h = f64::from(panel_h - x_label_px - 2 * margin_px - caption_px);
    let xs = report
        .per_pose
        .iter()
        .flat_map(|p| [p.p_world_gt_m.x, p.p_world_est_m.x]);
    let ys = report
        .per_pose
        .iter()
        .flat_map(|p| [p.p_world_gt_m.y, p.p_world_est_m.y]);
    let (mut x0, mut x1) = padded_range(xs, 0.05, 1e-3);
    let (mut y0, mut y1) = padded_range(ys, 0.05, 1e-3);
    let m_per_px = ((x1 - x0) / area_w).max((y1 - y0) / area_h);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    (x0, x1) = (cx - 0.5 * m_per_px * area_w, cx + 0.5 * m_per_px * area_w);
    (y0, y1) = (cy - 0.5 * m_per_px * area_h, cy + 0.5 * m_per_px * area_h);

    let mut top = ChartBuilder::on(&left)
        .caption("top view (ground-truth world)", ("sans-serif", 22))
        .margin(margin_px)
        .x_label_area_size(x_label_px)
        .y_label_area_size(y_label_px)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| draw_err(&e))?;
    top.configure_mesh()
        .x_desc("x [m]")
        .y_desc("y [m]")
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .draw()
        .map_err(|e| draw_err(&e))?;
    // Estimate first, ground truth on top so that a noisy estimate does not hide it.
    let min_step_m = 1.5 * m_per_px;
    let est_xy = decimate(
        report
            .per_pose
            .iter()
            .map(|p| (p.p_world_est_m.x, p.p_world_est_m.y)),
        min_step_m,
        1.0,
    );
    let gt_xy = decimate(
        report
            .per_pose
            .iter()
            .map(|p| (p.p_world_gt_m.x, p.p_world_gt_m.y)),
        min_step_m,
        1.0,
    );
    top.draw_series(LineSeries::new(est_xy, EST_COLOR.stroke_width(1)))
        .map_err(|e| draw_err(&e))?
        .label(format!("estimate ({} aligned)", report.align))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], EST_COLOR.stroke_width(3)));
    top.draw_series(LineSeries::new(gt_xy, GT_COLOR.stroke_width(2)))
        .map_err(|e| draw_err(&e))?
        .label("ground truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], GT_COLOR.stroke_width(3)));
    top.configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", 16))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| draw_err(&e))?;

    let t_end_s = report.per_pose.last().map_or(0.0, |p| p.time_s).max(1e-3);
    let ate_top_m = (report.ate_max_m * 1.1).max(1e-6);
    // The heading error on a second axis, when the body offset could be fitted.
    let heading: Option<Vec<(f64, f64)>> = report
        .per_pose
        .iter()
        .map(|p| p.heading_err_deg.map(|h| (p.time_s, h)))
        .collect();
    let (h0, h1) = heading.as_ref().map_or((-1.0, 1.0), |h| {
        let top = h.iter().fold(0.0f64, |m, p| m.max(p.1.abs())).max(0.1) * 1.1;
        (-top, top)
    });
    let mut ate = ChartBuilder::on(&right)
        .caption(
            if heading.is_some() {
                "absolute trajectory error and heading error over time"
            } else {
                "absolute trajectory error over time"
            },
            ("sans-serif", 22),
        )
        .margin(margin_px)
        .x_label_area_size(x_label_px)
        .y_label_area_size(y_label_px)
        .right_y_label_area_size(if heading.is_some() { y_label_px } else { 0 })
        .build_cartesian_2d(0.0..t_end_s, 0.0..ate_top_m)
        .map_err(|e| draw_err(&e))?
        .set_secondary_coord(0.0..t_end_s, h0..h1);
    ate.configure_mesh()
        .x_desc("time since first matched pose [s]")
        .y_desc("ATE [m]")
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .draw()
        .map_err(|e| draw_err(&e))?;
    // One point per ~pixel column and row keeps the PNG readable for long sequences.
    let (ate_w_px, ate_h_px) = right.dim_in_pixel();
    let s_per_px = t_end_s / f64::from(ate_w_px.max(1));
    let m_per_px_ate = ate_top_m / f64::from(ate_h_px.max(1));
    let ate_series = decimate(
        report.per_pose.iter().map(|p| (p.time_s, p.ate_m)),
        s_per_px,
        s_per_px / m_per_px_ate,
    );
    ate.draw_series(LineSeries::new(ate_series, EST_COLOR.stroke_width(1)))
        .map_err(|e| draw_err(&e))?
        .label("ATE")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], EST_COLOR.stroke_width(3)));
    let rmse_m = report.ate_rmse_m;
    ate.draw_series(LineSeries::new(
        [(0.0, rmse_m), (t_end_s, rmse_m)],
        BLACK.stroke_width(1),
    ))
    .map_err(|e| draw_err(&e))?
    .label(format!("RMSE {rmse_m:.4} m"))
    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    if let Some(h) = heading {
        ate.configure_secondary_axes()
            .y_desc("heading error [deg]")
            .label_style(("sans-serif", 16))
            .axis_desc_style(("sans-serif", 18))
            .draw()
            .map_err(|e| draw_err(&e))?;
        let deg_per_px = (h1 - h0) / f64::from(ate_h_px.max(1));
        let series = decimate(h.into_iter(), s_per_px, s_per_px / deg_per_px);
        ate.draw_secondary_series(LineSeries::new(series, HEADING_COLOR.stroke_width(1)))
            .map_err(|e| draw_err(&e))?
            .label("heading error (world z, offsets removed)")
            .legend(|(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], HEADING_COLOR.stroke_width(3))
            });
    }
    ate.configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(("sans-serif", 16))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| draw_err(&e))?;

    root.present().map_err(|e| draw_err(&e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::report::PoseError;
    use crate::time::TimeNs;
    use nalgebra::Vector3;

    fn report_with(per_pose: Vec<PoseError>) -> EvalReport {
        let json = r#"{"align":"se3","max_dt_ms":10.0,"gt_poses":50,"est_poses":50,
            "matched_poses":50,"duration_s":2.45,"gt_path_m":4.9,"ate_rmse_m":0.05,"ate_mean_m":0.04,"ate_median_m":0.04,
            "ate_max_m":0.1,"rot_rmse_deg":1.0,"rot_mean_deg":1.0,"rot_max_deg":2.0,
            "rpe_1m_trans_rmse_m":null,"rpe_1m_rot_rmse_deg":null,"rpe_1m_segments":0,
            "rpe_10m_trans_rmse_m":null,"rpe_10m_rot_rmse_deg":null,"rpe_10m_segments":0,
            "scale":1.01,"scale_error_pct":1.0}"#;
        EvalReport {
            per_pose,
            ..serde_json::from_str(json).unwrap()
        }
    }

    /// Width and height from a PNG's IHDR chunk.
    fn png_size(bytes: &[u8]) -> (u32, u32) {
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG");
        assert_eq!(&bytes[12..16], b"IHDR");
        let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().unwrap());
        (be(16), be(20))
    }

    #[test]
    fn writes_a_png_and_refuses_empty_or_unwritable() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let per_pose: Vec<PoseError> = (0..50)
            .map(|i| {
                let a = i as f64 * 0.1;
                PoseError {
                    t: TimeNs(i * 50_000_000),
                    time_s: i as f64 * 0.05,
                    p_world_gt_m: Vector3::new(a.cos(), a.sin(), 1.0),
                    p_world_est_m: Vector3::new(a.cos() + 0.05, a.sin(), 1.0),
                    ate_m: 0.05 + 0.001 * i as f64,
                    rot_err_deg: 1.0,
                    heading_err_deg: None,
                    tilt_err_deg: None,
                }
            })
            .collect();
        let png = dir.join("eval.png");
        plot_report(&report_with(per_pose.clone()), &png).unwrap();
        let bytes = std::fs::read(&png).unwrap();
        assert_eq!(png_size(&bytes), (WIDTH_PX, HEIGHT_PX));

        // With heading errors: the second axis and its series are drawn into the same frame.
        let with_heading: Vec<PoseError> = per_pose
            .iter()
            .map(|p| PoseError {
                heading_err_deg: Some(2.0 * (p.time_s * 3.0).sin()),
                tilt_err_deg: Some(0.3),
                ..*p
            })
            .collect();
        let png_h = dir.join("eval-heading.png");
        plot_report(&report_with(with_heading), &png_h).unwrap();
        let bytes_h = std::fs::read(&png_h).unwrap();
        assert_eq!(png_size(&bytes_h), (WIDTH_PX, HEIGHT_PX));
        assert_ne!(bytes_h, bytes);

        let err = plot_report(&report_with(vec![]), &png).unwrap_err();
        assert!(matches!(err, PlotError::Empty { .. }), "{err}");
        let missing = dir.join("no-such-dir").join("eval.png");
        let msg = plot_report(&report_with(per_pose), &missing)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("no-such-dir"), "{msg}");
    }
}
