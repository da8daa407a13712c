//! The 4-DoF pose graph over keyframes that takes the odometry's drift out when a loop closes
//! (VINS-Mono: T. Qin, P. Li, S. Shen, "VINS-Mono: A Robust and Versatile Monocular
//! Visual-Inertial State Estimator", IEEE Trans. Robotics 34(4), 2018, section *Global Pose Graph
//! Optimization*, "4-DOF Pose Graph Optimization").
//!
//! # Model
//!
//! The world frame is gravity-aligned with z up (see [`crate::geometry`]). A visual-inertial
//! odometry observes gravity, so the roll and pitch of every keyframe are (locally) observable and
//! do not drift; the yaw about world z and the position do. Each node is a keyframe's body pose
//! `t_world_body`, decomposed ZYX (yaw-pitch-roll) as `R = Rz(ψ) R_rp` with
//! `ψ = atan2(R[1,0], R[0,0])` and `R_rp = Rz(ψ)ᵀ R`. `R_rp` (roll and pitch) is held at the
//! odometry's; the free variables of node i are its yaw `ψ_i` (rad) and position `p_i` (m, world):
//! four per node.
//!
//! An edge (i, j) carries a relative yaw `ψ̂_ij` and a relative position `p̂_ij` (body i's
//! coordinates) and has the residual
//!
//! ```text
//! r_ψ = wrap(ψ_j − ψ_i − ψ̂_ij) / σ_ψ            wrap into (−π, π]
//! r_p = (R_iᵀ (p_j − p_i) − p̂_ij) / σ_p          R_i = Rz(ψ_i) R_rp,i
//! ```
//!
//! From a relative pose `t_i_j` (body i → body j) the measurement is `p̂_ij = t_i_j.translation`
//! and `ψ̂_ij = yaw(R_rp,i R_ij)`: the yaw node j would have relative to node i if node i sat at its
//! own roll and pitch, which is what `ψ_j − ψ_i` is when `R_j = R_i R_ij` (left-multiplying by
//! `Rz(ψ_i)` adds `ψ_i` to the ZYX yaw). The roll and pitch of `R_ij` are otherwise unused.
//!
//! * Odometry edges take `t_i_j` from the odometry poses given to [`PoseGraph::add_node`], so they
//!   are exactly satisfied at the odometry: a graph without loop edges stays where it is.
//!   [`PoseGraph::add_relative_edge`] adds the same kind of (non-robust) edge from a relative pose
//!   given by the caller.
//! * Loop edges take `t_i_j` from the loop detector (a PnP pose against an old keyframe). A wrong
//!   loop (perceptual aliasing) must not bend the whole trajectory, so their squared whitened
//!   residual `s = |r|²` goes through a Cauchy kernel `ρ(s) = c² ln(1 + s/c²)` of scale `c` (in
//!   whitened units, i.e. standard deviations; [`DEFAULT_LOOP_CAUCHY_SCALE`] = 3 by default). Its
//!   weight `ρ'(s) = 1 / (1 + s/c²)` is 1 for a consistent loop and falls below 0.5 once the
//!   residual's norm exceeds `c` standard deviations: such a loop edge is counted as *rejected*
//!   in the [`OptimizeSummary`]. The Cauchy kernel is redescending (the pull `ρ'(s)·r` of a far
//!   outlier tends to 0), unlike Huber whose pull stays constant, which is why it is used here.
//!   VINS-Mono uses a Huber loss on its loop edges.
//!
//! The Cauchy cost is not convex: a true loop closed after a long drift starts with a large
//! residual, and from the odometry's poses the estimate can lie in the basin of the "loop open"
//! local minimum even when closing it costs less. [`PoseGraph::optimize`] therefore graduates the
//! scale, as in graduated non-convexity (Yang, Antonante, Tzoumas, Carlone, "Graduated
//! Non-Convexity for Robust Spatial Perception", IEEE RA-L 2020): when the worst loop residual
//! exceeds `c`, it first runs a few steps at `2^k c` (k from ⌈log2(worst / c)⌉, at most 4, down to
//! 1), each stage starting where the previous ended, then converges at `c`. A gross outlier (tens
//! of standard deviations) keeps a small weight even at `16 c` and is rejected as the scale
//! shrinks. If the graduated result costs more (at `c`) than the start, it is discarded and the
//! optimisation redone from the start at `c` alone.
//!
//! The cost is `½ Σ ρ(s_e)` (ρ(s) = s for odometry edges). Gauge: the graph is invariant to one
//! rotation about z and one translation of everything, so **node 0 is held fixed** (its yaw and
//! position stay at the odometry's, or where [`PoseGraph::set_estimate`] put it). A part of the
//! graph with no path to node 0 has a free gauge of its own: the damping keeps its steps finite
//! and it stays about where it started.
//!
//! # Solver
//!
//! Levenberg-Marquardt (Marquardt's scaling: `H + λ diag(H)`) with iteratively re-weighted least
//! squares for the kernel and analytic Jacobians. The normal equations are 4n × 4n with one 4 × 4
//! block per node and per connected pair of nodes: odometry edges make them block tridiagonal,
//! loop edges add far-off blocks. They are solved exactly by a sparse block Cholesky
//! factorisation, i.e. Gaussian elimination of the nodes one at a time (each elimination is the
//! Schur complement onto the node's neighbours, creating fill between them), in a greedy
//! *minimum-degree* order chosen on the fly (Tinney & Walker 1967; George & Liu, *Computer Solution
//! of Large Sparse Positive Definite Systems*, ch. 5). On a keyframe chain with a few loops the
//! order peels the chain from its ends and the degrees stay at 2–3 (plus one per loop edge
//! crossing), so a factorisation costs O(n) 4 × 4 block products instead of the dense
//! (4n)³/3 flops (≈ 0.6 Gflop at n = 300 per iteration), and unlike preconditioned conjugate
//! gradients (whose iteration count grows with the chain's length, the condition number of a
//! chain Laplacian being O(n²)) it is exact, so LM keeps its quadratic convergence without a
//! tolerance to tune. A non-positive-definite pivot makes the step fail and LM increase λ.
//! Measured (release, this crate's test `optimize_time_200_and_400_nodes`, 10 loop edges): a whole
//! `optimize` takes ≈ 2.5 ms for 200 nodes and ≈ 5 ms for 400 (10–12 steps).
//!
//! Limits: the ZYX yaw is undefined when the body x axis is vertical (pitch ±90°), never the case
//! for a multirotor. Invalid edges (an index out of range, i == j, a non-finite measurement or a
//! non-positive standard deviation) are refused with a [`PoseGraphError`] and leave the graph
//! unchanged; an empty graph, a single node or a graph without edges optimise to a no-op.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::f64::consts::{PI, TAU};

use crate::geometry::se3;
use nalgebra::{Isometry3, Matrix3, Matrix4, Translation3, UnitQuaternion, Vector3, Vector4};

/// Default scale `c` of the Cauchy kernel on loop edges, in standard deviations of the whitened
/// 4-vector residual: a loop edge's weight is 0.5 when `|r| = c`.
pub const DEFAULT_LOOP_CAUCHY_SCALE: f64 = 3.0;

/// The loop kernel's scale starts at most `2^GRADUATED_STAGES` times its final value.
const GRADUATED_STAGES: u32 = 4;

/// Steps at most at each scale above the final one (they only need to carry the estimate into the
/// next scale's basin).
const STAGE_ITERATIONS: usize = 8;

/// Robust weights below this count a loop edge as rejected in [`OptimizeSummary`].
const REJECTED_WEIGHT: f64 = 0.5;

/// Standard deviations of an edge's relative yaw and relative position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeNoise {
    /// Of the relative yaw, rad.
    pub yaw_std_rad: f64,
    /// Of each axis of the relative position (in body i's frame), m.
    pub position_std_m: f64,
}

