//! Semidense inverse-depth mapping (paper section IV-A, eq. 27–28; details from DPPTAM, the paper's ref. 20).
//!
//! A [`SemidenseKeyframe`] holds one keyframe under construction: its raw image, camera, pose, its
//! candidate (high-gradient) pixels and, per candidate, the inverse-depth estimates found so far.
//! Every overlapping view passed to [`SemidenseKeyframe::observe`] contributes at most one
//! estimate per candidate; [`SemidenseKeyframe::map`] fuses them into a [`SemidenseMap`] at any
//! time. The caller (the mapping thread) decides which frames to feed and when the keyframe is
//! finished.
//!
//! # Geometry: search along the *distorted* epipolar curve
//!
//! Images are never resampled. Candidates are integer pixels of the raw (distorted) keyframe
//! image, which is also where [`MapPoint`] lives (the tracker samples distorted images). For a
//! candidate with normalised ray `r` (z = 1) and inverse depth `ρ` (1/z in the keyframe), the point
//! seen by a view is, up to scale, `X(ρ) = R r + ρ t` with `(R, t) = t_view_kf`: its normalised
//! coordinates move along a straight line as `ρ` varies. That line is clipped to the depth range
//! (and to points in front of the view) and to the normalised footprint of the image, then walked
//! in 1-pixel steps *after* distortion (the curve is followed with exact distortion at knots every
//! few pixels and straight in between), so any [`CameraModel`] works, and no field of view is lost
//! to undistortion.
//!
//! # Per view: eq. 27–28 for one `o`
//!
//! For each candidate (`search` module):
//! 1. The search range is the keyframe's global range ([`SemidenseKeyframe::set_inv_depth_range`])
//!    or the pixel's own window once it has one (see fusion). A view is skipped for the pixel if
//!    the whole global range spans fewer than `min_parallax_px` along the curve (no information),
//!    or if its baseline exceeds `max_baseline_depth_ratio` times the pixel's largest admissible
//!    depth (the patch's appearance changes too much for the warp below; DPPTAM bounds the
//!    baseline per frame by the median scene depth instead).
//! 2. The template warp `G` of eq. 28 is linearised: the 7x7 template around `u*` maps into the
//!    view by the affine Jacobian `A` of keyframe pixel → view pixel at constant inverse depth
//!    (fronto-parallel patch), evaluated once at the middle of the search range. This handles
//!    in-plane rotation and scale change between views, which DPPTAM's unwarped SAD does not.
//! 3. *Gradient vs. epipolar direction* (DPPTAM 1(b)): the view's epipolar direction pulled back to
//!    the keyframe, `A⁻¹ e`, must not be near-perpendicular to the keyframe gradient, or the match
//!    position along the line is undetermined. DPPTAM thresholds the mean over views; here each
//!    view is checked, and skipped for that pixel.
//! 4. *Epipolar scan* in 1-px steps with a 5-sample zero-mean SSD along the curve (each step
//!    samples one new view pixel; LSD-SLAM's scan), keeping the two best *interior* local minima
//!    (a minimum at a scan end may continue outside the range), each placed to sub-sample precision
//!    by a parabola through its three costs. The scan extends 3 px beyond the range ends so a match
//!    right at an end is still interior. DPPTAM scans with a sparse 7x7 SAD instead; the 5-sample
//!    scan is much cheaper and every retained minimum is checked with the full template.
//! 5. The full 7x7 zero-mean SSD of eq. 28 decides between the two minima (a second minimum whose
//!    cost is within `min_second_best_ratio` of the best is *ambiguous*: rejected), then one
//!    Gauss–Newton step on the curve parameter minimises it to sub-pixel precision (DPPTAM
//!    refines within ±1 px by a denser SAD scan). Zero-mean because the auto exposure changes the
//!    brightness between frames.
//! 6. The match is kept if its RMS patch residual is at most `max_patch_rms` (DPPTAM: a mean SAD
//!    threshold) and it lies within the range (±2σ). Its inverse depth follows from the curve
//!    parameter in closed form, and its standard deviation is the inverse-depth change for a shift
//!    of `match_std_px` along the curve (DPPTAM: 1 px), divided by `|cos|` of the
//!    gradient/epipolar angle (LSD-SLAM's geometric error), combined in quadrature with the
//!    view's pose uncertainty `ρ · baseline_std_m / |t|` (a baseline error scales every point of
//!    the view alike, so short-baseline views must not override wider or propagated ones).
//!
//! # Fusion over views
//!
//! Eq. 27 minimises the photometric error summed over all views. Around each view's own minimum
//! `ρ_o` its term is approximately quadratic with curvature `1/σ_o²`, so the minimiser of the sum
//! is the inverse-variance weighted mean of the per-view estimates — provided they belong to the
//! same minimum. The `fusion` module therefore first finds the largest *consistent run* (the
//! inverse depth contained in most `ρ_o ± τ σ_o` intervals; DPPTAM 1(a) uses the spread of a
//! sorted run over its mean uncertainty) and fuses only its members. Once a run of two exists, the
//! next views search only the intersection of the members' `ρ ± κ σ` intervals (DPPTAM's range
//! narrowing; before that, a pixel with a single estimate searches `± first_estimate_search_sigmas`
//! of it, as LSD-SLAM does), which makes later, wide-baseline views cheap and unambiguous: **feed
//! views in order of increasing baseline** (the keyframe's neighbours first, alternating
//! before/after) for the best speed and accuracy. A pixel searched in `give_up_after_searches` views without ever getting
//! two agreeing estimates is not searched any more (occluded, repetitive or badly textured: its
//! full-range searches would otherwise dominate the cost of the wide-baseline views). A pixel that
//! already makes a point skips a view whose parallax is too small to matter next to its fused
//! estimate (`max_view_std_ratio`: the view's best-case σ against the run's, by the weights of
//! eq. 27), typically the first views after a keyframe that was built from wider history views.
//!
//! [`SemidenseKeyframe::map`] then keeps a pixel if its run has at least `min_consistent_views`
//! votes, a relative uncertainty `σ/ρ` of at most `max_rel_inv_depth_std`, and at least
//! `min_agreeing_neighbours` fused neighbours in its 5x5 window whose inverse depths agree (DPPTAM
//! 1(c); DPPTAM also replaces the value by the neighbours' mean, which is not done here). The
//! fused runs are kept up to date by `observe`, so `map` only applies these tests (~1 ms).
//!
//! # Propagation
//!
//! [`SemidenseKeyframe::propagate_from`] moves every point of an earlier keyframe's map into this
//! keyframe (DPPTAM's propagation): it becomes a prior on the pixel it lands on (and on its 3x3
//! neighbours unless a nearer projection claims them), with the moved standard deviation inflated
//! by `prior_std_inflation` and at least `prior_min_rel_std` of the inverse depth. The prior
//! counts as one vote of the consistent run and bounds the first search, so seeded pixels converge
//! with fewer views. Unlike DPPTAM, a propagated pixel is still searched: a prior alone never
//! makes a point, and a view that disagrees with it releases the window.
//!
//! # Cost
//!
//! `observe` allocates nothing and is single-threaded unless `parallel` is set (then the
//! candidates are shared out on the rayon pool; the result is identical). On the simulator test
//! (752x480 EuRoC camera, ~20k candidates, `tests/semidense_depth.rs`) it takes ~5–25 ms of one
//! core (the first, full-range views are the dearest), `map` ~1 ms, `new` ~5–10 ms.
//!
//! Nothing assumes a scale: inverse depths are in 1/m given poses in metres.

