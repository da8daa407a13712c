//! [`SemidenseKeyframe`]: candidates, per-pixel estimates, observe / propagate / map.

use super::epipolar::{ViewGeometry, normalised_footprint, to_pixel};
use super::fusion::{
    Cover, CoversMut, Estimate, Run, append_cover, covers_from_scratch, run_from_covers,
};
use super::search::{KeyframePixel, Outcome, PATCH, ViewContext, search_pixel, template};
use super::{MapPoint, ObserveStats, SemidenseConfig, SemidenseMap, ViewSkip};
use crate::camera::CameraModel;
use crate::geometry::se3;
use crate::image::Image;
use nalgebra::{Isometry3, Matrix2, Point3, Vector2};
use rayon::prelude::*;

/// Estimates kept per pixel (one per view; when full, a new estimate replaces the least certain).
const MAX_ESTIMATES: usize = 24;
/// `index` value of a pixel that is not a candidate.
const NO_CANDIDATE: u32 = u32::MAX;

/// A candidate (high-gradient) pixel of the keyframe.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    x: u32,
    y: u32,
    /// Normalised ray (z = 1).
    ray: Vector2<f64>,
    /// `d normalised / d pixel`.
    jinv: Matrix2<f64>,
    /// Unit gradient.
    grad_dir: [f32; 2],
}

/// Estimates of one candidate and their current run.
#[derive(Clone, Copy, Debug)]
struct PixelState {
    count: u8,
    /// Views in which the epipolar curve was scanned.
    searches: u8,
    estimates: [Estimate; MAX_ESTIMATES],
    /// How many estimates (and their total weight) cover the left end of `estimates[i]`'s
    /// interval (fusion module's `Cover`, kept apart to keep the state small).
    cover_votes: [u8; MAX_ESTIMATES],
    cover_weight: [f32; MAX_ESTIMATES],
    prior: Option<Estimate>,
    prior_cover: Cover,
    run: Run,
}

impl PixelState {
    const EMPTY: PixelState = PixelState {
        count: 0,
        searches: 0,
        estimates: [Estimate {
            rho: 0.0,
            sigma: 0.0,
        }; MAX_ESTIMATES],
        cover_votes: [0; MAX_ESTIMATES],
        cover_weight: [0.0; MAX_ESTIMATES],
        prior: None,
        prior_cover: Cover {
            votes: 0,
            weight: 0.0,
        },
        run: Run::EMPTY,
    };

    /// Recomputes the covers (O(n²)) and the run.
    fn refuse(&mut self, cfg: &SemidenseConfig) {
        let n = self.count as usize;
        self.prior_cover = covers_from_scratch(
            &self.estimates[..n],
            self.prior,
            cfg.consistency_sigmas,
            CoversMut {
                votes: &mut self.cover_votes[..n],
                weight: &mut self.cover_weight[..n],
            },
        );
        self.update_run(cfg);
    }

    fn update_run(&mut self, cfg: &SemidenseConfig) {
        let n = self.count as usize;
        self.run = run_from_covers(
            &self.estimates[..n],
            &self.cover_votes[..n],
            &self.cover_weight[..n],
            self.prior,
            self.prior_cover,
            cfg.consistency_sigmas,
            cfg.search_sigmas,
        );
    }

    /// Adds an estimate and updates the run (eq. 27 over the consistent run).
    fn insert(&mut self, e: Estimate, cfg: &SemidenseConfig) {
        let n = self.count as usize;
        if n < MAX_ESTIMATES {
            self.estimates[n] = e;
            self.count += 1;
            append_cover(
                &self.estimates[..=n],
                self.prior,
                cfg.consistency_sigmas,
                CoversMut {
                    votes: &mut self.cover_votes[..=n],
                    weight: &mut self.cover_weight[..=n],
                },
                &mut self.prior_cover,
            );
            self.update_run(cfg);
        } else if let Some(worst) = self
            .estimates
            .iter_mut()
            .max_by(|a, b| a.sigma.total_cmp(&b.sigma))
            .filter(|w| w.sigma > e.sigma)
        {
            *worst = e;
            self.refuse(cfg);
        }
    }
}