impl EdgeNoise {
    /// Both deviations times `factor`.
    pub fn scaled(self, factor: f64) -> Self {
        EdgeNoise {
            yaw_std_rad: factor * self.yaw_std_rad,
            position_std_m: factor * self.position_std_m,
        }
    }

    /// Both deviations finite and positive (else an edge refuses them).
    fn is_valid(&self) -> bool {
        let valid = |s: f64| s.is_finite() && s > 0.0;
        valid(self.yaw_std_rad) && valid(self.position_std_m)
    }
}

/// Why an edge was refused (the graph is left unchanged).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PoseGraphError {
    #[error("node {index} out of range (the graph has {len} nodes)")]
    NodeOutOfRange { index: usize, len: usize },
    #[error("edge from node {0} to itself")]
    SelfEdge(usize),
    #[error(
        "edge standard deviations must be finite and positive (yaw {yaw_std_rad} rad, position {position_std_m} m)"
    )]
    InvalidNoise {
        yaw_std_rad: f64,
        position_std_m: f64,
    },
    #[error("non-finite relative pose")]
    NonFiniteMeasurement,
}

/// What [`PoseGraph::optimize`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct OptimizeSummary {
    /// `½ Σ ρ(s_e)` (whitened, dimensionless) at the estimate optimisation started from.
    pub initial_cost: f64,
    /// The same at the returned estimate (never above `initial_cost`).
    pub final_cost: f64,
    /// Levenberg-Marquardt steps tried (accepted or not).
    pub iterations: usize,
    /// True if it stopped on a vanishing gradient, step or cost decrease rather than on
    /// `max_iterations` (or on a non-finite cost).
    pub converged: bool,
    /// The Cauchy weight of each loop edge at the returned estimate, in the order they were added.
    pub loop_edge_weights: Vec<f64>,
    /// Loop edges whose weight is below 0.5 (residual beyond the kernel's scale): deemed wrong.
    pub rejected_loop_edges: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum EdgeKind {
    Odometry,
    Loop,
}

/// A node's fixed data: its odometry pose and roll-pitch part.
#[derive(Clone, Debug)]
struct Node {
    odometry: Isometry3<f64>,
    yaw_odometry_rad: f64,
    /// `Rz(ψ_odometry)⁻¹ q_odometry`: roll and pitch.
    q_rp: UnitQuaternion<f64>,
    r_rp: Matrix3<f64>,
}

impl Node {
    /// A node at the odometry pose `t_world_body`, split into its yaw and its roll and pitch.
    fn new(t_world_body: Isometry3<f64>) -> Node {
        let r = t_world_body.rotation.to_rotation_matrix().into_inner();
        let yaw_odometry_rad = yaw_of(&r);
        let q_rp = rz(-yaw_odometry_rad) * t_world_body.rotation;
        Node {
            odometry: t_world_body,
            yaw_odometry_rad,
            q_rp,
            r_rp: q_rp.to_rotation_matrix().into_inner(),
        }
    }

    /// The measurement `(ψ̂_ij, p̂_ij)` of an edge from this node (i) given the relative pose
    /// `t_i_j` (see the module documentation).
    fn measurement(&self, t_i_j: &Isometry3<f64>) -> (f64, Vector3<f64>) {
        let r_i_j = t_i_j.rotation.to_rotation_matrix().into_inner();
        (yaw_of(&(self.r_rp * r_i_j)), t_i_j.translation.vector)
    }
}

#[derive(Clone, Debug)]
struct Edge {
    i: usize,
    j: usize,
    kind: EdgeKind,
    yaw_rad: f64,
    position_m: Vector3<f64>,
    inv_yaw_std: f64,
    inv_position_std: f64,
}

/// A 4-DoF (yaw + position) pose graph over keyframes; see the module documentation.
#[derive(Clone, Debug)]
pub struct PoseGraph {
    nodes: Vec<Node>,
    edges: Vec<Edge>,
    /// Current estimate: yaw (rad, in (−π, π]) and world position (m) of every node.
    yaw_rad: Vec<f64>,
    position_m: Vec<Vector3<f64>>,
    loop_cauchy_scale: f64,
}

impl Default for PoseGraph {
    fn default() -> Self {
        Self::new()
    }
}

impl PoseGraph {
    /// An empty graph with the default loop kernel scale.
    pub fn new() -> Self {
        Self {
            nodes: Vec::new(),
            edges: Vec::new(),
            yaw_rad: Vec::new(),
            position_m: Vec::new(),
            loop_cauchy_scale: DEFAULT_LOOP_CAUCHY_SCALE,
        }
    }