// `if !(x > 0.0)` is deliberate throughout: a NaN must fail every check, so that no input panics or
// poisons the map.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod epipolar;
mod fusion;
mod keyframe;
mod search;

pub use keyframe::SemidenseKeyframe;

use crate::camera::CameraModel;
use nalgebra::Isometry3;

/// Tuning of the semidense mapper. Pixel and gray-level thresholds are for full-resolution 8-bit
/// images (gray levels 0..255).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SemidenseConfig {
    /// A pixel is a candidate if its central-difference gradient magnitude reaches this, gray
    /// levels per pixel.
    pub min_gradient: f32,
    /// At most this many candidates: the gradient threshold is raised until they fit (DPPTAM caps
    /// at ~25,000 on half-resolution images).
    pub max_candidates: usize,
    /// At most one candidate per square cell of this size, px: the pixel of strongest gradient
    /// in the cell (1 = every pixel over the threshold; an edge then gives a candidate per pixel
    /// across its width).
    pub candidate_cell_px: usize,
    /// Candidates keep this margin from the image border, px (DPPTAM: 5).
    pub border_px: usize,
    /// Initial search range, inverse depth 1/m; see [`SemidenseKeyframe::set_inv_depth_range`].
    pub min_inv_depth_m_inv: f64,
    /// Upper end of the initial search range, 1/m.
    pub max_inv_depth_m_inv: f64,
    /// A view is used for a pixel only if the whole search range spans at least this many pixels
    /// along its epipolar curve (smaller: too little parallax to say anything), px.
    pub min_parallax_px: f32,
    /// A view is used for a pixel only while its baseline is at most this fraction of the pixel's
    /// depth (at the far end of the pixel's search window): beyond, the 7x7 patch changes too much
    /// for the linearised warp (slanted surfaces close to the camera). DPPTAM bounds the baseline
    /// per frame by the median scene depth instead.
    pub max_baseline_depth_ratio: f32,
    /// Minimum `|cos|` between the keyframe gradient and the epipolar direction (DPPTAM: 0.2 for
    /// tracking points, 0.3 for map points).
    pub min_gradient_epipolar_cos: f32,
    /// Largest accepted RMS residual of the zero-mean 7x7 patch, gray levels.
    pub max_patch_rms: f32,
    /// The second-best minimum's 7x7 cost must exceed the best one's by this factor, or the match
    /// is ambiguous.
    pub min_second_best_ratio: f32,
    /// Position uncertainty of a match along the epipolar curve, px (DPPTAM: 1 px).
    pub match_std_px: f32,
    /// Uncertainty of the view's position relative to the keyframe, m (the tracker's relative
    /// pose error over short intervals). A baseline error `δ` moves the inverse depth of *every*
    /// point triangulated from that view by `ρ δ/|t|` — a common-mode (scale) error that no
    /// number of pixels averages away — so each view estimate's σ gets `ρ · baseline_std_m / |t|`
    /// added in quadrature: views over a baseline of a few times this weigh little against
    /// propagated priors and wider views. 0 = poses taken as exact (DPPTAM).
    pub baseline_std_m: f32,
    /// Estimates agree if an inverse depth lies within `consistency_sigmas` standard deviations of
    /// each (τ; DPPTAM: spread/uncertainty < 1.9).
    pub consistency_sigmas: f32,
    /// Once two estimates agree, later searches cover only `± search_sigmas` standard deviations
    /// around them (κ; DPPTAM: ±3σ around [min, max]).
    pub search_sigmas: f32,
    /// While a pixel has a single view estimate (and no prior), later searches cover only `±` this
    /// many of its standard deviations around it (LSD-SLAM narrows after one observation, DPPTAM
    /// after two). Shorter scans and fewer ambiguous matches; a disagreeing second estimate brings
    /// back the full range. Dimensionless; 0 searches the full range until two estimates agree.
    pub first_estimate_search_sigmas: f32,
    /// A pixel that has been searched in this many views without two estimates agreeing (no
    /// narrowed window yet) is not searched any more: it is ambiguous, occluded or badly textured,
    /// and its full-range searches would dominate the cost of later, wide-baseline views.
    pub give_up_after_searches: usize,
    /// A pixel that already makes a point (a narrowed run of `min_consistent_views` votes) is not
    /// searched in a view whose best-case inverse-depth standard deviation (`match_std_px` over the
    /// view's parallax per unit inverse depth at the run's estimate, pinhole, `|cos|` = 1) exceeds
    /// this many times the run's fused σ: by the inverse-variance weights of eq. 27 the view could
    /// carry at most 1/ratio² of the run's weight (ratio 2.5: σ shrinks by at most 7 %). Saves the
    /// short-baseline views after a keyframe. Dimensionless; 0 searches every view.
    pub max_view_std_ratio: f32,
    /// Votes needed in the consistent run for a point to be output (a propagated prior is one
    /// vote; DPPTAM needs a run of 4).
    pub min_consistent_views: usize,
    /// Largest relative standard deviation of the fused inverse depth (σ_ρ / ρ) of an output point.
    pub max_rel_inv_depth_std: f32,
    /// Neighbour check: window radius, px (2 = 5x5, as DPPTAM).
    pub neighbour_radius_px: usize,
    /// Neighbour check: at least this many fused neighbours must agree with the pixel.
    pub min_agreeing_neighbours: usize,
    /// Neighbour check: neighbours agree if their inverse depths differ by at most this relative
    /// amount (slanted surfaces) plus `consistency_sigmas` combined standard deviations.
    pub neighbour_rel_tolerance: f32,
    /// Propagated priors: the moved standard deviation is multiplied by this…
    pub prior_std_inflation: f32,
    /// …and is at least this fraction of the propagated inverse depth.
    pub prior_min_rel_std: f32,
    /// How much of a view's own scale its estimates keep, 0..1: 1 takes each view's
    /// triangulation as its tracked pose gives it; below 1 every estimate of the view is moved
    /// by `r^-(1-gain)`, `r` = [`ObserveStats::view_scale`] (factor clamped to 0.8–1.25), so a
    /// baseline error shared by the view reaches the map only in part and the map chain's scale
    /// follows the tracked (IMU-informed) baselines with that gain per view.
    pub view_scale_gain: f32,
    /// At least this many of the view's estimates must fall on propagated priors for its scale
    /// to be measured (and corrected).
    pub view_scale_min_points: usize,
    /// Search the candidates of one `observe` in parallel on the current rayon pool (the result
    /// is identical). The mapping thread runs it on a pool of its own at the mapper's lowered
    /// priority, so the tracking thread keeps its core (`runtime::mapping_worker`).
    pub parallel: bool,
}

