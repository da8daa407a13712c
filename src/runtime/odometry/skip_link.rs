//! Skip edges of the keyframe window (`[window] skip_edges`): the frame about to become a
//! keyframe is aligned once more, by vision alone, against the map of the keyframe two back, and
//! the length of that relative pose joins the window
//! ([`KeyframeWindow::set_newest_skip`], [`RelativePose::length_residual_scaled`]). Along the chain
//! the new keyframe's displacement crosses two maps, on the skip edge one: their difference is the
//! step of the maps' scale, read by the images instead of by the IMU alone.

use super::*;

/// What the skip edges keep between keyframes.
#[derive(Default)]
pub(super) struct SkipEdges {
    /// The keyframe left when the tracked one was installed, as tracked last (its depths as
    /// corrected and adjusted): the keyframe two back at the next new keyframe.
    left: Option<Keyframe>,
    /// The brightness of the tracked keyframe's image against the keyframe before it, by its
    /// id (`(log-gain, offset)`, the tracker's `I = e^α I_ref + β`).
    brightness: Option<(u32, (f64, f64))>,
    /// A tracker of its own (its buffers allocated once).
    tracker: Option<Tracker>,
}

impl SkipEdges {
    /// The tracked keyframe was left (for a new one).
    pub(super) fn left(&mut self, left: Option<&Keyframe>) {
        self.left = left.cloned();
    }
}

/// `I_c = e^{a1} I_b + b1` and `I_b = e^{a2} I_a + b2` give `I_c = e^{a1 + a2} I_a + e^{a1} b2 + b1`.
fn compose_brightness((a1, b1): (f64, f64), (a2, b2): (f64, f64)) -> (f64, f64) {
    (a1 + a2, a1.exp() * b2 + b1)
}

impl Odometry {
    /// Frame `result` (tracked against the window's newest keyframe, about to join the window as
    /// keyframe `next_kf_id`) aligned on `image` against the window's second newest keyframe's
    /// map: that keyframe's id and the relative body pose from it, or `None` (off, no such map,
    /// or the alignment did not hold). The alignment starts at the tracked pose with the
    /// brightness composed along the chain; its state prior (a zero-length IMU interval from a
    /// covariance of 10⁴) says nothing.
    pub(super) fn measure_skip_edge(
        &mut self,
        result: &TrackResult,
        image: &Image<u8>,
    ) -> Option<(u32, RelativePose)> {
        if !self.cfg.window.skip_edges {
            return None;
        }
        let newest = self.window.newest().map(|(id, _)| id)?;
        let frame_brightness = (result.log_gain, result.offset_gray);
        let newest_brightness = self
            .skip
            .brightness
            .replace((self.next_kf_id, frame_brightness))
            .filter(|(id, _)| *id == newest)
            .map(|(_, b)| b)?;
        let (from, x_from) = self.window.second_newest().map(|(id, x)| (id, *x))?;
        // Each keyframe left is the one two back at the next new keyframe only: taken, not copied.
        let mut kf = self.skip.left.take().filter(|kf| kf.id == from)?;
        kf.t_world_cam = pose_of(&x_from) * self.rig.t_body_cam;
        let tracker = self.skip.tracker.get_or_insert_with(|| {
            Tracker::new(
                self.cfg.tracking.clone(),
                &self.rig.camera,
                self.rig.t_body_cam,
                self.rig.noise,
                result.state,
                Matrix15::identity(),
            )
        });
        tracker.set_keyframe(kf);
        tracker.set_brightness(compose_brightness(frame_brightness, newest_brightness));
        tracker.reset_state(result.state, Matrix15::identity() * 1e4);
        let pre = Preintegration::new(result.t, result.state.bias);
        let r = tracker.track(result.t, image, &pre);
        self.stats.window_skip_edges_tried += 1;
        let held = r.flag.is_none()
            && r.inlier_ratio >= self.cfg.window.skip_min_inlier_ratio
            && r.state.is_finite();
        if !held {
            return None;
        }
        Some((
            from,
            RelativePose {
                t_i_j: pose_of(&x_from).inverse() * pose_of(&r.state),
                information: r.photometric_info,
            },
        ))
    }
}
