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

/// The largest set of estimates (plus an optional prior) whose `ρ ± τσ` intervals share a point;
/// ties go to the set with the larger total weight `Σ σ⁻²`. The window narrows searches once two
/// members agree, or when the prior is the only estimate.
pub(crate) fn consistent_run(
    ests: &[Estimate],
    prior: Option<Estimate>,
    tau: f32,
    kappa: f32,
) -> Run {
    let n = ests.len();
    let get = |i: usize| {
        if i < n {
            ests[i]
        } else {
            prior.unwrap_or_default()
        }
    };
    let total = n + usize::from(prior.is_some());
    if total == 0 {
        return Run::EMPTY;
    }
    let contains = |e: Estimate, x: f32| (x - e.rho).abs() <= tau * e.sigma * (1.0 + 1e-5);
    // The point covered by most intervals can be taken at some interval's left end.
    let (mut best_x, mut best_votes, mut best_w) = (f32::NAN, 0usize, 0.0f32);
    for j in 0..total {
        let ej = get(j);
        let x = ej.rho - tau * ej.sigma;
        let (mut votes, mut w) = (0usize, 0.0f32);
        for i in 0..total {
            let e = get(i);
            if contains(e, x) {
                votes += 1;
                w += 1.0 / (e.sigma * e.sigma);
            }
        }
        if votes > best_votes || (votes == best_votes && w > best_w) {
            (best_x, best_votes, best_w) = (x, votes, w);
        }
    }
    let (mut sw, mut swr, mut views) = (0.0f32, 0.0f32, 0u16);
    let (mut lo, mut hi) = (f32::NEG_INFINITY, f32::INFINITY);
    let mut prior_member = false;
    for i in 0..total {
        let e = get(i);
        if contains(e, best_x) {
            let w = 1.0 / (e.sigma * e.sigma);
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
}
