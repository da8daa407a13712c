//! A first map rebuilt in flight, shaped by its images (`[bootstrap] reinit_shape_from_images`).
//!
//! After a loss of seconds the state the IMU dead-reckoned is off by tenths of a m/s in velocity
//! — on S-V101's real IMU 0.4–0.8 m/s after 5 s, as fast as the vehicle flies — so the views of
//! a first map started then, posed by the dead reckoning, move in the wrong direction, and the
//! map triangulated from them is distorted (−49 % at its keyframe, then +4 … +113 % over the next
//! maps, none of their points within 10 % of the truth; docs/odometry-log.md, session 71): a
//! distortion the keyframe window's map scale cannot take out. Here each view's translation from
//! the first map's keyframe is turned to the direction the images give — the keyframe's corners
//! matched to the view's around where the gyro's rotation alone puts them, and the translation
//! direction solved from the matches with that rotation ([`translation_direction`]) — at a
//! distance of the view's median parallax times the last map's median depth
//! (`reinit_shape_length_from_parallax`; else the dead reckoning's distance, which carries the
//! velocity's error): what that distance gets wrong is a scale, which the keyframe window reads
//! from the IMU (`[window] map_scale_rebuilt_std`). Only after a loss of
//! `reinit_shape_min_loss_s` or more: after a short one the dead reckoning is right, and in a fast
//! turn the gyro's error over the turn is as large as the parallax. The tracker's position is
//! moved with the view, so the first map is installed where its views were.

use super::Odometry;
use crate::loop_closure::features::{
    Descriptor, Feature, MatchConfig, detect, match_guided, predicted_px,
};
use crate::loop_closure::two_view::{TwoViewConfig, translation_direction};
use crate::runtime::mapping_worker::MapFrame;
use nalgebra::{Isometry3, Translation3, Vector2, Vector3};

/// The first map's keyframe as the views are shaped against it.
pub(super) struct ReinitShape {
    t_world_cam: Isometry3<f64>,
    /// Its corners that unproject, with their rays (camera frame).
    descriptors: Vec<Descriptor>,
    rays: Vec<Vector3<f64>>,
}

impl Odometry {
    /// Fault injection for tests: the velocity dead-reckoned through a loss is off by `dv_m_s`
    /// (world frame), as after seconds of a real IMU's dead reckoning. Returns whether tracking
    /// was lost (the only time it applies).
    pub fn inject_dead_reckoning_velocity_error(&mut self, dv_m_s: Vector3<f64>) -> bool {
        if self.phase != super::Phase::Lost {
            return false;
        }
        let mut x = *self.tracker.state();
        x.nav.v_world_m_s += dv_m_s;
        let cov = *self.tracker.covariance();
        self.tracker.reset_state(x, cov);
        true
    }

    /// A first map is started in flight at `frame` (its keyframe), `[bootstrap]
    /// reinit_shape_min_loss_s` or more after the loss: its corners are kept to shape the views
    /// by.
    pub(super) fn start_reinit_shape(&mut self, frame: &MapFrame) {
        self.reinit_shape = None;
        let b = &self.cfg.bootstrap;
        let long_loss = self
            .lost_since
            .is_some_and(|since| frame.t.secs_since(since) >= b.reinit_shape_min_loss_s);
        if !(b.reinit_shape_from_images && long_loss) {
            return;
        }
        let features = detect(&frame.image, &self.cfg.loop_closure.features);
        let (descriptors, rays) = self.rays_of(&features).into_iter().unzip();
        self.reinit_shape = Some(ReinitShape {
            t_world_cam: frame.t_world_cam,
            descriptors,
            rays,
        });
    }

    /// The corners of `features` that unproject, with their rays.
    fn rays_of(&self, features: &[Feature]) -> Vec<(Descriptor, Vector3<f64>)> {
        let cam = &self.rig.camera;
        features
            .iter()
            .filter_map(|f| {
                cam.unproject(&Vector2::new(f.x_px as f64, f.y_px as f64))
                    .map(|r| (f.descriptor, r))
            })
            .collect()
    }

    /// A view of the first map being started in flight: `frame` with its translation from the
    /// keyframe turned to the images' direction (and the tracker's position moved with it), or
    /// as it is if the images do not tell (too few matches, too little parallax).
    pub(super) fn shape_reinit_view(&mut self, frame: MapFrame) -> MapFrame {
        let b = &self.cfg.bootstrap;
        let Some(shape) = self.reinit_shape.as_ref().filter(|_| self.init_in_flight) else {
            return frame;
        };
        let cam = &self.rig.camera;
        let t_kf_view = shape.t_world_cam.inverse() * frame.t_world_cam;
        let length_m = t_kf_view.translation.vector.norm();
        let r_view_kf = t_kf_view.rotation.inverse();
        let predicted: Vec<Option<[f32; 2]>> = shape
            .rays
            .iter()
            .map(|r| predicted_px(cam, &(r_view_kf * r)))
            .collect();
        let query = detect(&frame.image, &self.cfg.loop_closure.features);
        let matching = MatchConfig {
            radius_px: b.reinit_shape_radius_px,
            ..self.cfg.loop_closure.matching.clone()
        };
        let pairs = match_guided(&predicted, &shape.descriptors, &query, &matching);
        let (rays_kf, rays_view): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = pairs
            .iter()
            .filter_map(|&(k, q)| {
                let uv = Vector2::new(query[q].x_px as f64, query[q].y_px as f64);
                cam.unproject(&uv).map(|r| (shape.rays[k], r))
            })
            .unzip();
        let solved = translation_direction(
            &rays_kf,
            &rays_view,
            &r_view_kf.to_rotation_matrix(),
            &TwoViewConfig::default(),
        );
        let Some(tv) = solved.filter(|tv| {
            tv.inliers >= b.reinit_shape_min_inliers
                && tv.median_parallax_rad >= b.reinit_shape_min_parallax_rad
        }) else {
            return frame;
        };
        let length_m = match self.last_median_inv_depth {
            Some(inv) if b.reinit_shape_length_from_parallax && inv > 0.0 => {
                tv.median_parallax_rad / inv as f64
            }
            _ => length_m,
        };
        // The view's centre in the keyframe's frame: −R_view_kfᵀ t.
        let centre_dir = -(t_kf_view.rotation * tv.t_b_a_dir.into_inner());
        let shaped = shape.t_world_cam
            * Isometry3::from_parts(
                Translation3::from(centre_dir * length_m),
                t_kf_view.rotation,
            );
        if !crate::geometry::se3::is_finite(&shaped) {
            return frame;
        }
        let mut x = *self.tracker.state();
        if x.nav.t == frame.t {
            x.nav.p_world_m = (shaped * self.rig.t_body_cam.inverse()).translation.vector;
            let cov = *self.tracker.covariance();
            self.tracker.reset_state(x, cov);
        }
        self.stats.reinit_shaped_views += 1;
        MapFrame {
            t_world_cam: shaped,
            ..frame
        }
    }
}
