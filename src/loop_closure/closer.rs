//! The loop closer: keyframes in, a correction of the odometry's world out.
//!
//! Every keyframe the odometry starts becomes a node of a 4-DoF pose graph ([`PoseGraph`]) joined
//! to the keyframe it was tracked from (their relative pose as the odometry has them), and its
//! image's corners and descriptors are kept ([`features`](super::features)). When a keyframe is
//! left, the mapper's final semidense map gives depths to its corners. A new keyframe is then
//! compared with the old keyframes (at least `min_age_keyframes` nodes back) that the graph places
//! near it: the old keyframe's corners with depth are projected into the new image with the
//! relative pose the graph predicts, matched by descriptor around their predictions, and the
//! relative pose measured from the matches ([`pnp`](super::pnp)). A pose that explains enough
//! matches closely enough becomes a loop edge, and the graph is solved again.
//!
//! The result is [`LoopCloser::correction`]: the rotation about the world vertical and the
//! translation that take the odometry's pose of the newest keyframe to the graph's. The odometry
//! itself is not moved (as in VINS-Mono, the drift is taken out of the published pose only): its
//! tracking, maps and keyframe window stay in its own, drifting world, and the correction is
//! applied on the way out.
//!
//! Nodes are camera poses: the 4-DoF graph reads each node's heading as the angle of its x axis
//! about the world vertical, and the camera's x axis (image right) stays horizontal on a drone —
//! the IMU's may not (V1_01's body x points nearly up).