impl Default for SemidenseConfig {
    fn default() -> Self {
        SemidenseConfig {
            min_gradient: 6.0,
            max_candidates: 30_000,
            candidate_cell_px: 1,
            border_px: 5,
            min_inv_depth_m_inv: 0.01,
            max_inv_depth_m_inv: 4.0,
            min_parallax_px: 4.0,
            max_baseline_depth_ratio: 0.4,
            min_gradient_epipolar_cos: 0.3,
            max_patch_rms: 12.0,
            min_second_best_ratio: 1.3,
            match_std_px: 0.5,
            baseline_std_m: 0.0,
            consistency_sigmas: 2.0,
            search_sigmas: 3.0,
            first_estimate_search_sigmas: 6.0,
            give_up_after_searches: 6,
            max_view_std_ratio: 2.5,
            min_consistent_views: 3,
            max_rel_inv_depth_std: 0.05,
            neighbour_radius_px: 2,
            min_agreeing_neighbours: 2,
            neighbour_rel_tolerance: 0.03,
            prior_std_inflation: 2.0,
            prior_min_rel_std: 0.02,
            view_scale_gain: 1.0,
            view_scale_min_points: 200,
            parallel: true,
        }
    }
}

/// A finished (or current) semidense map of one keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct SemidenseMap {
    /// The keyframe's camera pose in the world.
    pub t_world_cam: Isometry3<f64>,
    /// The keyframe's camera (with its distortion: points are in distorted pixels).
    pub camera: CameraModel,
    pub points: Vec<MapPoint>,
}

