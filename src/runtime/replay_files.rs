//! The files a replay writes beside `report.json`: the trajectory (`trajectory.tum`) and in
//! hindsight (`trajectory_hindsight.tum`), the per-frame diagnostics (`frames.csv`) and the
//! semidense map (`semidense.ply`).

use super::replay::ReplayOutput;
use crate::dataset::{StampedPose, Trajectory};
use crate::tracking::pose_of;

/// Writes points as an ASCII PLY (x y z in m).
pub fn write_ply(path: &std::path::Path, points: &[nalgebra::Point3<f64>]) -> std::io::Result<()> {
    use std::io::Write;
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        w,
        "ply\nformat ascii 1.0\ncomment vidslam semidense map, world frame, metres\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header",
        points.len()
    )?;
    for p in points {
        writeln!(w, "{:.4} {:.4} {:.4}", p.x, p.y, p.z)?;
    }
    w.flush()
}

/// The estimated trajectory (body in the world) of a replay.
pub fn trajectory(out: &ReplayOutput) -> Trajectory {
    Trajectory::new(
        out.frames
            .iter()
            .map(|r| StampedPose {
                t: r.t,
                t_world_body: pose_of(&r.state),
            })
            .collect(),
    )
}

/// The published trajectory in hindsight (`trajectory_hindsight.tum`): each frame kept at its
/// pose relative to the keyframe whose world it was published in, that keyframe where the loop
/// closer's graph places it at the end
/// ([`crate::runtime::odometry::HindsightCorrections::moved`]); a frame published without a
/// correction stays as it was. `None` without loop closure, or when no frame was corrected
/// (`[loop_closure] correct_published_pose = false`).
pub fn hindsight_trajectory(out: &ReplayOutput) -> Option<Trajectory> {
    let h = out.odometry.loop_hindsight.as_ref()?;
    let corrected =
        out.loop_worlds.len() == out.frames.len() && out.loop_worlds.iter().any(Option::is_some);
    corrected.then(|| {
        Trajectory::new(
            (out.frames.iter().zip(&out.loop_worlds))
                .map(|(r, world)| {
                    let published = pose_of(&r.state);
                    StampedPose {
                        t: r.t,
                        t_world_body: world.map_or(published, |w| h.moved(&w, &published)),
                    }
                })
                .collect(),
        )
    })
}

/// Per-frame diagnostics as CSV (`frames.csv`): time, flag, iterations per level, inlier ratio,
/// overlap, residual RMS, IMU χ², keyframe, tracking time, position, velocity, biases,
/// brightness, whether vision was down-weighted (`[tracking] vision_downweight_chi2`) and the
/// tracking thread's whole frame split as in [`super::odometry::FrameTimes`] (ms; `cpu_ms`
/// empty where the platform cannot tell) and the velocity's divergence from the IMU's dead
/// reckoning since the window's newest keyframe (m/s; empty where not read).
pub fn frames_csv(out: &ReplayOutput) -> String {
    let mut s = String::from(
        "t_ns,phase,flag,iters_l0,iters_l1,iters_l2,iters_l3,inlier_ratio,overlap,residual_rms_gray,\
         imu_chi2,keyframe_id,new_keyframe,tracking_ms,px_m,py_m,pz_m,vx_m_s,vy_m_s,vz_m_s,\
         bgx_rad_s,bgy_rad_s,bgz_rad_s,bax_m_s2,bay_m_s2,baz_m_s2,log_gain,offset_gray,downweighted,\
         frame_ms,maps_ms,adjustments_ms,window_ms,other_ms,cpu_ms,imu_velocity_divergence_m_s\n",
    );
    for (i, (r, ph)) in out.frames.iter().zip(&out.phases).enumerate() {
        let n = &r.state.nav;
        let b = &r.state.bias;
        let ft = out.frame_times.get(i).copied().unwrap_or_default();
        let cpu_ms = ft
            .cpu_s
            .map_or(String::new(), |c| format!("{:.3}", c * 1e3));
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{:.4},{:.4},{:.3},{:.3},{},{},{:.3},{:.5},{:.5},{:.5},{:.4},{:.4},{:.4},\
             {:.6},{:.6},{:.6},{:.5},{:.5},{:.5},{:.4},{:.3},{},{:.3},{:.3},{:.3},{:.3},{:.3},{},{}\n",
            r.t.0,
            ph.as_str(),
            r.flag.map_or("", |f| f.as_str()),
            r.iterations[0],
            r.iterations[1],
            r.iterations[2],
            r.iterations[3],
            r.inlier_ratio,
            r.overlap,
            r.residual_rms_gray,
            r.imu_chi2,
            r.keyframe_id.map_or(-1, |k| k as i64),
            u8::from(r.wants_keyframe),
            r.time_s * 1e3,
            n.p_world_m.x,
            n.p_world_m.y,
            n.p_world_m.z,
            n.v_world_m_s.x,
            n.v_world_m_s.y,
            n.v_world_m_s.z,
            b.gyro_rad_s.x,
            b.gyro_rad_s.y,
            b.gyro_rad_s.z,
            b.accel_m_s2.x,
            b.accel_m_s2.y,
            b.accel_m_s2.z,
            r.log_gain,
            r.offset_gray,
            u8::from(r.downweighted),
            ft.total_s * 1e3,
            ft.maps_s * 1e3,
            ft.adjustments_s * 1e3,
            ft.window_s * 1e3,
            ft.other_s() * 1e3,
            cpu_ms,
            r.imu_velocity_divergence_m_s
                .map_or(String::new(), |d| format!("{d:.4}")),
        ));
    }
    s
}