use super::features::{
    Descriptor, Feature, FeatureConfig, MatchConfig, detect, match_guided, predicted_px,
};
use super::loop_shift::LoopShift;
use super::pnp::{PnpConfig, solve_from_prior};
use super::pose_graph::{EdgeNoise, PoseGraph};
use crate::camera::CameraModel;
use crate::image::Image;
use crate::mapping::semidense::SemidenseMap;
use nalgebra::{Isometry3, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// `[loop_closure]`: the drift taken out of the published pose at places mapped before.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopClosureConfig {
    /// Correct the published pose by loop closures (its jumps beyond `reset_min_jump_m` go to the
    /// flight controller as MAVLink `reset_counter` + 1). S-V101 seeds 1–10 with
    /// `hold_world_on_probation`: mean ATE 0.176 → 0.134 m offline, 0.211 → 0.143 m in real time
    /// (49–65 signalled jumps per 143 s flight); the demo 1.45 → 1.65 cm median over seeds 1–16
    /// (docs/odometry-log.md, session 69).
    pub enabled: bool,
    /// `[loop_closure.features]`: corners and descriptors of each keyframe's image.
    pub features: FeatureConfig,
    /// `[loop_closure.matching]`: guided matching around the predicted pixels.
    pub matching: MatchConfig,
    /// `[loop_closure.pnp]`: the relative pose from the matches.
    pub pnp: PnpConfig,
    /// A keyframe is a loop candidate for a new one only this many keyframes back (nearer ones
    /// are the odometry's own business; 10, ~7 s on S-V101: its first loop comes ~55 s into the
    /// flight with 20, and until then the published pose is the odometry's drift).
    pub min_age_keyframes: usize,
    /// A candidate's camera is at most this far from the new keyframe's (graph poses), m.
    pub max_distance_m: f64,
    /// …and its optical axis at most this far from the new one's, rad.
    pub max_angle_rad: f64,
    /// Candidates tried per new keyframe (nearest first); the search ends when
    /// `max_loops_per_keyframe` of them have closed.
    pub max_candidates: usize,
    /// Loops closed per new keyframe at most, each to another old keyframe (1: the first that
    /// closes ends the search; 0 is taken as 1). Each loop edge is measured on one old
    /// keyframe's map, so its error is mostly that map's depth error; loops to several old maps
    /// average it. Each later candidate is predicted from the graph as solved with the loops
    /// before it.
    pub max_loops_per_keyframe: usize,
    /// A closure needs at least this many PnP inliers…
    pub min_inliers: usize,
    /// …this fraction of the matches as inliers…
    pub min_inlier_ratio: f64,
    /// …an inlier RMS within this, px…
    pub max_inlier_rms_px: f64,
    /// …and a measured relative pose within this of the graph's prediction (the drift it
    /// corrects), m…
    pub max_correction_m: f64,
    /// …and rad.
    pub max_correction_rad: f64,
    /// Standard deviation of an odometry edge's relative heading, rad, and position, m, before
    /// [`Self::odometry_std_from_rest`] scales them. S-V101's odometry drifts by decimetres over
    /// ten keyframes in its scale traps (edges held to 1 cm / 0.002 rad made the graph's robust
    /// kernel refuse 13–17 true loops per flight), the demo's by a centimetre over its flight;
    /// scaled by the pad's gyro noise, these become 5.9 cm / 0.012 rad on S-V101's real IMU and
    /// 1.0–1.4 cm / 0.002–0.003 rad on the demo's.
    pub odometry_yaw_std_rad: f64,
    pub odometry_position_std_m: f64,
    /// Standard deviation of a loop edge's relative heading, rad, and position, m: a loop is
    /// measured against one old keyframe's map, whose depths are off by 1–4 %, so a few
    /// centimetres (3 cm / 0.005 rad moved the demo's accurate odometry by its loops' errors:
    /// mean ATE 1.47 → 2.2 cm over 8 seeds; 5 cm / 0.01 rad 1.57 cm, S-V101 alike).
    pub loop_yaw_std_rad: f64,
    pub loop_position_std_m: f64,
    /// Added to an edge's position standard deviation per metre between its two keyframes (in
    /// quadrature): a map whose depths are off by a few percent places a camera a baseline away
    /// off by as many percent of it, along it — the loop's PnP measures against the old
    /// keyframe's map, the odometry chains its maps.
    pub loop_position_std_per_m: f64,
    pub odometry_position_std_per_m: f64,
    /// A loop edge's standard deviations are scaled by how well its PnP fit
    /// ([`loop_quality_factor`]: inlier RMS, inlier count and share against S-V101's medians,
    /// within ½ … 4): over 1419 loops of S-V101 seeds 1–20 the decile PnP called best was off by
    /// 1.1 cm median against 4.8 cm for the worst, and the loops beyond 10 cm gather there.
    pub loop_std_from_quality: bool,
    /// The odometry edges' standard deviations are multiplied by the gyro's noise measured on the
    /// pad over its datasheet density (at least 1; the odometry's `rotation_noise_scale`): a
    /// vehicle whose gyro is as its datasheet says drifts little between keyframes, one whose
    /// gyro is several times noisier (S-V101's real IMU, ×5.9) drifts as much more.
    pub odometry_std_from_rest: bool,
    /// Returns to stored keyframes are sought, and started, from the current pose moved into
    /// each stored keyframe's world by the graph (`C_k⁻¹ · C_now`, the corrections of the
    /// keyframe and of the one tracked): the drift since the stored keyframe was mapped, which
    /// the tracker alone must otherwise bridge from the drifted pose, is taken out first. A
    /// return that holds its probation then moves the odometry itself onto the old map.
    pub guide_returns: bool,
    /// Apply the graph's correction to the published pose (else the loops act only through
    /// `guide_returns`).
    pub correct_published_pose: bool,
    /// A change of the published correction is signalled to the flight controller as a reset
    /// (MAVLink `reset_counter` + 1) once it moves the published pose, where the body is, by more
    /// than this from the correction last signalled, m (or turns it by more than
    /// `reset_min_jump_rad`). Smaller steps reach it as measurements (a centimetre is within any
    /// vision noise an estimator fuses with, e.g. PX4's `EKF2_EVP_NOISE` 0.1 m), and the unsignalled
    /// offset never exceeds this. 0: every change is a reset.
    pub reset_min_jump_m: f64,
    pub reset_min_jump_rad: f64,
    /// A return to a stored keyframe changes the world the published pose is corrected in only
    /// once it passed its probation (`[reuse] probation_frames`): a return that fails within a
    /// frame or two does not throw the published pose into the stored keyframe's world and back.
    pub hold_world_on_probation: bool,
    /// Keep the graph's keyframes where the keyframe window last placed them: after each window
    /// solve every keyframe of the window moves in the graph with its correction kept (the
    /// frames tracked against it from then on are in the moved keyframe's world), and the
    /// odometry edges among them are measured again. Off, a keyframe stays in the graph at its
    /// pose when it was started while the window moves it (S-V101 seed 1: by 1.6 cm median,
    /// 16 cm at most, before the next keyframe starts), and its edge to the next is measured
    /// from the moved pose: the graph's odometry and its edges disagree, and each loop's solve
    /// spreads that as drift. S-V101 seeds 1–10 mean ATE 0.101 → 0.089 m (9 better), the
    /// keyframes in hindsight 0.051 → 0.044 m (docs/odometry-log.md, session 84).
    pub follow_window_poses: bool,
    /// A loop that moves its new keyframe far from where the graph has it — by more than
    /// `confirm_beyond_m` or `confirm_beyond_rad` ([`LoopShift`]) — counts fully only once a loop
    /// to another old keyframe, from the same new keyframe or one of the next
    /// `confirm_within_keyframes`, asks for the same move within `confirm_tolerance_m` and
    /// `confirm_tolerance_rad`, each plus `confirm_tolerance_share` of the held loop's move (two
    /// right loops differ by their maps' errors, a few percent of the distance to each old
    /// keyframe). Until then it is weak (`confirm_weak_std_factor`) or, with that factor 0, held
    /// out of the graph and dropped (`loops_unconfirmed`, `loops.csv` `dropped`) when the next
    /// loop asks for another move or none comes in time. S-V101 offline: weak × 3 0.089 → 0.088
    /// m mean over seeds 1–10, but seeds 16 / 20, which lose their scale, 0.409 / 0.165 → 0.722 /
    /// 0.260 (their loops are right and far, each asks for more than the one before, and few are
    /// ever confirmed): off by default since session 87; held back, seeds 1–4, 8, 10 0.090 →
    /// 0.098 (36 of the 46 loops dropped were right) — docs/odometry-log.md, sessions 86–87.
    pub confirm_far_loops: bool,
    pub confirm_beyond_m: f64,
    pub confirm_beyond_rad: f64,
    pub confirm_tolerance_m: f64,
    pub confirm_tolerance_rad: f64,
    pub confirm_tolerance_share: f64,
    pub confirm_within_keyframes: usize,
    /// A far loop goes into the graph at once with its standard deviations times this, and gets
    /// its own back when another loop agrees with what it still asks of the graph; one that none
    /// confirms stays weak. A weak loop counts towards `max_loops_per_keyframe` (with 1, the
    /// default, it is confirmed by one of the next keyframes' loops; letting the same keyframe's
    /// next candidate confirm it at once measured no better: S-V101 seeds 1–6, 8, 10 0.0887
    /// against 0.0879 m mean). 0: far loops are held back and dropped unconfirmed.
    pub confirm_weak_std_factor: f64,
    /// Real time: the loop closer's thread raises its nice value by this much (Linux; 0 = the
    /// tracker's). Above `[bootstrap] background_nice`: a loop can wait, the mapper's next map is
    /// what the tracker waits for (at nice 0 the closer's thread delayed the mapper on two cores
    /// and the demo lost in real time).
    pub thread_nice: i32,
    /// Gauss–Newton iterations per solve of the graph.
    pub iterations: usize,
    /// Keyframes kept at most (the graph stops growing: memory and solve time stay bounded).
    pub max_keyframes: usize,
}