    /// Sets the Cauchy scale `c` of loop edges (standard deviations, see
    /// [`DEFAULT_LOOP_CAUCHY_SCALE`]); ignored unless finite and positive.
    pub fn set_loop_cauchy_scale(&mut self, c: f64) {
        if c.is_finite() && c > 0.0 {
            self.loop_cauchy_scale = c;
        }
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True if there is no node.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Adds a keyframe at the odometry's pose `t_world_body`; returns its index. Its estimate
    /// starts at the odometry pose carried by the previous node's current
    /// [`correction`](Self::correction) (the odometry pose itself for the first node and before
    /// any loop was optimised), so that a graph already optimised stays consistent.
    pub fn add_node(&mut self, t_world_body: Isometry3<f64>) -> usize {
        let node = Node::new(t_world_body);
        let yaw_odometry_rad = node.yaw_odometry_rad;
        let (yaw, position) = match self.nodes.len().checked_sub(1) {
            None => (yaw_odometry_rad, t_world_body.translation.vector),
            Some(last) => {
                let c = self.correction(last);
                (
                    wrap_angle(
                        yaw_odometry_rad + self.yaw_rad[last] - self.nodes[last].yaw_odometry_rad,
                    ),
                    c.rotation * t_world_body.translation.vector + c.translation.vector,
                )
            }
        };
        self.nodes.push(node);
        self.yaw_rad.push(yaw);
        self.position_m.push(position);
        self.nodes.len() - 1
    }

    /// Adds an odometry edge between nodes i and j, measured from their odometry poses (those
    /// given to [`add_node`](Self::add_node)); not robustified.
    pub fn add_odometry_edge(
        &mut self,
        i: usize,
        j: usize,
        noise: EdgeNoise,
    ) -> Result<(), PoseGraphError> {
        self.check_indices(i, j)?;
        let t_i_j = self.nodes[i].odometry.inv_mul(&self.nodes[j].odometry);
        self.push_edge(i, j, &t_i_j, noise, EdgeKind::Odometry)
    }

    /// Adds a non-robust edge like an odometry edge but from a given relative pose `t_i_j` (body
    /// j's pose in body i's frame), e.g. the odometry's current relative pose of two keyframes
    /// whose poses it refined after they were added.
    pub fn add_relative_edge(
        &mut self,
        i: usize,
        j: usize,
        t_i_j: &Isometry3<f64>,
        noise: EdgeNoise,
    ) -> Result<(), PoseGraphError> {
        self.check_indices(i, j)?;
        self.push_edge(i, j, t_i_j, noise, EdgeKind::Odometry)
    }

    /// Adds a loop edge from the measured relative pose `t_i_j` (body j's pose in body i's
    /// frame: `p_i = t_i_j * p_j`); only its relative yaw and translation are used, and it goes
    /// through the Cauchy kernel.
    /// Returns the edge's index (for [`Self::set_edge_noise`]).
    pub fn add_loop_edge(
        &mut self,
        i: usize,
        j: usize,
        t_i_j: &Isometry3<f64>,
        noise: EdgeNoise,
    ) -> Result<usize, PoseGraphError> {
        self.check_indices(i, j)?;
        self.push_edge(i, j, t_i_j, noise, EdgeKind::Loop)?;
        Ok(self.edges.len() - 1)
    }

    /// Sets the standard deviations of edge `index` (as returned by [`Self::add_loop_edge`]);
    /// ignored unless the index exists and both are finite and positive.
    pub fn set_edge_noise(&mut self, index: usize, noise: EdgeNoise) {
        if let Some(e) = self.edges.get_mut(index)
            && noise.is_valid()
        {
            e.inv_yaw_std = 1.0 / noise.yaw_std_rad;
            e.inv_position_std = 1.0 / noise.position_std_m;
        }
    }

    /// Number of loop edges.
    pub fn loop_edge_count(&self) -> usize {
        self.edges
            .iter()
            .filter(|e| e.kind == EdgeKind::Loop)
            .count()
    }

    /// Levenberg-Marquardt from the current estimate, node 0 held fixed, at most `max_iterations`
    /// steps in all (a few tens is plenty; each is one sparse factorisation). The kernel's scale
    /// is graduated (see the module documentation). The returned estimate never has a higher
    /// cost than the one it started from.
    pub fn optimize(&mut self, max_iterations: usize) -> OptimizeSummary {
        let c = self.loop_cauchy_scale;
        let initial_cost = self.cost(&self.yaw_rad, &self.position_m, c);
        if !initial_cost.is_finite() {
            return self.summary(initial_cost, initial_cost, 0, false);
        }
        // Start at a scale where the worst loop edge has a weight of about 0.5 (at most 16 c).
        let worst = (self.edges.iter())
            .filter(|e| e.kind == EdgeKind::Loop)
            .map(|e| self.whitened(e, &self.yaw_rad, &self.position_m).0.norm())
            .fold(0.0, f64::max);
        let stages = (worst / c)
            .log2()
            .ceil()
            .clamp(0.0, GRADUATED_STAGES as f64) as i32;
        let start = (self.yaw_rad.clone(), self.position_m.clone());
        let mut iterations = 0;
        for k in (1..=stages).rev() {
            let scale = c * f64::from(1 << k);
            let budget = STAGE_ITERATIONS.min(max_iterations - iterations);
            iterations += self.levenberg_marquardt(scale, budget, 1e-4).0;
        }
        let (n, mut converged) = self.levenberg_marquardt(c, max_iterations - iterations, 1e-12);
        iterations += n;
        let mut cost = self.cost(&self.yaw_rad, &self.position_m, c);
        if cost > initial_cost {
            // The graduation led to a worse basin: start again without it.
            (self.yaw_rad, self.position_m) = start;
            let (n, conv) = self.levenberg_marquardt(c, max_iterations - iterations, 1e-12);
            iterations += n;
            converged = conv;
            cost = self.cost(&self.yaw_rad, &self.position_m, c);
        }
        self.summary(initial_cost, cost, iterations, converged)
    }

    /// The optimised pose of node i: its optimised yaw and position, the odometry's roll and
    /// pitch. Panics if `i >= len()`.
    pub fn pose(&self, i: usize) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.position_m[i]),
            rz(self.yaw_rad[i]) * self.nodes[i].q_rp,
        )
    }

    /// Sets node i's estimate (the start of the next [`optimize`](Self::optimize)) to the yaw and
    /// position of `t_world_body`; its roll and pitch are ignored (node i keeps the odometry's).
    /// Ignored if the pose is not finite. Setting node 0 moves the fixed gauge node. Panics if
    /// `i >= len()`.
    pub fn set_estimate(&mut self, i: usize, t_world_body: &Isometry3<f64>) {
        let r = t_world_body.rotation.to_rotation_matrix().into_inner();
        let yaw = yaw_of(&r);
        let p = t_world_body.translation.vector;
        assert!(i < self.nodes.len(), "node {i} out of range");
        if yaw.is_finite() && p.iter().all(|x| x.is_finite()) {
            self.yaw_rad[i] = yaw;
            self.position_m[i] = p;
        }
    }

    /// Node i's odometry pose measured again as `t_world_body` (the odometry refined it after
    /// it was added): its estimate moves with it, keeping its [`correction`](Self::correction),
    /// and its roll and pitch become the new pose's. The edges are left as measured
    /// ([`remeasure_odometry_edges`](Self::remeasure_odometry_edges); a loop edge from node i
    /// keeps the relative yaw it was given with i's roll and pitch then — the window moves those
    /// by milliradians). Ignored if the pose is not finite. Panics if `i >= len()`.
    pub fn move_odometry(&mut self, i: usize, t_world_body: &Isometry3<f64>) {
        if !se3::is_finite(t_world_body) {
            return;
        }
        let c = self.correction(i);
        self.nodes[i] = Node::new(*t_world_body);
        let moved = c * t_world_body;
        self.yaw_rad[i] = wrap_angle(yaw_of(&moved.rotation.to_rotation_matrix().into_inner()));
        self.position_m[i] = moved.translation.vector;
    }

    /// Every odometry edge between two of the nodes `moved` measured again from their odometry
    /// poses ([`move_odometry`](Self::move_odometry)); its noise is kept. Loop edges are left.
    pub fn remeasure_odometry_edges(&mut self, moved: &[usize]) {
        let nodes = &self.nodes;
        for e in (self.edges.iter_mut()).filter(|e| {
            e.kind == EdgeKind::Odometry && moved.contains(&e.i) && moved.contains(&e.j)
        }) {
            let t_i_j = nodes[e.i].odometry.inv_mul(&nodes[e.j].odometry);
            (e.yaw_rad, e.position_m) = nodes[e.i].measurement(&t_i_j);
        }
    }

    /// The odometry pose of node i: as added, or as last moved
    /// ([`move_odometry`](Self::move_odometry)). Panics if `i >= len()`.
    pub fn odometry_pose(&self, i: usize) -> Isometry3<f64> {
        self.nodes[i].odometry
    }

    /// The 4-DoF correction `C` (a rotation about world z, then a translation) with
    /// `pose(i) = C * odometry_pose(i)`: what to apply to the odometry's poses near keyframe i.
    /// Panics if `i >= len()`.
    pub fn correction(&self, i: usize) -> Isometry3<f64> {
        let node = &self.nodes[i];
        let rotation = rz(self.yaw_rad[i] - node.yaw_odometry_rad);
        let translation = self.position_m[i] - rotation * node.odometry.translation.vector;
        Isometry3::from_parts(Translation3::from(translation), rotation)
    }

    /// Levenberg-Marquardt with loop kernel scale `scale`, at most `max_iterations` steps; stops
    /// when a step lowers the cost by at most `tolerance` of it. Returns the steps tried and
    /// whether it converged (vanishing gradient, step or decrease).
    fn levenberg_marquardt(
        &mut self,
        scale: f64,
        max_iterations: usize,
        tolerance: f64,
    ) -> (usize, bool) {
        let mut cost = self.cost(&self.yaw_rad, &self.position_m, scale);
        let mut iterations = 0;
        let mut lambda = 1e-4;
        let mut system = self.normal_equations(scale);
        while iterations < max_iterations {
            let gradient_norm = system.rhs.iter().map(|g| g.amax()).fold(0.0, f64::max);
            if gradient_norm <= 1e-12 {
                return (iterations, true);
            }
            iterations += 1;
            let step = solve_block_sparse(system.damped(lambda));
            let Some(step) = step.filter(|s| s.iter().all(|d| d.iter().all(|x| x.is_finite())))
            else {
                lambda *= 10.0;
                if lambda > 1e12 {
                    return (iterations, false);
                }
                continue;
            };
            let yaw: Vec<f64> = (self.yaw_rad.iter().zip(&step))
                .map(|(y, d)| wrap_angle(y + d[0]))
                .collect();
            let position: Vec<Vector3<f64>> = (self.position_m.iter().zip(&step))
                .map(|(p, d)| p + d.fixed_rows::<3>(1))
                .collect();
            let new_cost = self.cost(&yaw, &position, scale);
            if new_cost < cost {
                let decrease = cost - new_cost;
                let step_max = step.iter().map(|d| d.amax()).fold(0.0, f64::max);
                self.yaw_rad = yaw;
                self.position_m = position;
                cost = new_cost;
                lambda = (lambda * 0.1).max(1e-12);
                if decrease <= tolerance * cost || step_max < 1e-12 {
                    return (iterations, true);
                }
                system = self.normal_equations(scale);
            } else {
                lambda *= 10.0;
                if lambda > 1e12 {
                    // No decrease even along a tiny gradient step: at a minimum to rounding.
                    return (iterations, true);
                }
            }
        }
        (iterations, false)
    }

    fn check_indices(&self, i: usize, j: usize) -> Result<(), PoseGraphError> {
        let len = self.nodes.len();
        for index in [i, j] {
            if index >= len {
                return Err(PoseGraphError::NodeOutOfRange { index, len });
            }
        }
        if i == j {
            return Err(PoseGraphError::SelfEdge(i));
        }
        Ok(())
    }

    fn push_edge(
        &mut self,
        i: usize,
        j: usize,
        t_i_j: &Isometry3<f64>,
        noise: EdgeNoise,
        kind: EdgeKind,
    ) -> Result<(), PoseGraphError> {
        if !noise.is_valid() {
            return Err(PoseGraphError::InvalidNoise {
                yaw_std_rad: noise.yaw_std_rad,
                position_std_m: noise.position_std_m,
            });
        }
        if !se3::is_finite(t_i_j) {
            return Err(PoseGraphError::NonFiniteMeasurement);
        }
        let (yaw_rad, position_m) = self.nodes[i].measurement(t_i_j);
        self.edges.push(Edge {
            i,
            j,
            kind,
            yaw_rad,
            position_m,
            inv_yaw_std: 1.0 / noise.yaw_std_rad,
            inv_position_std: 1.0 / noise.position_std_m,
        });
        Ok(())
    }

    /// Whitened residual and Jacobians (wrt `[ψ_i, p_i]`, `[ψ_j, p_j]`) of edge e at a state.
    fn whitened(
        &self,
        e: &Edge,
        yaw: &[f64],
        position: &[Vector3<f64>],
    ) -> (Vector4<f64>, Matrix4<f64>, Matrix4<f64>) {
        let (r, ji, jj) = edge_residual(
            &self.nodes[e.i].r_rp,
            yaw[e.i],
            &position[e.i],
            yaw[e.j],
            &position[e.j],
            e.yaw_rad,
            &e.position_m,
        );
        let w = Vector4::new(
            e.inv_yaw_std,
            e.inv_position_std,
            e.inv_position_std,
            e.inv_position_std,
        );
        let wm = Matrix4::from_diagonal(&w);
        (r.component_mul(&w), wm * ji, wm * jj)
    }

    /// `(ρ(s), ρ'(s))` of an edge with squared whitened residual s, loop kernel scale `scale`.
    fn kernel(kind: EdgeKind, s: f64, scale: f64) -> (f64, f64) {
        match kind {
            EdgeKind::Odometry => (s, 1.0),
            EdgeKind::Loop => {
                let c2 = scale * scale;
                (c2 * (s / c2).ln_1p(), 1.0 / (1.0 + s / c2))
            }
        }
    }

    fn cost(&self, yaw: &[f64], position: &[Vector3<f64>], scale: f64) -> f64 {
        0.5 * self
            .edges
            .iter()
            .map(|e| {
                let (r, _, _) = self.whitened(e, yaw, position);
                Self::kernel(e.kind, r.norm_squared(), scale).0
            })
            .sum::<f64>()
    }

    /// `H = Σ w Jᵀ J`, right-hand side `−Σ w Jᵀ r` at the current estimate; node 0 is fixed.
    fn normal_equations(&self, scale: f64) -> BlockSystem {
        let n = self.nodes.len();
        let mut free = vec![true; n];
        if let Some(f) = free.first_mut() {
            *f = false;
        }
        let mut sys = BlockSystem {
            diag: vec![Matrix4::zeros(); n],
            off: vec![Vec::new(); n],
            rhs: vec![Vector4::zeros(); n],
            free,
        };
        for e in &self.edges {
            let (r, ji, jj) = self.whitened(e, &self.yaw_rad, &self.position_m);
            let w = Self::kernel(e.kind, r.norm_squared(), scale).1;
            let (wji, wjj) = (ji.transpose() * w, jj.transpose() * w);
            if sys.free[e.i] {
                sys.diag[e.i] += wji * ji;
                sys.rhs[e.i] -= wji * r;
            }
            if sys.free[e.j] {
                sys.diag[e.j] += wjj * jj;
                sys.rhs[e.j] -= wjj * r;
            }
            if sys.free[e.i] && sys.free[e.j] {
                let h_ij = wji * jj;
                add_block(&mut sys.off[e.i], e.j, &h_ij);
                add_block(&mut sys.off[e.j], e.i, &h_ij.transpose());
            }
        }
        sys
    }

    fn summary(
        &self,
        initial_cost: f64,
        final_cost: f64,
        iterations: usize,
        converged: bool,
    ) -> OptimizeSummary {
        let loop_edge_weights: Vec<f64> = (self.edges.iter())
            .filter(|e| e.kind == EdgeKind::Loop)
            .map(|e| {
                let (r, _, _) = self.whitened(e, &self.yaw_rad, &self.position_m);
                Self::kernel(e.kind, r.norm_squared(), self.loop_cauchy_scale).1
            })
            .collect();
        let rejected_loop_edges = loop_edge_weights
            .iter()
            .filter(|&&w| w < REJECTED_WEIGHT)
            .count();
        OptimizeSummary {
            initial_cost,
            final_cost,
            iterations,
            converged,
            loop_edge_weights,
            rejected_loop_edges,
        }
    }
}