/// One keyframe under construction: its image, camera, pose, candidate (high-gradient) pixels and
/// per-pixel inverse-depth estimates (module doc: [`super`]). Buffers are allocated once in
/// [`new`](Self::new); [`observe`](Self::observe) allocates nothing.
#[derive(Clone, Debug)]
pub struct SemidenseKeyframe {
    cfg: SemidenseConfig,
    camera: CameraModel,
    t_world_cam: Isometry3<f64>,
    /// Pose finite and camera usable.
    valid: bool,
    image: Image<f32>,
    footprint: [f64; 4],
    candidates: Vec<Candidate>,
    /// Zero-mean 7x7 template of each candidate.
    templates: Vec<[f32; PATCH]>,
    states: Vec<PixelState>,
    /// Candidate index of every pixel (row-major), or `NO_CANDIDATE`.
    index: Vec<u32>,
    range_m_inv: (f64, f64),
    /// The current view's estimate of each candidate, before it is fused (`observe`).
    pending: Vec<Option<Estimate>>,
    /// Ratios of the current view's estimates to their propagated priors (`view_scale`).
    ratios: Vec<f32>,
}

fn camera_is_usable(c: &CameraModel) -> bool {
    [c.fx, c.fy, c.cx, c.cy].iter().all(|v| v.is_finite()) && c.fx > 0.0 && c.fy > 0.0
}

impl SemidenseKeyframe {
    /// Selects the candidates of `image` (raw, distorted, gray levels 0..255; its size must be the
    /// camera's, else the keyframe has no candidates) taken at camera pose `t_world_cam`.
    pub fn new(
        image: &Image<f32>,
        camera: &CameraModel,
        t_world_cam: &Isometry3<f64>,
        cfg: &SemidenseConfig,
    ) -> Self {
        let (w, h) = (camera.width, camera.height);
        let size_ok = image.width() == w && image.height() == h;
        let footprint = if size_ok && camera_is_usable(camera) {
            normalised_footprint(camera)
        } else {
            None
        };
        let valid = footprint.is_some() && se3::is_finite(t_world_cam);
        let mut kf = SemidenseKeyframe {
            cfg: cfg.clone(),
            camera: *camera,
            t_world_cam: *t_world_cam,
            valid,
            image: if size_ok {
                image.clone()
            } else {
                Image::new(0, 0)
            },
            footprint: footprint.unwrap_or([0.0; 4]),
            candidates: Vec::new(),
            templates: Vec::new(),
            states: Vec::new(),
            index: Vec::new(),
            range_m_inv: (0.0, 1.0),
            pending: Vec::new(),
            ratios: Vec::new(),
        };
        kf.set_inv_depth_range(cfg.min_inv_depth_m_inv, cfg.max_inv_depth_m_inv);
        if valid {
            kf.select_candidates();
        }
        kf
    }