impl Default for LoopClosureConfig {
    fn default() -> Self {
        LoopClosureConfig {
            enabled: true,
            features: FeatureConfig::default(),
            matching: MatchConfig::default(),
            pnp: PnpConfig::default(),
            min_age_keyframes: 10,
            max_distance_m: 1.5,
            max_angle_rad: 0.5,
            max_candidates: 3,
            max_loops_per_keyframe: 1,
            min_inliers: 20,
            min_inlier_ratio: 0.4,
            max_inlier_rms_px: 1.5,
            max_correction_m: 1.5,
            max_correction_rad: 0.25,
            odometry_yaw_std_rad: 0.002,
            odometry_position_std_m: 0.01,
            loop_yaw_std_rad: 0.01,
            loop_position_std_m: 0.05,
            loop_position_std_per_m: 0.0,
            odometry_position_std_per_m: 0.0,
            loop_std_from_quality: true,
            odometry_std_from_rest: true,
            guide_returns: false,
            correct_published_pose: true,
            reset_min_jump_m: 0.05,
            reset_min_jump_rad: 0.035,
            hold_world_on_probation: true,
            follow_window_poses: true,
            confirm_far_loops: false,
            confirm_beyond_m: 0.1,
            confirm_beyond_rad: 0.05,
            confirm_tolerance_m: 0.05,
            confirm_tolerance_rad: 0.02,
            confirm_tolerance_share: 0.0,
            confirm_within_keyframes: 4,
            confirm_weak_std_factor: 3.0,
            thread_nice: 15,
            iterations: 10,
            max_keyframes: 2000,
        }
    }
}

/// One keyframe of the loop closer.
struct Entry {
    node: usize,
    features: Vec<Feature>,
    /// Per feature, its point in the keyframe's camera frame, m (once the map is final).
    points_cam_m: Vec<Option<Vector3<f64>>>,
    has_points: bool,
    /// Its map's depths are to be multiplied by this ([`LoopCloser::scale_map`]), also when
    /// the map comes after the correction.
    depth_factor: f64,
}

/// What one new keyframe did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KeyframeOutcome {
    /// Loop candidates tried.
    pub candidates: usize,
    /// A loop was closed to this keyframe id (the first, when several were).
    pub closed_to: Option<u32>,
    /// Loops closed (at most `max_loops_per_keyframe`).
    pub loops: usize,
    /// PnP inliers of the closure (or of the best failed try).
    pub inliers: usize,
}

/// The PnP fit of S-V101's loops at their medians (1419 loops, seeds 1–20, session 73): inlier
/// RMS, px, inliers, inlier share.
const LOOP_MEDIAN_FIT: (f64, f64, f64) = (1.09, 34.0, 0.82);

/// How much a loop edge's standard deviations grow for its PnP fit (`loop_std_from_quality`): as
/// a least-squares pose's, with the reprojection error's RMS and one over the square root of the
/// points, and one over the share of matches that held (the rest were outliers, and some that
/// held are too) — 1 at S-V101's medians (inlier RMS 1.09 px, 34 inliers, share 0.82), within
/// ½ … 4.
pub fn loop_quality_factor(inlier_rms_px: f64, inliers: usize, inlier_ratio: f64) -> f64 {
    let (rms_px, n, share) = LOOP_MEDIAN_FIT;
    let k = (inlier_rms_px / rms_px) * (n / inliers.max(1) as f64).sqrt() * (share / inlier_ratio);
    if k.is_finite() {
        k.clamp(0.5, 4.0)
    } else {
        4.0
    }
}

