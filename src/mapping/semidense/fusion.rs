//! Fusion of per-view inverse-depth estimates of one pixel (eq. 27 over all views): the largest
//! consistent run, its inverse-variance weighted mean, and the search window it implies.

/// One inverse-depth estimate, 1/m.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Estimate {
    pub rho: f32,
    pub sigma: f32,
}

/// The consistent run of a pixel's estimates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Run {
    /// Members (a prior counts as one).
    pub votes: u16,
    /// Members that are view estimates.
    pub views: u16,
    /// Inverse-variance weighted mean, 1/m.
    pub rho: f32,
    /// Its standard deviation `(Σ σ⁻²)^(-1/2)`, 1/m.
    pub sigma: f32,
    /// Search window for later views: the intersection of the members' `ρ ± κσ`, or infinite when
    /// the run cannot be trusted yet (a single view estimate).
    pub lo: f32,
    pub hi: f32,
}

impl Run {
    pub const EMPTY: Run = Run {
        votes: 0,
        views: 0,
        rho: f32::NAN,
        sigma: f32::INFINITY,
        lo: f32::NEG_INFINITY,
        hi: f32::INFINITY,
    };
}

/// How many of a pixel's intervals `ρ_i ± τσ_i` contain the left end `ρ_j − τσ_j` of interval `j`
/// (`votes`), and their total weight `Σ σ_i⁻²` (`weight`, summed prior first, then the estimates in
/// order). Kept per estimate, so adding an estimate updates the run in O(n) instead of O(n²).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Cover {
    pub votes: u8,
    pub weight: f32,
}

#[inline(always)]
fn contains(e: Estimate, x: f32, tau: f32) -> bool {
    (x - e.rho).abs() <= tau * e.sigma * (1.0 + 1e-5)
}

#[inline(always)]
fn left_end(e: Estimate, tau: f32) -> f32 {
    e.rho - tau * e.sigma
}

#[inline(always)]
fn weight(e: Estimate) -> f32 {
    1.0 / (e.sigma * e.sigma)
}

/// The cover of the point `x` by the prior and the estimates (in that order).
fn cover_of(ests: &[Estimate], prior: Option<Estimate>, x: f32, tau: f32) -> Cover {
    let mut c = Cover::default();
    for e in prior.iter().chain(ests) {
        if contains(*e, x, tau) {
            c.votes += 1;
            c.weight += weight(*e);
        }
    }
    c
}

/// The covers of a pixel's estimates, stored compactly (votes and weights apart).
pub(crate) struct CoversMut<'a> {
    pub votes: &'a mut [u8],
    pub weight: &'a mut [f32],
}

impl CoversMut<'_> {
    #[inline(always)]
    fn set(&mut self, j: usize, c: Cover) {
        self.votes[j] = c.votes;
        self.weight[j] = c.weight;
    }
}

/// Recomputes every cover (O(n²)): `covers[j]` for `ests[j]`, and the prior's (returned).
pub(crate) fn covers_from_scratch(
    ests: &[Estimate],
    prior: Option<Estimate>,
    tau: f32,
    mut covers: CoversMut,
) -> Cover {
    for (j, e) in ests.iter().enumerate() {
        covers.set(j, cover_of(ests, prior, left_end(*e, tau), tau));
    }
    prior.map_or(Cover::default(), |p| {
        cover_of(ests, prior, left_end(p, tau), tau)
    })
}

/// Updates the covers after `ests`' last element was appended (O(n)); the result is the same as
/// [`covers_from_scratch`].
pub(crate) fn append_cover(
    ests: &[Estimate],
    prior: Option<Estimate>,
    tau: f32,
    mut covers: CoversMut,
    prior_cover: &mut Cover,
) {
    let Some((&e, older)) = ests.split_last() else {
        return;
    };
    let m = older.len();
    let w = weight(e);
    for (j, o) in older.iter().enumerate() {
        if contains(e, left_end(*o, tau), tau) {
            covers.votes[j] += 1;
            covers.weight[j] += w;
        }
    }
    if let Some(p) = prior
        && contains(e, left_end(p, tau), tau)
    {
        prior_cover.votes += 1;
        prior_cover.weight += w;
    }
    covers.set(m, cover_of(ests, prior, left_end(e, tau), tau));
}

/// The largest set of estimates (plus an optional prior) whose `ρ ± τσ` intervals share a point;
/// ties go to the set with the larger total weight `Σ σ⁻²`. The window narrows searches once two
/// members agree, or when the prior is the only estimate. `covers` / `prior_cover` are those of
/// [`covers_from_scratch`] (kept up to date by [`append_cover`]).
pub(crate) fn run_from_covers(
    ests: &[Estimate],
    votes: &[u8],
    weights: &[f32],
    prior: Option<Estimate>,
    prior_cover: Cover,
    tau: f32,
    kappa: f32,
) -> Run {
    let n = ests.len();
    if n == 0 && prior.is_none() {
        return Run::EMPTY;
    }
    // The point covered by most intervals can be taken at some interval's left end.
    let (mut best_x, mut best_votes, mut best_w) = (f32::NAN, 0u8, 0.0f32);
    let own = ests.iter().zip(votes.iter().zip(weights));
    let prior_end = prior.map(|p| (p, (prior_cover.votes, prior_cover.weight)));
    let prior_end = prior_end.iter().map(|(p, (v, w))| (p, (v, w)));
    for (e, (&v, &w)) in own.chain(prior_end) {
        if v > best_votes || (v == best_votes && w > best_w) {
            (best_x, best_votes, best_w) = (left_end(*e, tau), v, w);
        }
    }
    // Eq. 27 over the run's members: inverse-variance weighted mean.
    let (mut sw, mut swr, mut views) = (0.0f32, 0.0f32, 0u16);
    let (mut lo, mut hi) = (f32::NEG_INFINITY, f32::INFINITY);
    let mut prior_member = false;
    for (i, e) in ests.iter().chain(prior.iter()).enumerate() {
        if contains(*e, best_x, tau) {
            let w = weight(*e);
            sw += w;
            swr += w * e.rho;
            lo = lo.max(e.rho - kappa * e.sigma);
            hi = hi.min(e.rho + kappa * e.sigma);
            if i < n {
                views += 1;
            } else {
                prior_member = true;
            }
        }
    }
    let narrow = best_votes >= 2 || (prior_member && n == 0);
    if !narrow || !(lo < hi) {
        (lo, hi) = (f32::NEG_INFINITY, f32::INFINITY);
    }
    Run {
        votes: best_votes as u16,
        views,
        rho: swr / sw,
        sigma: 1.0 / sw.sqrt(),
        lo,
        hi,
    }
}

