//! The keyframe window's estimate of each keyframe map's scale (`[window] map_scale`), fed back
//! into the map chain (`map_scale_gain`): a map that is suddenly too large — the way the chain's
//! scale wanders on S-V101 — is read by the IMU over the window and the next keyframes' maps are
//! brought back to metric; without the feedback the error stays in the chain.

mod drive;
mod scratch;

use std::path::PathBuf;
use vidslam::dataset::AslDataset;
use vidslam::runtime::map_depth::keyframe_depth_errors;
use vidslam::runtime::mapping_worker::MappingOutput;
use vidslam::runtime::odometry::{OdometryConfig, OdometryStats};
use vidslam::time::TimeNs;

/// The first 12 s of the built-in flight (2 s on the pad, the take-off and the first
/// figure-eight), seed 11, with the simulator's noise.
fn first_figure_eight() -> PathBuf {
    drive::render_builtin(scratch::dir("map-scale-feedback"), 12.0, 11)
}

/// Replays `dir` offline with `cfg` and the map tracked at 6 s made `depth_factor` too large;
/// returns the odometry's outputs and when the fault was injected.
fn run_with_fault(
    dir: &std::path::Path,
    cfg: OdometryConfig,
    depth_factor: f64,
) -> (OdometryStats, MappingOutput, TimeNs) {
    let mut t_fault: Option<TimeNs> = None;
    let mut injected: Option<TimeNs> = None;
    let odo = drive::feed(
        dir,
        cfg,
        |odo, _, t| {
            let t_fault = *t_fault.get_or_insert(t.add_ns(6_000_000_000));
            if injected.is_none() && t >= t_fault && odo.inject_map_scale_error(depth_factor) {
                injected = Some(t);
            }
            None
        },
        |_, r| assert!(r.result.state.is_finite()),
    );
    let injected = injected.expect("no mapped keyframe to scale after 6 s");
    let (stats, mapping) = odo.finish();
    assert_eq!(stats.resets, 0);
    (stats, mapping, injected)
}

/// [`run_with_fault`] with the window's scale fed back by `gain`; returns per keyframe started
/// after the fault (time since it, s; median signed depth error, %).
fn replay_with_fault(dir: &std::path::Path, gain: f64, depth_factor: f64) -> Vec<(f64, f64)> {
    let mut cfg = OdometryConfig::default();
    cfg.window.map_scale = true;
    cfg.window.map_scale_gain = gain;
    let (_, mapping, injected) = run_with_fault(dir, cfg, depth_factor);
    let ds = AslDataset::open(dir).unwrap();
    let errors =
        keyframe_depth_errors(&ds, &mapping.keyframe_maps, &mapping.keyframe_times).unwrap();
    errors
        .iter()
        .filter(|e| e.t > injected)
        .map(|e| (e.t.secs_since(injected), e.signed_median_pct))
        .collect()
}

/// Mean of the keyframes' median signed depth errors (%) started 1–2.5 s after the fault: long
/// enough for the window to have seen the large map (it is read over several keyframes), short
/// enough that the chain's own wander has not taken over.
fn mean_error_after_fault_pct(e: &[(f64, f64)]) -> f64 {
    let w: Vec<f64> = e
        .iter()
        .filter(|(t, _)| (1.0..=2.5).contains(t))
        .map(|p| p.1)
        .collect();
    assert!(
        w.len() >= 4,
        "{} keyframes 1–2.5 s after the fault",
        w.len()
    );
    w.iter().sum::<f64>() / w.len() as f64
}

#[test]
fn a_map_made_too_large_is_brought_back_to_metric_by_the_windows_scale() {
    let dir = first_figure_eight();
    let print = |what: &str, e: &[(f64, f64)]| {
        println!(
            "{what}: {}",
            e.iter()
                .map(|(t, e)| format!("{t:.2} s {e:+.1} %"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    // A map 15 % too large at 6 s.
    let without = replay_with_fault(&dir, 0.0, 1.15);
    print("estimated, not fed back", &without);
    let gain = OdometryConfig::default().window.map_scale_gain;
    let with = replay_with_fault(&dir, gain, 1.15);
    print(&format!("fed back (the default gain, {gain})"), &with);
    let (e_without, e_with) = (
        mean_error_after_fault_pct(&without),
        mean_error_after_fault_pct(&with),
    );
    println!("mean signed depth error 1–2.5 s after: {e_without:+.1} % / {e_with:+.1} %");
    // Without the feedback the chain keeps most of the fault; with it the maps are metric again.
    assert!(e_without > 5.0, "{e_without}");
    assert!(e_with.abs() < 3.0, "{e_with}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `[window] stored_map_scale_gain`: the map tracked at 6 s made 15 % too large, and not fed
/// back into the chain (`map_scale_gain = 0`, so the maps after it stay large): each keyframe
/// map that leaves the window afterwards has its stored copies scaled down by what the window
/// read of it — the IMU's word reaches the maps loops and returns are measured against — where
/// the maps before the fault, metric, are left nearly as they were.
#[test]
fn maps_made_too_large_are_scaled_back_in_their_stored_copies_as_they_leave_the_window() {
    let dir = drive::render_builtin(scratch::dir("stored-map-scale"), 12.0, 11);
    let mut cfg = OdometryConfig::default();
    cfg.window.map_scale = true;
    cfg.window.map_scale_gain = 0.0;
    cfg.window.stored_map_scale_gain = 0.75;
    cfg.window.stored_map_scale_in_returns = true;
    let (stats, _, injected) = run_with_fault(&dir, cfg.clone(), 1.15);
    let c = &stats.stored_map_scale_corrections;
    let mean = |w: Vec<f64>| {
        assert!(w.len() >= 3, "{} stored maps corrected there", w.len());
        w.iter().sum::<f64>() / w.len() as f64
    };
    // Keyframes started from the pad's take-off to the fault, and from 1 s after it (the
    // window's λ has seen the large map by the time they leave).
    let before = mean(
        c.iter()
            .filter(|(t, _)| *t < injected)
            .map(|p| p.1)
            .collect(),
    );
    let after = mean(
        c.iter()
            .filter(|(t, _)| t.secs_since(injected) > 1.0)
            .map(|p| p.1)
            .collect(),
    );
    println!(
        "stored maps corrected by e^-c, mean c: before the fault {before:+.4}, after {after:+.4} \
         (the fault ln 1.15 = {:+.4}; at most {} a map)",
        1.15f64.ln(),
        cfg.window.map_scale_max_step
    );
    assert!(before.abs() < 0.02, "{before}");
    assert!(after > 0.03, "{after}");
    let _ = std::fs::remove_dir_all(&dir);
}