/// One loop closed — or measured, held and dropped unconfirmed (`confirm_far_loops`): the
/// keyframes it joined and what PnP measured (`OUT/loops.csv`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopClosure {
    /// The new keyframe and the stored one it was closed to.
    pub new_id: u32,
    pub old_id: u32,
    /// PnP inliers, their share of the matches and their RMS, px.
    pub inliers: usize,
    pub inlier_ratio: f64,
    pub inlier_rms_px: f64,
    /// The new camera's pose in the old camera's frame as measured (the loop edge; the true one
    /// with [`LoopCloser::set_true_pose`], a diagnostic)…
    pub t_old_new: Isometry3<f64>,
    /// …and as the graph predicted it before (the drift the loop corrects is between the two).
    pub prior_t_old_new: Isometry3<f64>,
    /// Held for another loop to agree with it and dropped: never in the graph.
    pub dropped: bool,
}

/// Counters for the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LoopClosureStats {
    pub keyframes: usize,
    pub candidates_tried: usize,
    pub loops_closed: usize,
    /// Closures whose pose disagreed with the graph's prediction by more than the limits.
    pub loops_implausible: usize,
    /// Loops held for another to agree with them (`confirm_far_loops`), and those of them
    /// dropped unconfirmed (the rest are in `loops_closed`).
    pub loops_held: usize,
    pub loops_unconfirmed: usize,
    /// Loop edges the graph's robust kernel holds for wrong at its last solve.
    pub loops_rejected_by_graph: usize,
    /// The correction's size at the end: translation m, heading rad.
    pub final_correction_m: f64,
    pub final_correction_rad: f64,
    /// Jobs the odometry dropped because the loop closer's queue was full (real time).
    pub jobs_dropped: usize,
    /// Times the published pose jumped by a new correction (the odometry's count; those beyond
    /// `reset_min_jump_m` are `reset_jumps`).
    pub published_jumps: u32,
    /// Those jumps' size at the body (the published position moved by the change of correction),
    /// m: mean and max; and the largest turn, rad.
    pub published_jump_m_mean: f64,
    pub published_jump_m_max: f64,
    pub published_jump_rad_max: f64,
    /// The jumps signalled as resets (`reset_min_jump_m`; MAVLink `reset_counter` steps).
    pub reset_jumps: u32,
    /// Returns to stored keyframes started from the graph's placement (the odometry's count,
    /// `guide_returns`).
    pub guided_returns: usize,
    /// Time per new keyframe (corners, search, graph solve), ms: mean and max.
    pub keyframe_ms_mean: f64,
    pub keyframe_ms_max: f64,
}

/// The loop closer's state (no threads: see the odometry for where it runs).
pub struct LoopCloser {
    cfg: LoopClosureConfig,
    camera: CameraModel,
    graph: PoseGraph,
    entries: HashMap<u32, Entry>,
    /// Keyframe id of each node.
    node_ids: Vec<u32>,
    /// Factor on the odometry edges' standard deviations ([`Self::set_odometry_noise_scale`]).
    odometry_noise_scale: f64,
    stats: LoopClosureStats,
    /// Loops closed since [`Self::take_closures`] last took them.
    closures: Vec<LoopClosure>,
    /// A loop waiting for another to agree with it (`confirm_far_loops`).
    held: Option<HeldLoop>,
    /// Diagnostic (`vidslam replay --loop-edges gt`): keyframes' true camera poses
    /// ([`Self::set_true_pose`]); empty in the product.
    true_poses: HashMap<u32, Isometry3<f64>>,
}

/// A loop edge measured (`confirm_far_loops`): waiting for another loop to agree with it, out
/// of the graph or weak in it.
struct HeldLoop {
    /// Its edge in the graph, weakened (`confirm_weak_std_factor`); None: not in the graph.
    edge_index: Option<usize>,
    old_node: usize,
    new_node: usize,
    t_old_new: Isometry3<f64>,
    noise: EdgeNoise,
    shift: LoopShift,
    closure: LoopClosure,
}

/// A position standard deviation `std_m` with `per_m` of the baseline of `t_i_j` added in
/// quadrature, m.
fn with_baseline(std_m: f64, per_m: f64, t_i_j: &Isometry3<f64>) -> f64 {
    std_m.hypot(per_m * t_i_j.translation.vector.norm())
}

/// The loop edges to add now for a loop just measured (`confirm_far_loops`): the held one
/// and this one if they agree; this one alone if it moves the graph little (a held one that it
/// contradicts is dropped); none if it is held.
fn confirm(
    c: &LoopClosureConfig,
    held: &mut Option<HeldLoop>,
    stats: &mut LoopClosureStats,
    closures: &mut Vec<LoopClosure>,
    edge: HeldLoop,
) -> [Option<HeldLoop>; 2] {
    if !c.confirm_far_loops {
        return [Some(edge), None];
    }
    let previous = held.take();
    if let Some(h) = previous {
        if confirms(c, &h.shift, h.old_node, &edge) {
            return [Some(h), Some(edge)];
        }
        drop_held(h, stats, closures);
    }
    if edge.shift.beyond(c.confirm_beyond_m, c.confirm_beyond_rad) {
        stats.loops_held += 1;
        *held = Some(edge);
        return [None, None];
    }
    [Some(edge), None]
}