    /// Candidates: gradient ≥ `min_gradient` (raised until at most `max_candidates` pass), a
    /// `border_px` margin (at least the 7x7 template's), and a ray that unprojects.
    fn select_candidates(&mut self) {
        let (w, h) = (self.image.width(), self.image.height());
        let b = self.cfg.border_px.max(4);
        if w <= 2 * b || h <= 2 * b {
            return;
        }
        let img = &self.image;
        let grad = |x: usize, y: usize| {
            let gx = 0.5 * (img.get(x + 1, y) - img.get(x - 1, y));
            let gy = 0.5 * (img.get(x, y + 1) - img.get(x, y - 1));
            (gx, gy)
        };
        // The eligible pixels (row-major; with cells, the strongest of each cell, cells
        // row-major) and their squared gradients.
        let min_g = self.cfg.min_gradient.max(0.0);
        let cell = self.cfg.candidate_cell_px.max(1);
        let mut eligible: Vec<(usize, usize, f32, f32)> = Vec::new();
        if cell == 1 {
            for y in b..h - b {
                for x in b..w - b {
                    let (gx, gy) = grad(x, y);
                    let g2 = gx * gx + gy * gy;
                    // (Either test of the threshold below may pass.)
                    if g2.sqrt() >= min_g || g2 >= min_g * min_g {
                        eligible.push((x, y, gx, gy));
                    }
                }
            }
        } else {
            for y0 in (b..h - b).step_by(cell) {
                for x0 in (b..w - b).step_by(cell) {
                    let mut best: Option<(usize, usize, f32, f32)> = None;
                    for y in y0..(y0 + cell).min(h - b) {
                        for x in x0..(x0 + cell).min(w - b) {
                            let (gx, gy) = grad(x, y);
                            let g2 = gx * gx + gy * gy;
                            if !(g2 >= 0.0) {
                                continue; // NaN pixel: never the cell's best
                            }
                            if best.is_none_or(|(_, _, bx, by)| g2 > bx * bx + by * by) {
                                best = Some((x, y, gx, gy));
                            }
                        }
                    }
                    eligible.extend(best);
                }
            }
        }
        // Histogram of gradient magnitudes (0.25 gray-level bins) to cap the count.
        const BIN: f32 = 0.25;
        const BINS: usize = 1500;
        let mut hist = vec![0usize; BINS + 1];
        for &(_, _, gx, gy) in &eligible {
            let g = (gx * gx + gy * gy).sqrt();
            if g >= min_g {
                hist[((g / BIN) as usize).min(BINS)] += 1;
            }
        }
        let mut threshold = min_g;
        let mut count: usize = hist.iter().sum();
        let mut bin = 0;
        while count > self.cfg.max_candidates && bin <= BINS {
            count -= hist[bin];
            bin += 1;
            threshold = threshold.max(bin as f32 * BIN);
        }
        let thr2 = threshold * threshold;
        self.index = vec![NO_CANDIDATE; w * h];
        for (x, y, gx, gy) in eligible {
            let g2 = gx * gx + gy * gy;
            if !(g2 >= thr2 && g2 > 0.0) || self.candidates.len() >= self.cfg.max_candidates {
                continue;
            }
            let Some(r) = self.camera.unproject(&Vector2::new(x as f64, y as f64)) else {
                continue;
            };
            let ray = Vector2::new(r.x, r.y);
            let Some(jinv) = to_pixel(&self.camera, &ray).1.try_inverse() else {
                continue;
            };
            let g = g2.sqrt();
            self.index[y * w + x] = self.candidates.len() as u32;
            self.candidates.push(Candidate {
                x: x as u32,
                y: y as u32,
                ray,
                jinv,
                grad_dir: [gx / g, gy / g],
            });
        }
        self.templates = self
            .candidates
            .iter()
            .map(|c| template(&self.image, c.x as usize, c.y as usize))
            .collect();
        self.states = vec![PixelState::EMPTY; self.candidates.len()];
        self.pending = vec![None; self.candidates.len()];
        self.ratios = Vec::with_capacity(self.candidates.len());
    }

    /// Number of candidate pixels.
    pub fn num_candidates(&self) -> usize {
        self.candidates.len()
    }

    /// The keyframe's camera pose in the world.
    pub fn t_world_cam(&self) -> &Isometry3<f64> {
        &self.t_world_cam
    }

    /// The global search range, inverse depth 1/m.
    pub fn inv_depth_range(&self) -> (f64, f64) {
        self.range_m_inv
    }

    /// Bounds every pixel's search: inverse depth (1/z, z along the optical axis) in
    /// `[min, max]`, 1/m (`min` may be 0: infinity). Invalid input (non-finite, negative,
    /// `max ≤ min`) is ignored. Pixels whose own window (from agreeing estimates or a prior) lies
    /// inside it keep searching that window only.
    pub fn set_inv_depth_range(&mut self, min_m_inv: f64, max_m_inv: f64) {
        if min_m_inv.is_finite()
            && max_m_inv.is_finite()
            && min_m_inv >= 0.0
            && max_m_inv > min_m_inv
        {
            self.range_m_inv = (min_m_inv, max_m_inv);
        }
    }

    /// Multiplies every inverse-depth estimate (and its standard deviation, and the prior) by
    /// `factor`: the keyframe's structure scaled about its camera by `1 / factor`, as when the
    /// odometry has found the scale of the poses it was triangulated from to be off. Relative
    /// consistency is unchanged, so every pixel keeps its run. A factor that is not finite and
    /// positive is ignored.
    pub fn scale_inv_depths(&mut self, factor: f64) {
        if !(factor.is_finite() && factor > 0.0) {
            return;
        }
        let f = factor as f32;
        let scale = |e: &mut Estimate| {
            e.rho *= f;
            e.sigma *= f;
        };
        for st in &mut self.states {
            let n = st.count as usize;
            st.estimates[..n].iter_mut().for_each(scale);
            if let Some(p) = st.prior.as_mut() {
                scale(p);
            }
            st.refuse(&self.cfg);
        }
    }

