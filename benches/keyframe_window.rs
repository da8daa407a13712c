//! One keyframe-window update (issue 5): push a keyframe (marginalising the oldest of a full
//! window, `[window] max_keyframes` as configured by default, 12) and solve, on the built-in
//! flight with noise-free IMU and slightly wrong initial guesses — the work the tracking thread
//! does at every new keyframe.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use vidslam::imu::{FrameState, ImuBias, ImuNoise, Matrix15, Preintegration};
use vidslam::sim::flights::builtin_flight;
use vidslam::sim::imu_synth::ideal_imu;
use vidslam::sim::{PoseSpline, fit_pose_spline};
use vidslam::smoother::{KeyframeWindow, RelativePose, WindowConfig};
use vidslam::time::TimeNs;
use vidslam::tracking::pose_of;

const KF_PERIOD_NS: i64 = 250_000_000;

fn truth(sp: &PoseSpline, t: TimeNs) -> FrameState {
    FrameState {
        nav: sp.nav_state(t),
        bias: ImuBias::default(),
    }
}

fn bench(c: &mut Criterion) {
    let tb = Isometry3::from_parts(Translation3::identity(), UnitQuaternion::identity());
    let sp = fit_pose_spline(&builtin_flight("demo", &tb).unwrap().poses, 50_000_000)
        .unwrap()
        .0;
    let noise = ImuNoise::euroc_adis16448();
    let t0 = sp.start().add_ns(10_000_000_000);
    // A full window, then the keyframe that makes it marginalise its oldest.
    let full = WindowConfig::default().max_keyframes;
    let states: Vec<FrameState> = (0..=full as i64)
        .map(|k| truth(&sp, t0.add_ns(k * KF_PERIOD_NS)))
        .collect();
    let pre: Vec<Preintegration> = states
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0].nav.t, w[1].nav.t);
            let n = (b.0 - a.0) / 5_000_000;
            let imu: Vec<_> = (0..=n)
                .map(|k| ideal_imu(&sp, a.add_ns(k * 5_000_000)))
                .collect();
            let mut p = Preintegration::new(a, ImuBias::default());
            p.integrate(&imu, b, Some(&noise));
            p
        })
        .collect();
    let info = Matrix6::from_diagonal(&nalgebra::Vector6::new(1e8, 1e8, 1e8, 1e7, 1e7, 1e7));
    let cov0 = Matrix15::identity() * 1e-6;
    let build = || {
        let mut w = KeyframeWindow::new(WindowConfig::default(), noise);
        w.reset(0, states[0], &cov0);
        for k in 1..full {
            let mut guess = states[k];
            guess.nav.p_world_m += Vector3::new(0.01, -0.005, 0.002);
            guess.nav.v_world_m_s += Vector3::new(0.03, 0.0, -0.01);
            w.push(
                k as u32,
                guess,
                pre[k - 1].clone(),
                Some(RelativePose {
                    t_i_j: pose_of(&states[k - 1]).inverse() * pose_of(&states[k]),
                    information: info,
                }),
            );
        }
        w
    };
    c.bench_function(
        "keyframe window: push (marginalise) + solve, full window",
        |b| {
            b.iter_batched(
                build,
                |mut w| {
                    w.push(
                        full as u32,
                        states[full],
                        pre[full - 1].clone(),
                        Some(RelativePose {
                            t_i_j: pose_of(&states[full - 1]).inverse() * pose_of(&states[full]),
                            information: info,
                        }),
                    );
                    w.solve()
                },
                criterion::BatchSize::SmallInput,
            )
        },
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