/// Whether loop `edge` confirms a held loop to `held_old_node` that asks for `held_shift`: another
/// old keyframe, the same move within the tolerances.
fn confirms(
    c: &LoopClosureConfig,
    held_shift: &LoopShift,
    held_old_node: usize,
    edge: &HeldLoop,
) -> bool {
    let k = c.confirm_tolerance_share;
    let tol_m = c.confirm_tolerance_m + k * held_shift.position_m.norm();
    let tol_rad = c.confirm_tolerance_rad + k * held_shift.yaw_rad.abs();
    held_old_node != edge.old_node && held_shift.agrees(&edge.shift, tol_m, tol_rad)
}

/// `confirm_weak_std_factor`: a loop measured goes into the graph — weakened if it moves the graph
/// far and does not agree with the loop held; a held loop it agrees with gets its own standard
/// deviations back. Returns whether the edge went in.
fn add_weak_until_confirmed(
    c: &LoopClosureConfig,
    graph: &mut PoseGraph,
    held: &mut Option<HeldLoop>,
    stats: &mut LoopClosureStats,
    closures: &mut Vec<LoopClosure>,
    mut edge: HeldLoop,
) -> bool {
    let confirmed = match held.take() {
        Some(h) => {
            // What the held loop still asks of the graph it pulled (weakly) since.
            let shift = LoopShift::of(
                &graph.pose(h.old_node),
                &graph.pose(h.new_node),
                &h.t_old_new,
            );
            if confirms(c, &shift, h.old_node, &edge) {
                if let Some(ix) = h.edge_index {
                    graph.set_edge_noise(ix, h.noise);
                }
                true
            } else {
                stats.loops_unconfirmed += 1;
                false
            }
        }
        None => false,
    };
    let weak = !confirmed && edge.shift.beyond(c.confirm_beyond_m, c.confirm_beyond_rad);
    let f = if weak { c.confirm_weak_std_factor } else { 1.0 };
    let Some(ix) = add_to_graph(graph, stats, closures, &edge, edge.noise.scaled(f)) else {
        return false;
    };
    if weak {
        stats.loops_held += 1;
        edge.edge_index = Some(ix);
        *held = Some(edge);
    }
    true
}

/// Loop `e`'s edge into the graph with the deviations `noise`, counted and recorded if it went
/// in; its edge index.
fn add_to_graph(
    graph: &mut PoseGraph,
    stats: &mut LoopClosureStats,
    closures: &mut Vec<LoopClosure>,
    e: &HeldLoop,
    noise: EdgeNoise,
) -> Option<usize> {
    let ix = (graph.add_loop_edge(e.old_node, e.new_node, &e.t_old_new, noise)).ok()?;
    stats.loops_closed += 1;
    closures.push(e.closure);
    Some(ix)
}

/// A held loop dropped unconfirmed: counted, and recorded as dropped.
fn drop_held(h: HeldLoop, stats: &mut LoopClosureStats, closures: &mut Vec<LoopClosure>) {
    stats.loops_unconfirmed += 1;
    closures.push(LoopClosure {
        dropped: true,
        ..h.closure
    });
}

/// Heading of a camera pose's optical axis is compared through this.
fn optical_axis(t_world_cam: &Isometry3<f64>) -> Vector3<f64> {
    t_world_cam.rotation * Vector3::z()
}

impl LoopCloser {
    pub fn new(cfg: LoopClosureConfig, camera: CameraModel) -> Self {
        LoopCloser {
            cfg,
            camera,
            graph: PoseGraph::new(),
            entries: HashMap::new(),
            node_ids: Vec::new(),
            odometry_noise_scale: 1.0,
            stats: LoopClosureStats::default(),
            closures: Vec::new(),
            held: None,
            true_poses: HashMap::new(),
        }
    }

    /// Diagnostic (`vidslam replay --loop-edges gt`), before [`Self::add_keyframe`] of the same
    /// `id`: keyframe `id`'s true camera pose. A loop between two keyframes that both have one
    /// is found and accepted as always (matches, PnP, the plausibility limits), then goes into
    /// the graph — and into its [`LoopClosure`] record — with the true relative pose in place
    /// of the measured one: what the loop edges' errors cost. Non-finite poses are ignored.
    pub fn set_true_pose(&mut self, id: u32, t_world_cam: Isometry3<f64>) {
        if crate::geometry::se3::is_finite(&t_world_cam) {
            self.true_poses.insert(id, t_world_cam);
        }
    }

