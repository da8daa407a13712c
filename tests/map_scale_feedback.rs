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
/// figure-eight), seed 11, with the simulator's noise, rendered into `target/tmp/NAME`. Each test
/// renders its own copy under its own name: the tests of this binary run at once, and a shared
/// directory was emptied and rewritten by one while another read it.
fn first_figure_eight(name: &str) -> PathBuf {
    drive::render_builtin(scratch::dir(name), 12.0, 11)
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
    let dir = first_figure_eight("map-scale-feedback");
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
    let dir = first_figure_eight("stored-map-scale");
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

/// Per frame (time since the fault, s — negative before it; the velocity's divergence from the
/// IMU's dead reckoning, m/s; a keyframe asked for at the frame), and the odometry's statistics,
/// for the accelerometer reading `step_m_s2` more along the body's x axis from 6 s after the
/// first frame on (0 = no fault).
fn divergences_with_accel_step(
    dir: &std::path::Path,
    cfg: OdometryConfig,
    step_m_s2: f64,
) -> (Vec<(f64, f64, bool)>, OdometryStats) {
    let ds = AslDataset::open(dir).unwrap();
    let first = ds.frames().unwrap().next().unwrap().unwrap().t;
    let t_fault = first.add_ns(6_000_000_000);
    let mut frames = Vec::new();
    let odo = drive::feed_imu_mapped(
        dir,
        cfg,
        |mut s| {
            if s.t >= t_fault {
                s.accel_m_s2.x += step_m_s2;
            }
            s
        },
        |_, _, _| None,
        |_, r| {
            assert!(r.result.state.is_finite());
            if let Some(d) = r.result.imu_velocity_divergence_m_s {
                frames.push((r.result.t.secs_since(t_fault), d, r.result.wants_keyframe));
            }
        },
    );
    let (stats, _) = odo.finish();
    assert_eq!(stats.resets, 0);
    (frames, stats)
}

/// `[tracking] keyframe_max_velocity_divergence_m_s`: the frame's velocity against the IMU's
/// dead reckoning from the keyframe window's newest keyframe. An accelerometer that reads
/// 0.5 m/s² more from 6 s on (a bias jump: the images still say where the camera is) takes the
/// dead reckoning off the tracked velocity — far beyond anything the flight shows before — and a
/// limit between the two starts keyframes only after the fault, at frames beyond it, and more of
/// them without the rule's wait after a keyframe.
#[test]
fn an_accelerometer_off_the_images_is_read_and_the_divergence_limit_starts_keyframes() {
    let dir = first_figure_eight("velocity-divergence");
    let max_m_s = |f: &[(f64, f64, bool)], from_s: f64, to_s: f64| {
        f.iter()
            .filter(|p| (from_s..to_s).contains(&p.0))
            .map(|p| p.1)
            .fold(0.0, f64::max)
    };
    let (clean, stats) = divergences_with_accel_step(&dir, OdometryConfig::default(), 0.0);
    assert_eq!(stats.diverged_keyframes, 0, "the limit is off by default");
    let (faulty, _) = divergences_with_accel_step(&dir, OdometryConfig::default(), 0.5);
    let (before, after) = (max_m_s(&faulty, -3.0, 0.0), max_m_s(&faulty, 0.0, 2.0));
    let clean_max = max_m_s(&clean, -3.0, 6.0);
    println!(
        "velocity divergence from the IMU's dead reckoning, max: 3 s before the fault \
         {before:.3} m/s, 2 s after {after:.3} m/s; without a fault, from 3 s before to the end \
         {clean_max:.3} m/s"
    );
    assert!(
        after > 2.0 * before.max(clean_max),
        "{after} {before} {clean_max}"
    );
    let limit_m_s = 0.5 * (after + before.max(clean_max));
    let mut cfg = OdometryConfig::default();
    cfg.tracking.keyframe_max_velocity_divergence_m_s = limit_m_s;
    let (limited, stats) = divergences_with_accel_step(&dir, cfg.clone(), 0.5);
    let above: Vec<f64> = limited
        .iter()
        .filter(|p| p.2 && p.1 > limit_m_s)
        .map(|p| p.0)
        .collect();
    println!(
        "limit {limit_m_s:.3} m/s: {} keyframes started at it; frames beyond it at {above:.2?} s \
         from the fault",
        stats.diverged_keyframes
    );
    assert!(stats.diverged_keyframes >= 1);
    assert!(above.len() >= stats.diverged_keyframes);
    assert!(above.iter().all(|t| *t >= 0.0), "{above:?}");
    let (_, clean_limited) = divergences_with_accel_step(&dir, cfg.clone(), 0.0);
    assert_eq!(clean_limited.diverged_keyframes, 0);
    // The rule's wait after the window's newest keyframe (0.5 s by default; the built-in
    // flight's keyframes come every ~0.3 s): without it, more keyframes are started by it.
    cfg.tracking.keyframe_divergence_min_age_s = 0.0;
    let (_, unhindered) = divergences_with_accel_step(&dir, cfg, 0.5);
    println!(
        "without the {:.1} s wait: {} keyframes started at the limit",
        OdometryConfig::default()
            .tracking
            .keyframe_divergence_min_age_s,
        unhindered.diverged_keyframes
    );
    assert!(unhindered.diverged_keyframes > stats.diverged_keyframes);
    let _ = std::fs::remove_dir_all(&dir);
}