    /// Seeds pixels from the finished map of an earlier keyframe (propagation): each point is moved
    /// into this keyframe and becomes the prior of the candidate it lands on (and of its 3x3
    /// neighbours that have none closer), which bounds that pixel's search and counts as one vote.
    /// Returns the number of candidates that received a prior.
    pub fn propagate_from(&mut self, previous: &SemidenseMap) -> usize {
        if !self.valid
            || !se3::is_finite(&previous.t_world_cam)
            || !camera_is_usable(&previous.camera)
        {
            return 0;
        }
        let t_new_prev = self.t_world_cam.inverse() * previous.t_world_cam;
        let w = self.camera.width as i64;
        let h = self.camera.height as i64;
        // Pixel distance of the point that set each prior (nearest wins).
        let mut dist = vec![f32::INFINITY; self.candidates.len()];
        for p in &previous.points {
            let rho = p.inv_depth_m_inv as f64;
            let sigma = p.inv_depth_std_m_inv as f64;
            if !(rho > 0.0 && rho.is_finite() && sigma.is_finite() && sigma >= 0.0) {
                continue;
            }
            let Some(ray) = previous
                .camera
                .unproject(&Vector2::new(p.u_px as f64, p.v_px as f64))
            else {
                continue;
            };
            let q = t_new_prev * Point3::from(ray / rho);
            if !(q.z > 1e-6) {
                continue;
            }
            let Some(uv) = self.camera.project(&q.coords) else {
                continue;
            };
            let rho_new = 1.0 / q.z;
            // d rho_new / d rho = (R₃·ray) / (ρ² z_new²)
            let r3_ray = (t_new_prev.rotation * ray).z;
            let sigma_moved = (r3_ray / (rho * rho * q.z * q.z)).abs() * sigma;
            let sigma_new = (sigma_moved * self.cfg.prior_std_inflation as f64)
                .max(self.cfg.prior_min_rel_std as f64 * rho_new);
            if !(sigma_new > 0.0 && sigma_new.is_finite()) {
                continue;
            }
            let prior = Estimate {
                rho: rho_new as f32,
                sigma: sigma_new as f32,
            };
            let (cx, cy) = (uv.x.round() as i64, uv.y.round() as i64);
            for y in cy - 1..=cy + 1 {
                for x in cx - 1..=cx + 1 {
                    if x < 0 || y < 0 || x >= w || y >= h {
                        continue;
                    }
                    let i = self.index[(y * w + x) as usize];
                    if i == NO_CANDIDATE {
                        continue;
                    }
                    let d = ((x as f64 - uv.x).powi(2) + (y as f64 - uv.y).powi(2)) as f32;
                    if d < dist[i as usize] {
                        dist[i as usize] = d;
                        self.states[i as usize].prior = Some(prior);
                    }
                }
            }
        }
        let mut seeded = 0;
        for (st, d) in self.states.iter_mut().zip(&dist) {
            if d.is_finite() {
                st.refuse(&self.cfg);
                seeded += 1;
            }
        }
        seeded
    }