    /// The new camera's true pose in the old camera's frame, if both have one
    /// ([`Self::set_true_pose`]).
    fn true_t_old_new(&self, old_id: u32, new_id: u32) -> Option<Isometry3<f64>> {
        let (old, new) = (self.true_poses.get(&old_id)?, self.true_poses.get(&new_id)?);
        Some(old.inverse() * new)
    }

    /// The loops closed since the last call, in order.
    pub fn take_closures(&mut self) -> Vec<LoopClosure> {
        std::mem::take(&mut self.closures)
    }

    pub fn stats(&self) -> LoopClosureStats {
        let mut s = self.stats.clone();
        let c = self.correction();
        s.final_correction_m = c.translation.vector.norm();
        s.final_correction_rad = c.rotation.angle();
        s
    }

    /// The correction of the odometry's world: `C · t_world_x` is the pose the graph gives (an
    /// identity until a loop is closed).
    pub fn correction(&self) -> Isometry3<f64> {
        match self.graph.len() {
            0 => Isometry3::identity(),
            n => self.graph.correction(n - 1),
        }
    }

    /// Multiplies the standard deviations of the odometry edges added from now on by `scale`
    /// (finite and positive; else ignored).
    pub fn set_odometry_noise_scale(&mut self, scale: f64) {
        if scale.is_finite() && scale > 0.0 {
            self.odometry_noise_scale = scale;
        }
    }

    /// Keyframes moved by the odometry (the keyframe window's solve): each `(id, t_world_cam)` of
    /// a keyframe in the graph moves there keeping its correction, and the odometry edges among
    /// them are measured again ([`LoopClosureConfig::follow_window_poses`]).
    pub fn move_keyframes(&mut self, poses: &[(u32, Isometry3<f64>)]) {
        let mut moved = Vec::with_capacity(poses.len());
        for (id, t_world_cam) in poses {
            if let Some(e) = self.entries.get(id) {
                self.graph.move_odometry(e.node, t_world_cam);
                moved.push(e.node);
            }
        }
        self.graph.remeasure_odometry_edges(&moved);
    }

    /// Every keyframe's correction of the odometry's world (the graph's pose of it over the
    /// odometry's when it was started), by keyframe id, into `out` (cleared first).
    pub fn corrections_into(&self, out: &mut HashMap<u32, Isometry3<f64>>) {
        out.clear();
        let graph = &self.graph;
        out.extend(
            (self.node_ids.iter().enumerate()).map(|(node, &id)| (id, graph.correction(node))),
        );
    }

    /// A new keyframe `id` at the odometry's camera pose `t_world_cam`, started from keyframe
    /// `host` (whose camera pose is now `t_world_cam_host`), with its image. Returns what the
    /// loop search did.
    pub fn add_keyframe(
        &mut self,
        id: u32,
        t_world_cam: &Isometry3<f64>,
        host: Option<(u32, Isometry3<f64>)>,
        image: &Image<u8>,
    ) -> KeyframeOutcome {
        if self.entries.contains_key(&id) || self.graph.len() >= self.cfg.max_keyframes {
            return KeyframeOutcome::default();
        }
        let started = std::time::Instant::now();
        let node = self.graph.add_node(*t_world_cam);
        self.node_ids.push(id);
        let c = &self.cfg;
        let k = self.odometry_noise_scale;
        let noise = |t_i_j: &Isometry3<f64>| EdgeNoise {
            yaw_std_rad: k * c.odometry_yaw_std_rad,
            position_std_m: k * with_baseline(
                c.odometry_position_std_m,
                c.odometry_position_std_per_m,
                t_i_j,
            ),
        };
        // Joined to the keyframe it was tracked from; else (a restart of the odometry) to the
        // previous node, ten times looser.
        let known_host = host.and_then(|(h, p)| self.entries.get(&h).map(|e| (e.node, p)));
        // The edges' poses are finite (the odometry publishes none that is not), so adding them
        // cannot fail; a refusal would leave the node joined by the other branch's edge.
        if let Some((h, t_world_cam_host)) = known_host {
            let t_h_n = t_world_cam_host.inverse() * t_world_cam;
            let _ = self.graph.add_relative_edge(h, node, &t_h_n, noise(&t_h_n));
            // Carried by the host's correction (the node before may be far: after a return).
            let c = self.graph.correction(h);
            self.graph.set_estimate(node, &(c * t_world_cam));
        } else if node > 0 {
            let prev = node - 1;
            let t_p_n = self.graph.odometry_pose(prev).inverse() * t_world_cam;
            let n = noise(&t_p_n);
            let _ = (self.graph).add_relative_edge(prev, node, &t_p_n, n.scaled(10.0));
        }
        let features = detect(image, &c.features);
        self.entries.insert(
            id,
            Entry {
                node,
                points_cam_m: vec![None; features.len()],
                features,
                has_points: false,
                depth_factor: 1.0,
            },
        );
        let waited = self.cfg.confirm_within_keyframes;
        if let Some(h) = self.held.take_if(|h| h.new_node + waited < node) {
            if h.edge_index.is_some() {
                self.stats.loops_unconfirmed += 1;
            } else {
                drop_held(h, &mut self.stats, &mut self.closures);
            }
        }
        let out = self.search(id);
        let ms = started.elapsed().as_secs_f64() * 1e3;
        let s = &mut self.stats;
        s.keyframe_ms_mean =
            (s.keyframe_ms_mean * s.keyframes as f64 + ms) / (s.keyframes + 1) as f64;
        s.keyframe_ms_max = s.keyframe_ms_max.max(ms);
        s.keyframes += 1;
        out
    }