/// The ZYX yaw of a rotation matrix, rad: `atan2(R[1,0], R[0,0])`.
pub(crate) fn yaw_of(r: &Matrix3<f64>) -> f64 {
    r[(1, 0)].atan2(r[(0, 0)])
}

/// Rotation by `yaw` rad about world z.
fn rz(yaw: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
}

/// An angle wrapped into (−π, π], rad.
pub(crate) fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w > PI { w - TAU } else { w }
}

/// Unwhitened residual `[wrap(ψ_j − ψ_i − ψ̂); R_iᵀ(p_j − p_i) − p̂]` with `R_i = Rz(ψ_i) R_rp,i`,
/// and its Jacobians wrt `[ψ_i, p_i]` and `[ψ_j, p_j]`.
fn edge_residual(
    r_rp_i: &Matrix3<f64>,
    yaw_i: f64,
    p_i: &Vector3<f64>,
    yaw_j: f64,
    p_j: &Vector3<f64>,
    yaw_meas: f64,
    position_meas: &Vector3<f64>,
) -> (Vector4<f64>, Matrix4<f64>, Matrix4<f64>) {
    let (s, c) = yaw_i.sin_cos();
    let rz_t = Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
    let d_rz_t = Matrix3::new(-s, c, 0.0, -c, -s, 0.0, 0.0, 0.0, 0.0);
    let d = p_j - p_i;
    let r_i_t = r_rp_i.transpose() * rz_t;
    let r_p = r_i_t * d - position_meas;
    let d_rp_d_yaw_i = r_rp_i.transpose() * (d_rz_t * d);
    let r = Vector4::new(wrap_angle(yaw_j - yaw_i - yaw_meas), r_p.x, r_p.y, r_p.z);
    let mut ji = Matrix4::zeros();
    let mut jj = Matrix4::zeros();
    ji[(0, 0)] = -1.0;
    jj[(0, 0)] = 1.0;
    ji.fixed_view_mut::<3, 1>(1, 0).copy_from(&d_rp_d_yaw_i);
    ji.fixed_view_mut::<3, 3>(1, 1).copy_from(&(-r_i_t));
    jj.fixed_view_mut::<3, 3>(1, 1).copy_from(&r_i_t);
    (r, ji, jj)
}

/// Adds `m` to the block of `row` at column node `col`, creating it if absent.
fn add_block(row: &mut Vec<(usize, Matrix4<f64>)>, col: usize, m: &Matrix4<f64>) {
    match row.iter_mut().find(|(c, _)| *c == col) {
        Some((_, b)) => *b += m,
        None => row.push((col, *m)),
    }
}