    /// One more overlapping view (eq. 27–28): epipolar search of each candidate's 7x7 patch in the
    /// raw `image` taken at camera pose `t_world_cam`, sub-pixel refinement, per-estimate
    /// inverse-depth standard deviation, fusion. The whole view is searched before any estimate is
    /// fused, so that its scale against the propagated priors is measured first
    /// ([`ObserveStats::view_scale`], `view_scale_gain`). Views can come from before or after the
    /// keyframe; nearest first is fastest. Never panics: unusable views are reported in `skipped`.
    pub fn observe(&mut self, image: &Image<f32>, t_world_cam: &Isometry3<f64>) -> ObserveStats {
        let mut stats = ObserveStats {
            candidates: self.candidates.len(),
            ..Default::default()
        };
        if !self.valid || !se3::is_finite(t_world_cam) {
            stats.skipped = Some(ViewSkip::NonFinitePose);
            return stats;
        }
        if image.width() != self.camera.width || image.height() != self.camera.height {
            stats.skipped = Some(ViewSkip::ImageSizeMismatch);
            return stats;
        }
        let geometry = ViewGeometry::new(&self.t_world_cam, t_world_cam);
        if !(geometry.t_view_kf.norm() > 1e-9) {
            stats.skipped = Some(ViewSkip::NoBaseline);
            return stats;
        }
        let (g_lo, g_hi) = self.range_m_inv;
        let ctx = ViewContext {
            image,
            camera: &self.camera,
            geometry,
            footprint: self.footprint,
            global_width_m_inv: g_hi - g_lo,
            min_parallax_px: self.cfg.min_parallax_px as f64,
            baseline_m: geometry.t_view_kf.norm(),
            max_baseline_depth_ratio: self.cfg.max_baseline_depth_ratio as f64,
            min_cos: self.cfg.min_gradient_epipolar_cos,
            max_patch_rms: self.cfg.max_patch_rms,
            min_second_best_ratio: self.cfg.min_second_best_ratio,
            match_std_px: self.cfg.match_std_px,
            baseline_std_m: self.cfg.baseline_std_m,
        };
        let kf_image = &self.image;
        let cfg = &self.cfg;
        let f_px = 0.5 * (self.camera.fx + self.camera.fy);
        let std_ratio = cfg.max_view_std_ratio as f64;
        let min_votes = cfg.min_consistent_views.max(1);
        let first_kappa = cfg.first_estimate_search_sigmas as f64;
        let pose_rel = cfg.baseline_std_m as f64 / ctx.baseline_m;
        let one = |(c, t7): (&Candidate, &[f32; PATCH]),
                   (st, pending): (&mut PixelState, &mut Option<Estimate>)|
         -> ObserveStats {
            let mut s = ObserveStats::default();
            *pending = None;
            if !st.run.lo.is_finite() && st.searches as usize >= cfg.give_up_after_searches {
                s.given_up = 1;
                return s;
            }
            // Information gain (eq. 27: inverse-variance weights): a view whose best-case σ (|cos|
            // = 1, pinhole parallax at the run's estimate) is `k` times the fused σ would weigh
            // at most 1/k² of the run. Only for pixels that already make a point.
            if std_ratio > 0.0
                && st.run.lo.is_finite()
                && st.run.votes as usize >= min_votes
                && let Some(v) = ctx
                    .geometry
                    .line(&c.ray)
                    .normalised_speed(st.run.rho as f64)
                && (cfg.match_std_px as f64).hypot(st.run.rho as f64 * pose_rel * f_px * v)
                    > std_ratio * st.run.sigma as f64 * f_px * v
            {
                s.converged = 1;
                return s;
            }
            let (mut lo, mut hi) = (g_lo.max(st.run.lo as f64), g_hi.min(st.run.hi as f64));
            if !(lo < hi) {
                (lo, hi) = (g_lo, g_hi);
            }
            // A pixel with one view estimate and nothing else searches around it (LSD-SLAM's
            // narrowing; DPPTAM waits for two): a wrong first estimate is released by a
            // disagreeing second one, or given up after failed searches like an unmatched pixel.
            if first_kappa > 0.0 && !st.run.lo.is_finite() && st.count == 1 && st.prior.is_none() {
                let (r, sg) = (st.run.rho as f64, st.run.sigma as f64);
                let (l1, h1) = (
                    g_lo.max(r - first_kappa * sg),
                    g_hi.min(r + first_kappa * sg),
                );
                if l1 < h1 {
                    (lo, hi) = (l1, h1);
                }
            }
            let kp = KeyframePixel {
                image: kf_image,
                x: c.x as usize,
                y: c.y as usize,
                ray: c.ray,
                jinv: c.jinv,
                grad_dir: c.grad_dir,
                template: t7,
            };
            match search_pixel(&ctx, &kp, lo, hi) {
                Outcome::Matched(e) => {
                    s.searched = 1;
                    s.matched = 1;
                    *pending = Some(e);
                }
                Outcome::OutOfView => s.out_of_view = 1,
                Outcome::LowParallax => s.low_parallax = 1,
                Outcome::WideBaseline => s.wide_baseline = 1,
                Outcome::GradientParallel => s.gradient_parallel = 1,
                Outcome::Photometric => (s.searched, s.photometric) = (1, 1),
                Outcome::Ambiguous => (s.searched, s.ambiguous) = (1, 1),
                Outcome::OutOfRange => (s.searched, s.out_of_range) = (1, 1),
            }
            st.searches = st.searches.saturating_add(s.searched as u8);
            s
        };
        let counts = if cfg.parallel {
            self.candidates
                .par_iter()
                .zip(self.templates.par_iter())
                .zip(self.states.par_iter_mut().zip(self.pending.par_iter_mut()))
                .fold(ObserveStats::default, |acc, (c, st)| acc.add(&one(c, st)))
                .reduce(ObserveStats::default, |a, b| a.add(&b))
        } else {
            self.candidates
                .iter()
                .zip(self.templates.iter())
                .zip(self.states.iter_mut().zip(self.pending.iter_mut()))
                .fold(ObserveStats::default(), |acc, (c, st)| acc.add(&one(c, st)))
        };
        let mut stats = stats.add(&counts);
        stats.view_scale = view_scale(
            &self.states,
            &self.pending,
            &mut self.ratios,
            cfg.view_scale_min_points,
        );
        // The view's scale taken only in part (`view_scale_gain`): each of its estimates moved
        // by `r^-(1-g)` toward the propagated map's scale, then fused.
        let gain = cfg.view_scale_gain;
        let factor = match stats.view_scale {
            Some(r) if gain < 1.0 => r.powf(gain - 1.0).clamp(0.8, 1.25),
            _ => 1.0,
        };
        let fuse = |(st, e): (&mut PixelState, &Option<Estimate>)| {
            if let Some(e) = e {
                let e = Estimate {
                    rho: e.rho * factor,
                    sigma: e.sigma * factor,
                };
                st.insert(e, cfg);
            }
        };
        if cfg.parallel {
            self.states
                .par_iter_mut()
                .zip(self.pending.par_iter())
                .for_each(fuse);
        } else {
            self.states.iter_mut().zip(&self.pending).for_each(fuse);
        }
        stats
    }