/// [`run_from_covers`] with the covers computed from scratch (O(n²)).
#[cfg(test)]
pub(crate) fn consistent_run(
    ests: &[Estimate],
    prior: Option<Estimate>,
    tau: f32,
    kappa: f32,
) -> Run {
    let (mut v, mut w) = (vec![0; ests.len()], vec![0.0; ests.len()]);
    let covers = CoversMut {
        votes: &mut v,
        weight: &mut w,
    };
    let pc = covers_from_scratch(ests, prior, tau, covers);
    run_from_covers(ests, &v, &w, prior, pc, tau, kappa)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(rho: f32, sigma: f32) -> Estimate {
        Estimate { rho, sigma }
    }

    #[test]
    fn outliers_are_left_out_and_inliers_weighted() {
        let ests = [
            e(0.50, 0.01),
            e(0.51, 0.02),
            e(0.80, 0.01),
            e(0.495, 0.01),
            e(0.2, 0.05),
        ];
        let r = consistent_run(&ests, None, 2.0, 3.0);
        assert_eq!((r.votes, r.views), (3, 3));
        let w = [1.0 / 1e-4, 1.0 / 4e-4, 1.0 / 1e-4];
        let want = (0.50 * w[0] + 0.51 * w[1] + 0.495 * w[2]) / (w[0] + w[1] + w[2]);
        assert!((r.rho - want).abs() < 1e-5, "{} vs {want}", r.rho);
        assert!((r.sigma - (1.0 / (w[0] + w[1] + w[2])).sqrt()).abs() < 1e-6);
        // window = intersection of ±3σ: [0.495+... max(0.47, 0.45, 0.465), min(0.53, 0.57, 0.525)]
        assert!(
            (r.lo - 0.47).abs() < 1e-6 && (r.hi - 0.525).abs() < 1e-6,
            "{r:?}"
        );
    }

    #[test]
    fn a_single_view_does_not_narrow_but_a_lone_prior_does() {
        let r = consistent_run(&[e(0.5, 0.01)], None, 2.0, 3.0);
        assert_eq!(r.votes, 1);
        assert!(r.lo.is_infinite() && r.hi.is_infinite());
        let r = consistent_run(&[], Some(e(0.5, 0.01)), 2.0, 3.0);
        assert_eq!((r.votes, r.views), (1, 0));
        assert!((r.lo - 0.47).abs() < 1e-6 && (r.hi - 0.53).abs() < 1e-6);
        // A view that disagrees with the prior releases the window.
        let r = consistent_run(&[e(0.9, 0.01)], Some(e(0.5, 0.01)), 2.0, 3.0);
        assert_eq!(r.votes, 1);
        assert!(r.lo.is_infinite());
        // ... and one that agrees counts with it.
        let r = consistent_run(&[e(0.505, 0.01)], Some(e(0.5, 0.01)), 2.0, 3.0);
        assert_eq!((r.votes, r.views), (2, 1));
        assert!(r.lo > 0.47 && r.hi < 0.54);
        assert_eq!(consistent_run(&[], None, 2.0, 3.0).votes, 0);
    }

    #[test]
    fn appended_covers_equal_covers_from_scratch() {
        let ests = [
            e(0.50, 0.01),
            e(0.51, 0.02),
            e(0.80, 0.01),
            e(0.495, 0.01),
            e(0.2, 0.05),
            e(0.503, 0.004),
            e(0.81, 0.02),
        ];
        fn mk<'a>(votes: &'a mut [u8], weight: &'a mut [f32]) -> CoversMut<'a> {
            CoversMut { votes, weight }
        }
        for prior in [None, Some(e(0.5, 0.03)), Some(e(0.79, 0.05))] {
            let (mut v, mut w) = ([0u8; 7], [0.0f32; 7]);
            let mut pc = covers_from_scratch(&[], prior, 2.0, mk(&mut [], &mut []));
            for n in 1..=ests.len() {
                append_cover(&ests[..n], prior, 2.0, mk(&mut v, &mut w), &mut pc);
                let (mut wv, mut ww) = ([0u8; 7], [0.0f32; 7]);
                let want_pc = covers_from_scratch(&ests[..n], prior, 2.0, mk(&mut wv, &mut ww));
                assert_eq!(
                    (&v[..n], &w[..n], pc),
                    (&wv[..n], &ww[..n], want_pc),
                    "n = {n}"
                );
            }
        }
    }
}