    /// The final semidense map of keyframe `id` (points in its camera frame): depths for its
    /// corners. A corner takes the median inverse depth of the map points within 2 px if they
    /// agree within 15 %.
    pub fn attach_map(&mut self, id: u32, map: &SemidenseMap) {
        let Some(e) = self.entries.get_mut(&id) else {
            return;
        };
        if e.has_points {
            return;
        }
        let (w, h) = (self.camera.width, self.camera.height);
        let mut grid = vec![f32::NAN; w * h];
        for p in &map.points {
            let (u, v) = (p.u_px as isize, p.v_px as isize);
            let ok = p.inv_depth_m_inv > 0.0
                && p.inv_depth_std_m_inv < 0.1 * p.inv_depth_m_inv
                && u >= 0
                && v >= 0
                && (u as usize) < w
                && (v as usize) < h;
            if ok {
                grid[v as usize * w + u as usize] = p.inv_depth_m_inv;
            }
        }
        let mut near = Vec::with_capacity(25);
        let mut any = false;
        for (f, slot) in e.features.iter().zip(&mut e.points_cam_m) {
            near.clear();
            let (cx, cy) = (f.x_px.round() as isize, f.y_px.round() as isize);
            for y in cy - 2..=cy + 2 {
                for x in cx - 2..=cx + 2 {
                    if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                        let r = grid[y as usize * w + x as usize];
                        if r.is_finite() {
                            near.push(r);
                        }
                    }
                }
            }
            if near.len() < 2 {
                continue;
            }
            near.sort_by(f32::total_cmp);
            let med = near[near.len() / 2];
            if (near[near.len() - 1] - near[0]) > 0.15 * med {
                continue;
            }
            let uv = Vector2::new(f.x_px as f64, f.y_px as f64);
            if let Some(ray) = self.camera.unproject(&uv) {
                *slot = Some(ray * (e.depth_factor / med as f64));
                any = true;
            }
        }
        e.has_points = any;
    }

    /// Keyframe `id`'s map is scaled by `depth_factor` about its camera (the keyframe window's
    /// estimate of its scale as it left the window, `[window] stored_map_scale_gain`): its
    /// corners' points, and those of a map attached later.
    pub fn scale_map(&mut self, id: u32, depth_factor: f64) {
        let Some(e) = self.entries.get_mut(&id) else {
            return;
        };
        if !(depth_factor.is_finite() && depth_factor > 0.0) {
            return;
        }
        e.depth_factor *= depth_factor;
        for p in e.points_cam_m.iter_mut().flatten() {
            *p *= depth_factor;
        }
    }

    /// Looks for a loop for the new keyframe `id`.
    fn search(&mut self, id: u32) -> KeyframeOutcome {
        let mut out = KeyframeOutcome::default();
        let new = &self.entries[&id];
        let new_node = new.node;
        // Candidates are chosen around the new keyframe as placed before any loop of its own.
        let t_world_new_searched = self.graph.pose(new_node);
        let axis_new = optical_axis(&t_world_new_searched);
        let mut candidates: Vec<(f64, u32)> = self
            .entries
            .iter()
            .filter(|(_, e)| e.has_points && e.node + self.cfg.min_age_keyframes <= new_node)
            .filter_map(|(&cid, e)| {
                let t = self.graph.pose(e.node);
                let d = (t.translation.vector - t_world_new_searched.translation.vector).norm();
                let a = optical_axis(&t).angle(&axis_new);
                (d <= self.cfg.max_distance_m && a <= self.cfg.max_angle_rad).then_some((d, cid))
            })
            .collect();
        candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        candidates.truncate(self.cfg.max_candidates);
        for (_, cid) in candidates {
            out.candidates += 1;
            self.stats.candidates_tried += 1;
            let old = &self.entries[&cid];
            // As solved with the loops this keyframe closed before (unchanged until one does).
            let t_world_new = self.graph.pose(new_node);
            let t_world_old = self.graph.pose(old.node);
            // The relative pose the graph predicts: the old camera's points into the new one.
            let prior_t_new_old = t_world_new.inverse() * t_world_old;
            let mut refs: Vec<usize> = Vec::new();
            let mut predicted: Vec<Option<[f32; 2]>> = Vec::new();
            let mut descriptors: Vec<Descriptor> = Vec::new();
            for (k, (f, p)) in old.features.iter().zip(&old.points_cam_m).enumerate() {
                let Some(p) = p else { continue };
                let q = prior_t_new_old * Point3::from(*p);
                refs.push(k);
                predicted.push(predicted_px(&self.camera, &q.coords));
                descriptors.push(f.descriptor);
            }
            let pairs = match_guided(&predicted, &descriptors, &new.features, &self.cfg.matching);
            if pairs.len() < self.cfg.min_inliers {
                continue;
            }
            let points: Vec<Vector3<f64>> = pairs
                .iter()
                .filter_map(|&(r, _)| old.points_cam_m[refs[r]])
                .collect();
            let pixels: Vec<Vector2<f64>> = pairs
                .iter()
                .map(|&(_, q)| {
                    let f = &new.features[q];
                    Vector2::new(f.x_px as f64, f.y_px as f64)
                })
                .collect();
            let Some(sol) = solve_from_prior(
                &self.camera,
                &points,
                &pixels,
                &prior_t_new_old,
                &self.cfg.pnp,
            ) else {
                continue;
            };
            out.inliers = out.inliers.max(sol.num_inliers);
            let ratio = sol.num_inliers as f64 / pairs.len() as f64;
            if sol.num_inliers < self.cfg.min_inliers
                || ratio < self.cfg.min_inlier_ratio
                || sol.inlier_rms_px > self.cfg.max_inlier_rms_px
            {
                continue;
            }
            let moved = prior_t_new_old.inverse() * sol.t_query_ref;
            if moved.translation.vector.norm() > self.cfg.max_correction_m
                || moved.rotation.angle() > self.cfg.max_correction_rad
            {
                self.stats.loops_implausible += 1;
                continue;
            }
            let t_old_new =
                (self.true_t_old_new(cid, id)).unwrap_or_else(|| sol.t_query_ref.inverse());
            let k = if self.cfg.loop_std_from_quality {
                loop_quality_factor(sol.inlier_rms_px, sol.num_inliers, ratio)
            } else {
                1.0
            };
            let noise = EdgeNoise {
                yaw_std_rad: k * self.cfg.loop_yaw_std_rad,
                position_std_m: k * with_baseline(
                    self.cfg.loop_position_std_m,
                    self.cfg.loop_position_std_per_m,
                    &t_old_new,
                ),
            };
            let old_node = old.node;
            let closure = LoopClosure {
                new_id: id,
                old_id: cid,
                inliers: sol.num_inliers,
                inlier_ratio: ratio,
                inlier_rms_px: sol.inlier_rms_px,
                t_old_new,
                prior_t_old_new: prior_t_new_old.inverse(),
                dropped: false,
            };
            let edge = HeldLoop {
                edge_index: None,
                old_node,
                new_node,
                t_old_new,
                noise,
                shift: LoopShift::of(&t_world_old, &t_world_new, &t_old_new),
                closure,
            };
            let added = if self.cfg.confirm_far_loops && self.cfg.confirm_weak_std_factor > 0.0 {
                add_weak_until_confirmed(
                    &self.cfg,
                    &mut self.graph,
                    &mut self.held,
                    &mut self.stats,
                    &mut self.closures,
                    edge,
                )
            } else {
                let edges = confirm(
                    &self.cfg,
                    &mut self.held,
                    &mut self.stats,
                    &mut self.closures,
                    edge,
                );
                let mut added = false;
                for e in edges.into_iter().flatten() {
                    let (graph, stats, closures) =
                        (&mut self.graph, &mut self.stats, &mut self.closures);
                    added |= add_to_graph(graph, stats, closures, &e, e.noise).is_some();
                }
                added
            };
            if !added {
                continue;
            }
            let summary = self.graph.optimize(self.cfg.iterations);
            self.stats.loops_rejected_by_graph = summary.rejected_loop_edges;
            out.closed_to.get_or_insert(cid);
            out.loops += 1;
            if out.loops >= self.cfg.max_loops_per_keyframe.max(1) {
                break;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loop_edge_is_loosened_for_a_worse_fit_and_tightened_for_a_better_one() {
        let (rms_px, n, share) = LOOP_MEDIAN_FIT;
        let median = loop_quality_factor(rms_px, n as usize, share);
        assert!((median - 1.0).abs() < 1e-12, "{median}");
        // Twice the reprojection error: twice the deviation; four times the points: half.
        let rough = loop_quality_factor(2.0 * rms_px, n as usize, share);
        assert!((rough - 2.0).abs() < 1e-12, "{rough}");
        let many = loop_quality_factor(rms_px, 4 * n as usize, share);
        assert!((many - 0.5).abs() < 1e-12, "{many}");
        // Fewer matches held: looser.
        assert!(loop_quality_factor(rms_px, n as usize, 0.5 * share) > 1.9);
        // Bounded both ways, and a degenerate fit is the loosest.
        assert_eq!(loop_quality_factor(10.0, 20, 0.4), 4.0);
        assert_eq!(loop_quality_factor(0.1, 400, 1.0), 0.5);
        assert_eq!(loop_quality_factor(f64::NAN, 30, 0.8), 4.0);
        assert_eq!(loop_quality_factor(1.0, 0, 0.0), 4.0);
    }
}