/// A symmetric block-sparse linear system `A x = rhs` with 4 × 4 blocks, one block row per node.
#[derive(Clone, Debug)]
struct BlockSystem {
    /// `A_vv`.
    diag: Vec<Matrix4<f64>>,
    /// Row v's off-diagonal blocks `(u, A_vu)`; symmetric: `off[u]` holds `(v, A_vuᵀ)`.
    off: Vec<Vec<(usize, Matrix4<f64>)>>,
    rhs: Vec<Vector4<f64>>,
    /// Fixed nodes are not unknowns (their solution is 0) and have no blocks.
    free: Vec<bool>,
}

impl BlockSystem {
    /// A copy with Marquardt's damping `λ max(A_kk, 1e-9)` added to the diagonal.
    fn damped(&self, lambda: f64) -> Self {
        let mut sys = self.clone();
        for d in &mut sys.diag {
            for k in 0..4 {
                d[(k, k)] += lambda * d[(k, k)].max(1e-9);
            }
        }
        sys
    }
}

/// One eliminated node: `L_vv⁻¹`, the forward-substituted `y_v` and the column `(u, L_uv)`.
struct Eliminated {
    v: usize,
    l_inv: Matrix4<f64>,
    y: Vector4<f64>,
    column: Vec<(usize, Matrix4<f64>)>,
}