    /// The current fused estimates after outlier removal: a consistent run of at least
    /// `min_consistent_views` votes (eq. 27 fused over its members), relative uncertainty at most
    /// `max_rel_inv_depth_std`, and at least `min_agreeing_neighbours` agreeing fused neighbours.
    /// (Gradient vs. epipolar direction is enforced per view by `observe`.) Callable at any time.
    pub fn map(&self) -> SemidenseMap {
        let mut out = SemidenseMap {
            t_world_cam: self.t_world_cam,
            camera: self.camera,
            points: Vec::new(),
        };
        if !self.valid || self.candidates.is_empty() {
            return out;
        }
        let cfg = &self.cfg;
        let ok = |r: &Run| {
            r.votes as usize >= cfg.min_consistent_views.max(1)
                && r.views >= 1
                && r.rho > 0.0
                && r.sigma <= cfg.max_rel_inv_depth_std * r.rho
        };
        let w = self.camera.width;
        let h = self.camera.height;
        let rad = cfg.neighbour_radius_px as i64;
        for (c, st) in self.candidates.iter().zip(&self.states) {
            let r = &st.run;
            if !ok(r) {
                continue;
            }
            let mut agree = 0usize;
            'win: for y in (c.y as i64 - rad).max(0)..=(c.y as i64 + rad).min(h as i64 - 1) {
                for x in (c.x as i64 - rad).max(0)..=(c.x as i64 + rad).min(w as i64 - 1) {
                    let j = self.index[y as usize * w + x as usize];
                    if j == NO_CANDIDATE || (x == c.x as i64 && y == c.y as i64) {
                        continue;
                    }
                    let n = &self.states[j as usize].run;
                    if !ok(n) {
                        continue;
                    }
                    let tol = cfg.neighbour_rel_tolerance * r.rho
                        + cfg.consistency_sigmas * (r.sigma * r.sigma + n.sigma * n.sigma).sqrt();
                    if (n.rho - r.rho).abs() <= tol {
                        agree += 1;
                        if agree >= cfg.min_agreeing_neighbours {
                            break 'win;
                        }
                    }
                }
            }
            if agree >= cfg.min_agreeing_neighbours {
                out.points.push(MapPoint {
                    u_px: c.x as f32,
                    v_px: c.y as f32,
                    inv_depth_m_inv: r.rho,
                    inv_depth_std_m_inv: r.sigma,
                    num_views: r.views,
                });
            }
        }
        out
    }
}

/// The median ratio of the current view's estimates (`pending`) to the priors propagated from
/// the previous keyframe's map. A baseline error shared by the whole view scales every inverse
/// depth triangulated from it by the same factor, so this is that view's scale against the map
/// chain. `None` below `view_scale_min_points` such pixels (a first map has no priors).
fn view_scale(
    states: &[PixelState],
    pending: &[Option<Estimate>],
    ratios: &mut Vec<f32>,
    min_points: usize,
) -> Option<f32> {
    ratios.clear();
    for (st, e) in states.iter().zip(pending) {
        if let Some(e) = e
            && let Some(p) = st.prior
            && p.rho > 0.0
        {
            ratios.push(e.rho / p.rho);
        }
    }
    let n = ratios.len();
    if n == 0 || n < min_points {
        return None;
    }
    let (_, m, _) = ratios.select_nth_unstable_by(n / 2, f32::total_cmp);
    Some(*m).filter(|m| m.is_finite() && *m > 0.0)
}