impl SemidenseMap {
    /// Every point's inverse depth and its standard deviation multiplied by `factor` (the map
    /// scaled about the keyframe's camera by `1 / factor`; as
    /// [`SemidenseKeyframe::scale_inv_depths`] does to the estimates it is built from).
    pub fn scale_inv_depths(&mut self, factor: f64) {
        for p in &mut self.points {
            p.inv_depth_m_inv *= factor as f32;
            p.inv_depth_std_m_inv *= factor as f32;
        }
    }
}

/// One semidense point of a keyframe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapPoint {
    /// Pixel in the keyframe's original (distorted) image; integer-valued.
    pub u_px: f32,
    pub v_px: f32,
    /// Inverse depth 1/z in the keyframe camera frame (z along the optical axis), 1/m.
    pub inv_depth_m_inv: f32,
    /// Standard deviation of the fused inverse depth, 1/m (assumes independent views, so it is
    /// optimistic: all views share the keyframe's patch).
    pub inv_depth_std_m_inv: f32,
    /// Views whose estimates were fused into this point (a propagated prior not counted).
    pub num_views: u16,
}

#[cfg(test)]
impl MapPoint {
    /// A test point at pixel `(u_px, v_px)`, 2 m away (inverse depth 0.5 ± 0.01 /m, 3 views).
    pub(crate) fn at_2_m(u_px: f32, v_px: f32) -> Self {
        MapPoint {
            u_px,
            v_px,
            inv_depth_m_inv: 0.5,
            inv_depth_std_m_inv: 0.01,
            num_views: 3,
        }
    }
}