/// Solves a symmetric positive-definite block system by sparse block Cholesky factorisation in a
/// greedy minimum-degree elimination order (see the module documentation). `None` if a pivot
/// block is not positive definite.
fn solve_block_sparse(mut sys: BlockSystem) -> Option<Vec<Vector4<f64>>> {
    let n = sys.diag.len();
    let mut active = sys.free.clone();
    let mut heap: BinaryHeap<Reverse<(usize, usize)>> = (0..n)
        .filter(|&v| active[v])
        .map(|v| Reverse((sys.off[v].len(), v)))
        .collect();
    let mut order: Vec<Eliminated> = Vec::with_capacity(n);
    while let Some(Reverse((degree, v))) = heap.pop() {
        if !active[v] || degree != sys.off[v].len() {
            continue; // eliminated, or a stale degree (a fresher entry is in the heap)
        }
        active[v] = false;
        let l = sys.diag[v].cholesky()?.l();
        let l_inv = l.solve_lower_triangular(&Matrix4::identity())?;
        let y = l_inv * sys.rhs[v];
        let neighbours = std::mem::take(&mut sys.off[v]);
        // L_uv = A_uv L_vv⁻ᵀ = (L_vv⁻¹ A_vu)ᵀ.
        let column: Vec<(usize, Matrix4<f64>)> = neighbours
            .iter()
            .map(|(u, a_vu)| (*u, (l_inv * a_vu).transpose()))
            .collect();
        for (u, l_uv) in &column {
            let row = &mut sys.off[*u];
            if let Some(k) = row.iter().position(|(c, _)| *c == v) {
                row.swap_remove(k);
            }
            sys.rhs[*u] -= l_uv * y;
            sys.diag[*u] -= l_uv * l_uv.transpose();
            for (w, l_wv) in &column {
                if w != u {
                    add_block(&mut sys.off[*u], *w, &(-(l_uv * l_wv.transpose())));
                }
            }
        }
        for (u, _) in &column {
            heap.push(Reverse((sys.off[*u].len(), *u)));
        }
        order.push(Eliminated {
            v,
            l_inv,
            y,
            column,
        });
    }
    let mut x = vec![Vector4::zeros(); n];
    for e in order.iter().rev() {
        let mut b = e.y;
        for (u, l_uv) in &e.column {
            b -= l_uv.transpose() * x[*u];
        }
        x[e.v] = e.l_inv.transpose() * b;
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use std::time::Instant;

    /// Deterministic xorshift64* in [−1, 1).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let u = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11;
            2.0 * (u as f64 / (1u64 << 53) as f64) - 1.0
        }
    }

    fn ypr(yaw: f64, pitch: f64, roll: f64, p: Vector3<f64>) -> Isometry3<f64> {
        // nalgebra's from_euler_angles(roll, pitch, yaw) is Rz(yaw) Ry(pitch) Rx(roll) (ZYX).
        Isometry3::from_parts(
            Translation3::from(p),
            UnitQuaternion::from_euler_angles(roll, pitch, yaw),
        )
    }

    /// Roll-pitch part `Rz(ψ)ᵀ R` of a pose's rotation.
    fn roll_pitch(t: &Isometry3<f64>) -> Matrix3<f64> {
        let r = t.rotation.to_rotation_matrix().into_inner();
        rz(-yaw_of(&r)).to_rotation_matrix().into_inner() * r
    }

    fn yaw_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
        let ya = yaw_of(&a.rotation.to_rotation_matrix().into_inner());
        let yb = yaw_of(&b.rotation.to_rotation_matrix().into_inner());
        wrap_angle(ya - yb).abs()
    }

    const NOISE: EdgeNoise = EdgeNoise {
        yaw_std_rad: 0.5 * PI / 180.0,
        position_std_m: 0.05,
    };

    /// A tilted circle of radius 3 m, `n` nodes per lap, `laps` laps: the truth, and an odometry
    /// with 0.2°/node yaw drift, 2 % scale error and a constant bias per step.
    fn loop_trajectory(n: usize, laps: usize) -> (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>) {
        let truth: Vec<Isometry3<f64>> = (0..n * laps)
            .map(|k| {
                let th = TAU * k as f64 / n as f64;
                let p = Vector3::new(3.0 * th.cos(), 3.0 * th.sin(), 1.0 + 0.2 * (2.0 * th).sin());
                ypr(
                    th + PI / 2.0,
                    0.06 * (2.0 * th).cos() + 0.03,
                    0.1 * th.sin(),
                    p,
                )
            })
            .collect();
        let drift = 0.2 * PI / 180.0;
        let mut odometry = vec![truth[0]];
        for k in 1..truth.len() {
            let dz = rz(k as f64 * drift);
            let step = truth[k].translation.vector - truth[k - 1].translation.vector;
            let p = odometry[k - 1].translation.vector
                + dz * step * 1.02
                + Vector3::new(0.004, -0.003, 0.002);
            odometry.push(Isometry3::from_parts(
                Translation3::from(p),
                dz * truth[k].rotation,
            ));
        }
        (truth, odometry)
    }

    fn chain(odometry: &[Isometry3<f64>]) -> PoseGraph {
        chain_with(odometry, NOISE)
    }

    fn chain_with(odometry: &[Isometry3<f64>], noise: EdgeNoise) -> PoseGraph {
        let mut g = PoseGraph::new();
        for t in odometry {
            g.add_node(*t);
        }
        for k in 1..odometry.len() {
            g.add_odometry_edge(k - 1, k, noise).unwrap();
        }
        g
    }

    fn position_error(g: &PoseGraph, truth: &[Isometry3<f64>], k: usize) -> f64 {
        (g.pose(k).translation.vector - truth[k].translation.vector).norm()
    }

    #[test]
    fn residual_jacobians_match_central_differences() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for _ in 0..50 {
            let rp = ypr(0.0, 0.5 * rng.next(), 0.6 * rng.next(), Vector3::zeros());
            let r_rp = rp.rotation.to_rotation_matrix().into_inner();
            let mut x = [0.0; 8]; // [ψ_i, p_i, ψ_j, p_j]
            for v in &mut x {
                *v = 3.0 * rng.next();
            }
            let yaw_meas = 3.0 * rng.next();
            let p_meas = Vector3::new(rng.next(), rng.next(), rng.next());
            let eval = |x: &[f64; 8]| {
                edge_residual(
                    &r_rp,
                    x[0],
                    &Vector3::new(x[1], x[2], x[3]),
                    x[4],
                    &Vector3::new(x[5], x[6], x[7]),
                    yaw_meas,
                    &p_meas,
                )
            };
            let (r0, ji, jj) = eval(&x);
            // Stay away from the wrap discontinuity of r_ψ.
            if r0[0].abs() > 3.0 {
                continue;
            }
            let h = 1e-6;
            for k in 0..8 {
                let (mut xp, mut xm) = (x, x);
                xp[k] += h;
                xm[k] -= h;
                let numeric = (eval(&xp).0 - eval(&xm).0) / (2.0 * h);
                let analytic: Vector4<f64> = if k < 4 {
                    ji.column(k).into()
                } else {
                    jj.column(k - 4).into()
                };
                assert!(
                    (numeric - analytic).amax() < 1e-7,
                    "variable {k}: numeric {numeric} analytic {analytic}"
                );
            }
        }
    }

    #[test]
    fn whitened_jacobians_match_central_differences() {
        // Through the graph's own residual (yaw measurement from a loop edge, whitening).
        let (_, odometry) = loop_trajectory(40, 1);
        let mut g = chain(&odometry[..6]);
        let t = ypr(0.3, 0.1, -0.2, Vector3::new(0.5, -1.0, 0.2));
        g.add_loop_edge(5, 1, &t, NOISE).unwrap();
        for e in g.edges.clone() {
            let (_, ji, jj) = g.whitened(&e, &g.yaw_rad, &g.position_m);
            let h = 1e-6;
            for (node, jac) in [(e.i, ji), (e.j, jj)] {
                for k in 0..4 {
                    let perturbed = |sign: f64| {
                        let (mut yaw, mut pos) = (g.yaw_rad.clone(), g.position_m.clone());
                        if k == 0 {
                            yaw[node] += sign * h;
                        } else {
                            pos[node][k - 1] += sign * h;
                        }
                        g.whitened(&e, &yaw, &pos).0
                    };
                    let numeric = (perturbed(1.0) - perturbed(-1.0)) / (2.0 * h);
                    assert!(
                        (numeric - jac.column(k)).amax() < 1e-5 * jac.amax().max(1.0),
                        "edge {}-{} node {node} variable {k}",
                        e.i,
                        e.j
                    );
                }
            }
        }
    }

    #[test]
    fn sparse_solve_matches_dense_cholesky() {
        let mut rng = Rng(7);
        let n = 30;
        let mut edges: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
        edges.extend([(0, 29), (3, 20), (7, 25), (10, 11), (12, 28)]);
        let mut sys = BlockSystem {
            diag: vec![Matrix4::zeros(); n],
            off: vec![Vec::new(); n],
            rhs: (0..n)
                .map(|_| Vector4::new(rng.next(), rng.next(), rng.next(), rng.next()))
                .collect(),
            free: (0..n).map(|v| v != 4).collect(),
        };
        sys.rhs[4] = Vector4::zeros();
        for &(i, j) in &edges {
            let mut jm = Matrix4::zeros();
            jm.iter_mut().for_each(|x| *x = rng.next());
            let (ji, jj) = (jm, Matrix4::identity() + 0.3 * jm.transpose());
            if sys.free[i] {
                sys.diag[i] += ji.transpose() * ji;
            }
            if sys.free[j] {
                sys.diag[j] += jj.transpose() * jj;
            }
            if sys.free[i] && sys.free[j] {
                add_block(&mut sys.off[i], j, &(ji.transpose() * jj));
                add_block(&mut sys.off[j], i, &(jj.transpose() * ji));
            }
        }
        let mut dense = DMatrix::<f64>::identity(4 * n, 4 * n);
        let mut b = nalgebra::DVector::<f64>::zeros(4 * n);
        for v in 0..n {
            if sys.free[v] {
                dense
                    .fixed_view_mut::<4, 4>(4 * v, 4 * v)
                    .copy_from(&sys.diag[v]);
            }
            b.fixed_rows_mut::<4>(4 * v).copy_from(&sys.rhs[v]);
            for (u, a) in &sys.off[v] {
                dense.fixed_view_mut::<4, 4>(4 * v, 4 * u).copy_from(a);
            }
        }
        let expected = dense.cholesky().expect("positive definite").solve(&b);
        let x = solve_block_sparse(sys).expect("positive definite");
        for (v, xv) in x.iter().enumerate() {
            let e: Vector4<f64> = expected.fixed_rows::<4>(4 * v).into();
            assert!((xv - e).amax() < 1e-9 * e.amax().max(1.0), "node {v}");
        }
        assert_eq!(x[4], Vector4::zeros());
    }

    /// A loop edge added weak pulls the graph a little; given its own deviations back
    /// (`set_edge_noise`, by the index `add_loop_edge` returned) it pulls as one added so.
    #[test]
    fn a_loop_edge_weakened_and_restored_pulls_as_its_deviations_say() {
        let (truth, odometry) = loop_trajectory(40, 1);
        let last = truth.len() - 1;
        let t_last_0 = truth[last].inv_mul(&truth[0]);
        let weak = NOISE.scaled(10.0);
        let solved = |noise: EdgeNoise, restore: bool| {
            let mut g = chain(&odometry);
            let before = g.loop_edge_count();
            let ix = g.add_loop_edge(last, 0, &t_last_0, noise).unwrap();
            assert_eq!(g.loop_edge_count(), before + 1);
            if restore {
                g.set_edge_noise(ix, NOISE);
                // Invalid deviations or an index beyond the edges change nothing.
                g.set_edge_noise(
                    ix,
                    EdgeNoise {
                        yaw_std_rad: 0.0,
                        ..NOISE
                    },
                );
                g.set_edge_noise(ix + 1, weak);
            }
            g.optimize(50);
            g
        };
        let (tight, weakened, restored) = (
            solved(NOISE, false),
            solved(weak, false),
            solved(weak, true),
        );
        let (p_tight, p_weak, p_restored) = (
            position_error(&tight, &truth, last),
            position_error(&weakened, &truth, last),
            position_error(&restored, &truth, last),
        );
        println!("last node off by {p_tight} / {p_weak} / {p_restored} m");
        assert!(p_weak > 2.0 * p_tight, "{p_tight} {p_weak}");
        for k in 0..tight.len() {
            let d = tight.pose(k).inverse() * restored.pose(k);
            assert!(d.translation.vector.norm() < 1e-12, "node {k}: {d}");
        }
    }

    #[test]
    fn loop_closure_removes_drift() {
        let (truth, odometry) = loop_trajectory(40, 1);
        let last = truth.len() - 1;
        let mut g = chain(&odometry);
        let t_last_0 = truth[last].inv_mul(&truth[0]);
        g.add_loop_edge(last, 0, &t_last_0, NOISE).unwrap();
        let (p_before, yaw_before) = (
            position_error(&g, &truth, last),
            yaw_error(&g.pose(last), &truth[last]),
        );
        assert!(
            p_before > 0.3 && yaw_before > 0.1,
            "{p_before} {yaw_before}"
        );
        let summary = g.optimize(50);
        let (p_after, yaw_after) = (
            position_error(&g, &truth, last),
            yaw_error(&g.pose(last), &truth[last]),
        );
        println!(
            "{summary:?}\nposition {p_before} -> {p_after} m, yaw {yaw_before} -> {yaw_after} rad"
        );
        assert!(summary.converged);
        assert!(summary.final_cost < 0.5 * summary.initial_cost);
        assert!(p_after < p_before / 5.0, "{p_before} -> {p_after}");
        assert!(yaw_after < yaw_before / 5.0, "{yaw_before} -> {yaw_after}");
        assert_eq!(summary.rejected_loop_edges, 0);
        assert_eq!(
            (g.yaw_rad[0], g.position_m[0]),
            (g.nodes[0].yaw_odometry_rad, odometry[0].translation.vector)
        );
        assert!((g.pose(0).to_homogeneous() - odometry[0].to_homogeneous()).amax() < 1e-15);
        for (k, t) in odometry.iter().enumerate() {
            let d = roll_pitch(&g.pose(k)) - roll_pitch(t);
            assert!(
                d.amax() < 1e-12,
                "node {k}: roll/pitch changed by {}",
                d.amax()
            );
        }
        // Every node got closer to the truth than the odometry was, on average.
        let mean = |f: &dyn Fn(usize) -> f64| (0..g.len()).map(f).sum::<f64>() / g.len() as f64;
        let odo_err =
            mean(&|k| (odometry[k].translation.vector - truth[k].translation.vector).norm());
        let opt_err = mean(&|k| position_error(&g, &truth, k));
        assert!(opt_err < odo_err / 3.0, "{odo_err} -> {opt_err}");

        // A node added afterwards starts at the odometry carried by the latest correction and
        // keeps the graph at its minimum.
        let next = ypr(0.5, 0.02, 0.01, Vector3::new(3.0, 0.2, 1.0));
        let k = g.add_node(next);
        g.add_odometry_edge(k - 1, k, NOISE).unwrap();
        let expected = g.correction(k - 1) * next;
        assert!((g.pose(k).to_homogeneous() - expected.to_homogeneous()).amax() < 1e-12);
        let again = g.optimize(50);
        assert!(
            (again.initial_cost - summary.final_cost).abs() < 1e-9 * summary.final_cost.max(1.0)
        );
    }

    #[test]
    fn wrong_loop_edge_is_rejected() {
        let (truth, odometry) = loop_trajectory(40, 1);
        let last = truth.len() - 1;
        let t_last_0 = truth[last].inv_mul(&truth[0]);
        let mut reference = chain(&odometry);
        reference.add_loop_edge(last, 0, &t_last_0, NOISE).unwrap();
        reference.optimize(50);

        let mut g = chain(&odometry);
        g.add_loop_edge(last, 0, &t_last_0, NOISE).unwrap();
        // 60° and 2 m off.
        let off = Isometry3::from_parts(Translation3::new(1.2, -1.6, 0.0), rz(PI / 3.0));
        let wrong = truth[30].inv_mul(&truth[10]) * off;
        g.add_loop_edge(30, 10, &wrong, NOISE).unwrap();
        let summary = g.optimize(100);
        println!("{summary:?}");
        assert_eq!(summary.rejected_loop_edges, 1);
        assert!(
            summary.loop_edge_weights[0] > 0.5,
            "{:?}",
            summary.loop_edge_weights
        );
        assert!(
            summary.loop_edge_weights[1] < 0.05,
            "{:?}",
            summary.loop_edge_weights
        );
        let p_before = (odometry[last].translation.vector - truth[last].translation.vector).norm();
        assert!(position_error(&g, &truth, last) < p_before / 5.0);
        assert!(
            yaw_error(&g.pose(last), &truth[last]) < yaw_error(&odometry[last], &truth[last]) / 5.0
        );
        // Close to the solution without the wrong edge.
        let max_diff = (0..g.len())
            .map(|k| (g.pose(k).translation.vector - reference.pose(k).translation.vector).norm())
            .fold(0.0, f64::max);
        let max_yaw_diff = (0..g.len())
            .map(|k| yaw_error(&g.pose(k), &reference.pose(k)))
            .fold(0.0, f64::max);
        println!("max difference to the single-loop solution: {max_diff} m, {max_yaw_diff} rad");
        assert!(max_diff < 0.05 && max_yaw_diff < 0.3_f64.to_radians());
    }

    /// Odometry standard deviations 2.5 times too small for its drift: the closed loop is still
    /// the cost's minimum, but at the kernel's final scale the odometry's start lies in the basin
    /// of the open loop (plain IRLS there ends with the loop weighted 0.01 and the last node
    /// 0.16 m off); the graduated scale reaches the closed one, and still rejects a wrong loop.
    #[test]
    fn graduated_kernel_closes_a_loop_beyond_the_odometry_noise() {
        let (truth, odometry) = loop_trajectory(40, 1);
        let last = truth.len() - 1;
        let stiff = EdgeNoise {
            yaw_std_rad: 0.2_f64.to_radians(),
            position_std_m: 0.02,
        };
        let mut g = chain_with(&odometry, stiff);
        g.add_loop_edge(last, 0, &truth[last].inv_mul(&truth[0]), stiff)
            .unwrap();
        let off = Isometry3::from_parts(Translation3::new(1.2, -1.6, 0.0), rz(PI / 3.0));
        g.add_loop_edge(30, 10, &(truth[30].inv_mul(&truth[10]) * off), stiff)
            .unwrap();
        let summary = g.optimize(100);
        println!("{summary:?}");
        assert!(summary.converged && summary.final_cost <= summary.initial_cost);
        assert!(summary.loop_edge_weights[0] > 0.5, "{summary:?}");
        assert_eq!(summary.rejected_loop_edges, 1);
        let before = (odometry[last].translation.vector - truth[last].translation.vector).norm();
        assert!(position_error(&g, &truth, last) < before / 20.0);
        assert!(yaw_error(&g.pose(last), &truth[last]) < 0.5_f64.to_radians());
    }

    #[test]
    fn correction_maps_odometry_to_pose_about_z() {
        let (truth, odometry) = loop_trajectory(40, 1);
        let last = truth.len() - 1;
        let mut g = chain(&odometry);
        g.add_loop_edge(last, 0, &truth[last].inv_mul(&truth[0]), NOISE)
            .unwrap();
        g.optimize(50);
        let mut max_angle: f64 = 0.0;
        for k in 0..g.len() {
            let c = g.correction(k);
            let composed = c * g.odometry_pose(k);
            let d = composed.to_homogeneous() - g.pose(k).to_homogeneous();
            assert!(d.amax() < 1e-12, "node {k}: {}", d.amax());
            let q = c.rotation.quaternion();
            assert!(q.i.abs() < 1e-15 && q.j.abs() < 1e-15, "node {k}: {q:?}");
            max_angle = max_angle.max(c.rotation.angle());
        }
        // The corrections are not all trivial (the test would pass vacuously otherwise).
        assert!(max_angle > 2.0_f64.to_radians(), "{max_angle}");
        assert_eq!(g.correction(0), Isometry3::identity());
    }

    #[test]
    fn odometry_only_graph_stays_at_the_odometry() {
        let (_, odometry) = loop_trajectory(40, 2);
        let mut g = chain(&odometry);
        // Plus a few non-consecutive odometry edges.
        g.add_odometry_edge(3, 17, NOISE).unwrap();
        g.add_odometry_edge(50, 2, NOISE).unwrap();
        let summary = g.optimize(20);
        assert!(summary.initial_cost < 1e-20, "{summary:?}");
        assert!(summary.final_cost <= summary.initial_cost);
        assert_eq!(summary.rejected_loop_edges, 0);
        assert!(summary.loop_edge_weights.is_empty());
        for (k, t) in odometry.iter().enumerate() {
            let d = g.pose(k).to_homogeneous() - t.to_homogeneous();
            assert!(d.amax() < 1e-12, "node {k}: {}", d.amax());
            let c = g.correction(k).to_homogeneous() - Matrix4::identity();
            assert!(c.amax() < 1e-12, "node {k}");
        }
    }

    #[test]
    fn degenerate_graphs_and_bad_edges() {
        let mut g = PoseGraph::new();
        assert!(g.is_empty());
        let s = g.optimize(10);
        assert_eq!((s.iterations, s.initial_cost, s.final_cost), (0, 0.0, 0.0));
        let t = ypr(1.0, 0.1, 0.2, Vector3::new(1.0, 2.0, 3.0));
        assert_eq!(g.add_node(t), 0);
        g.optimize(10);
        assert!((g.pose(0).to_homogeneous() - t.to_homogeneous()).amax() < 1e-15);
        assert_eq!(
            g.add_odometry_edge(0, 0, NOISE),
            Err(PoseGraphError::SelfEdge(0))
        );
        assert_eq!(
            g.add_loop_edge(0, 1, &t, NOISE),
            Err(PoseGraphError::NodeOutOfRange { index: 1, len: 1 })
        );
        g.add_node(t * ypr(0.1, 0.0, 0.0, Vector3::x()));
        g.add_node(t);
        let bad = EdgeNoise {
            yaw_std_rad: 0.0,
            position_std_m: 0.1,
        };
        assert!(matches!(
            g.add_odometry_edge(0, 1, bad),
            Err(PoseGraphError::InvalidNoise { .. })
        ));
        let mut nan = t;
        nan.translation.vector.x = f64::NAN;
        assert_eq!(
            g.add_loop_edge(0, 1, &nan, NOISE),
            Err(PoseGraphError::NonFiniteMeasurement)
        );
        assert_eq!(g.edges.len(), 0);
        // Nodes without edges (and a loop between two nodes not connected to node 0) do not
        // make the solve fail.
        g.add_loop_edge(1, 2, &Isometry3::identity(), NOISE)
            .unwrap();
        let s = g.optimize(20);
        assert!(
            s.final_cost <= s.initial_cost && s.final_cost < 1e-12,
            "{s:?}"
        );
        assert!((g.pose(0).to_homogeneous() - t.to_homogeneous()).amax() < 1e-15);
        assert!(g.pose(1).translation.vector.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn relative_edges_and_set_estimate() {
        let (_, odometry) = loop_trajectory(40, 1);
        let mut g = PoseGraph::new();
        for t in &odometry[..10] {
            g.add_node(*t);
        }
        for k in 1..10 {
            let t = odometry[k - 1].inv_mul(&odometry[k]);
            g.add_relative_edge(k - 1, k, &t, NOISE).unwrap();
        }
        assert!(g.optimize(10).initial_cost < 1e-20);
        // Moved in yaw, position and (ignored) roll/pitch: the optimisation brings it back.
        let moved = odometry[6] * ypr(0.2, 0.3, -0.2, Vector3::new(0.3, -0.2, 0.1));
        g.set_estimate(6, &moved);
        assert!(yaw_error(&g.pose(6), &moved) < 1e-12);
        assert!((g.pose(6).translation.vector - moved.translation.vector).norm() < 1e-12);
        assert!((roll_pitch(&g.pose(6)) - roll_pitch(&odometry[6])).amax() < 1e-12);
        let s = g.optimize(30);
        assert!(s.initial_cost > 100.0 && s.final_cost < 1e-16, "{s:?}");
        for (k, t) in odometry[..10].iter().enumerate() {
            let d = g.pose(k).to_homogeneous() - t.to_homogeneous();
            assert!(d.amax() < 1e-8, "node {k}: {}", d.amax());
        }
        // A non-finite estimate is ignored.
        g.set_estimate(3, &Isometry3::translation(f64::NAN, 0.0, 0.0));
        assert!((g.pose(3).to_homogeneous() - odometry[3].to_homogeneous()).amax() < 1e-8);
    }

    #[test]
    fn wrap_angle_range() {
        for (a, w) in [
            (0.0, 0.0),
            (PI, PI),
            (-PI, PI),
            (3.0 * PI, PI),
            (0.5 + TAU, 0.5),
            (-0.5 - 2.0 * TAU, -0.5),
        ] {
            assert!(
                (wrap_angle(a) - w).abs() < 1e-12,
                "{a} -> {}",
                wrap_angle(a)
            );
        }
    }

    /// Several laps with a loop edge every few nodes of the later laps; prints the time
    /// (`--nocapture`), asserts only the result.
    #[test]
    fn optimize_time_200_and_400_nodes() {
        for n in [200, 400] {
            let per_lap = 50;
            let (truth, odometry) = loop_trajectory(per_lap, n / per_lap);
            let mut g = chain(&odometry);
            let loops: Vec<usize> = (0..10).map(|k| per_lap + k * (n - per_lap) / 10).collect();
            for &j in &loops {
                let i = j % per_lap;
                g.add_loop_edge(j, i, &truth[j].inv_mul(&truth[i]), NOISE)
                    .unwrap();
            }
            let start = Instant::now();
            let summary = g.optimize(50);
            let elapsed = start.elapsed();
            let last = n - 1;
            let before =
                (odometry[last].translation.vector - truth[last].translation.vector).norm();
            let after = position_error(&g, &truth, last);
            println!(
                "{n} nodes, {} loop edges: {:.2} ms, {} iterations, cost {:.1} -> {:.3}, \
                 last node error {before:.2} -> {after:.3} m",
                g.loop_edge_count(),
                elapsed.as_secs_f64() * 1e3,
                summary.iterations,
                summary.initial_cost,
                summary.final_cost
            );
            assert!(summary.converged, "{summary:?}");
            assert_eq!(summary.rejected_loop_edges, 0, "{summary:?}");
            assert!(after < before / 5.0, "{before} -> {after}");
        }
    }

    /// Nodes moved by the odometry keep their corrections, and the odometry edges among them are
    /// measured from the new poses: a chain moved as a whole stays at its odometry (no cost),
    /// and an edge to a node not moved is left as it was.
    #[test]
    fn moved_nodes_keep_their_corrections_and_their_edges_follow() {
        let (truth, odometry) = loop_trajectory(12, 2);
        let n = odometry.len();
        let refined: Vec<Isometry3<f64>> = (odometry.iter().enumerate())
            .map(|(k, t)| {
                let k = k as f64;
                let nudge = ypr(
                    0.01 * k.sin(),
                    0.002 * k.cos(),
                    -0.003,
                    Vector3::new(0.02 * k.cos(), -0.01, 0.005 * k),
                );
                t * nudge
            })
            .collect();
        // Every node moved: a graph without loops sits at its new odometry.
        let mut g = chain(&odometry);
        for (k, t) in refined.iter().enumerate() {
            g.move_odometry(k, t);
        }
        g.remeasure_odometry_edges(&(0..n).collect::<Vec<_>>());
        assert!(g.cost(&g.yaw_rad, &g.position_m, 1.0) < 1e-20);
        for (k, t) in refined.iter().enumerate() {
            assert!((g.pose(k).translation.vector - t.translation.vector).norm() < 1e-12);
            assert!(yaw_error(&g.pose(k), t) < 1e-12);
            assert!((roll_pitch(&g.pose(k)) - roll_pitch(t)).norm() < 1e-12);
        }
        // After a loop, some nodes moved: their corrections are kept, the edges among them
        // follow the new poses, the edges to the others are left.
        let mut g = chain(&odometry);
        g.add_loop_edge(n - 1, 0, &truth[n - 1].inv_mul(&truth[0]), NOISE)
            .unwrap();
        g.optimize(20);
        let before: Vec<_> = (0..n).map(|k| g.correction(k)).collect();
        let edges_before = g.edges.clone();
        let moved = [14, 15, 16];
        for &k in &moved {
            g.move_odometry(k, &refined[k]);
        }
        g.remeasure_odometry_edges(&moved);
        for (k, c) in before.iter().enumerate() {
            let d = c.inverse() * g.correction(k);
            assert!(
                d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-12,
                "{k}"
            );
        }
        for (e, old) in g.edges.iter().zip(&edges_before) {
            let inside = moved.contains(&e.i) && moved.contains(&e.j);
            if inside {
                let t_i_j = refined[e.i].inv_mul(&refined[e.j]);
                assert!((e.position_m - t_i_j.translation.vector).norm() < 1e-12);
                assert!(
                    (e.position_m - old.position_m).norm() > 1e-4,
                    "{} {}",
                    e.i,
                    e.j
                );
            } else {
                assert_eq!((e.yaw_rad, e.position_m), (old.yaw_rad, old.position_m));
            }
        }
        // Not finite: ignored.
        let mut nan = refined[3];
        nan.translation.vector.x = f64::NAN;
        let pose = g.pose(3);
        g.move_odometry(3, &nan);
        assert_eq!(g.pose(3), pose);
    }
}