/// Why a whole view was skipped by [`SemidenseKeyframe::observe`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewSkip {
    /// The view's or the keyframe's pose is not finite.
    NonFinitePose,
    /// The view's image size differs from the keyframe camera's.
    ImageSizeMismatch,
    /// The camera centres coincide (no baseline, no depth).
    NoBaseline,
}

/// What one [`SemidenseKeyframe::observe`] did, per candidate pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ObserveStats {
    /// The whole view was skipped (all counters below are then 0 except `candidates`).
    pub skipped: Option<ViewSkip>,
    /// Candidate pixels of the keyframe.
    pub candidates: usize,
    /// Candidates whose epipolar curve was scanned.
    pub searched: usize,
    /// Estimates added.
    pub matched: usize,
    /// The search range does not project into the view (or only behind it).
    pub out_of_view: usize,
    /// The search range spans fewer than `min_parallax_px` pixels.
    pub low_parallax: usize,
    /// The baseline is too wide for the pixel's depth (`max_baseline_depth_ratio`).
    pub wide_baseline: usize,
    /// Gradient near-perpendicular to the epipolar direction, or a degenerate patch warp.
    pub gradient_parallel: usize,
    /// Best patch residual above `max_patch_rms`.
    pub photometric: usize,
    /// Second-best minimum too close to the best.
    pub ambiguous: usize,
    /// The refined match fell outside the search range.
    pub out_of_range: usize,
    /// Not searched any more (`give_up_after_searches`).
    pub given_up: usize,
    /// Not searched in this view: too little parallax to improve the pixel's fused estimate
    /// (`max_view_std_ratio`).
    pub converged: usize,
    /// The view's scale against the map chain: median ratio of its inverse-depth estimates to
    /// the priors propagated from the previous keyframe, before `view_scale_gain` is applied;
    /// `None` below `view_scale_min_points` such pixels.
    pub view_scale: Option<f32>,
}

impl ObserveStats {
    fn add(mut self, o: &ObserveStats) -> Self {
        self.searched += o.searched;
        self.matched += o.matched;
        self.out_of_view += o.out_of_view;
        self.low_parallax += o.low_parallax;
        self.wide_baseline += o.wide_baseline;
        self.gradient_parallel += o.gradient_parallel;
        self.photometric += o.photometric;
        self.ambiguous += o.ambiguous;
        self.out_of_range += o.out_of_range;
        self.given_up += o.given_up;
        self.converged += o.converged;
        self
    }
}

#[cfg(test)]
mod tests;
