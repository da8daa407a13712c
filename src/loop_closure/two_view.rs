//! The direction of the translation between two views whose relative rotation is known (from the
//! gyro), from matched rays: each match `(a, b)` with `b ∝ R a + t` satisfies the epipolar
//! constraint `bᵀ [t]ₓ R a = 0`, i.e. `tᵀ (R a × b) = 0` — linear in `t`, so two matches give a
//! hypothesis (the cross product of their two constraint vectors) and all inliers a least-squares
//! refinement (the smallest right singular vector). The sign is the one that puts most inliers'
//! points in front of both cameras.
//!
//! With the rotation given, this is the two-point method of Kneip et al. (2011) in its linear
//! form: better conditioned than an essential matrix from five or eight points when the baseline
//! is short and the rotation is what the gyro measures well.

use super::pnp::Draws;
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

/// RANSAC settings.
#[derive(Clone, Debug, PartialEq)]
pub struct TwoViewConfig {
    /// Two-match hypotheses drawn.
    pub hypotheses: usize,
    /// A match is an inlier if the angle between its ray in `b` and the epipolar plane of its ray
    /// in `a` is within this, rad (1 px at a focal length of 460 px ≈ 0.0022 rad).
    pub inlier_rad: f64,
    /// Seed of the sample draws (the result is deterministic).
    pub seed: u64,
}

impl Default for TwoViewConfig {
    fn default() -> Self {
        TwoViewConfig {
            hypotheses: 64,
            inlier_rad: 0.004,
            seed: 0x2_7ea1,
        }
    }
}

/// A translation direction and its support.
#[derive(Clone, Debug, PartialEq)]
pub struct TwoView {
    /// `t` of `b = R a + t` (view `a`'s frame into view `b`'s), unit length.
    pub t_b_a_dir: Unit<Vector3<f64>>,
    /// Matches within `inlier_rad` of their epipolar plane.
    pub inliers: usize,
    /// Median parallax of the inliers: angle between `R a` and `b`, rad (what the direction is
    /// measured from; zero for a pure rotation).
    pub median_parallax_rad: f64,
}

/// Angle of ray `b` off the epipolar plane of `(R a, t)`, rad.
fn off_plane_rad(t: &Vector3<f64>, ra: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let n = ra.cross(t);
    let nn = n.norm() * b.norm();
    if nn <= 0.0 {
        return f64::INFINITY;
    }
    (n.dot(b) / nn).abs().min(1.0).asin()
}

/// Whether the point seen along `ra` (in `b`'s orientation) and `b` lies in front of both
/// cameras for the translation `t` (midpoint of the closest approach).
fn in_front(t: &Vector3<f64>, ra: &Vector3<f64>, b: &Vector3<f64>) -> bool {
    // Point = s·ra in b's frame after the translation: s·ra + t = u·b.
    let m = Matrix3::from_columns(&[*ra, -*b, ra.cross(b)]);
    match m.try_inverse() {
        Some(inv) => {
            let x = inv * (-t);
            x[0] > 0.0 && x[1] > 0.0
        }
        None => false,
    }
}

/// The translation direction between views `a` and `b` from matched rays (`rays_a[i]` with
/// `rays_b[i]`, each in its camera's frame, any length) given `r_b_a`, view `a`'s frame into view
/// `b`'s. `None` with fewer than two matches, or when no hypothesis has at least two inliers.
pub fn translation_direction(
    rays_a: &[Vector3<f64>],
    rays_b: &[Vector3<f64>],
    r_b_a: &Rotation3<f64>,
    cfg: &TwoViewConfig,
) -> Option<TwoView> {
    let n = rays_a.len().min(rays_b.len());
    if n < 2 {
        return None;
    }
    let ra: Vec<Vector3<f64>> = rays_a[..n].iter().map(|a| r_b_a * a).collect();
    let b = &rays_b[..n];
    // Constraint vectors: tᵀ c_i = 0.
    let c: Vec<Vector3<f64>> = ra.iter().zip(b).map(|(a, b)| a.cross(b)).collect();
    let inliers_of = |t: &Vector3<f64>| -> Vec<usize> {
        (0..n)
            .filter(|&i| off_plane_rad(t, &ra[i], &b[i]) <= cfg.inlier_rad)
            .collect()
    };
    let mut draws = Draws(cfg.seed | 1);
    let mut best: Vec<usize> = Vec::new();
    for _ in 0..cfg.hypotheses {
        let i = draws.below(n);
        let j = draws.below(n);
        if i == j {
            continue;
        }
        let t = c[i].cross(&c[j]);
        if t.norm() < 1e-12 {
            continue;
        }
        let inl = inliers_of(&t);
        if inl.len() > best.len() {
            best = inl;
        }
    }
    if best.len() < 2 {
        return None;
    }
    // Least squares over the inliers, then the inliers of that, once more.
    let refine = |set: &[usize]| -> Option<Vector3<f64>> {
        let mut m = Matrix3::zeros();
        for &i in set {
            let ci = c[i] / c[i].norm().max(1e-12);
            m += ci * ci.transpose();
        }
        let eig = m.symmetric_eigen();
        let k = eig.eigenvalues.imin();
        let t = eig.eigenvectors.column(k).into_owned();
        t.iter().all(|v| v.is_finite()).then_some(t)
    };
    let mut t = refine(&best)?;
    let again = inliers_of(&t);
    if again.len() >= 2 {
        t = refine(&again)?;
        best = again;
    }
    let front = best
        .iter()
        .filter(|&&i| in_front(&t, &ra[i], &b[i]))
        .count();
    if 2 * front < best.len() {
        t = -t;
    }
    let mut parallax: Vec<f64> = best.iter().map(|&i| ra[i].angle(&b[i])).collect();
    parallax.sort_by(f64::total_cmp);
    Some(TwoView {
        t_b_a_dir: Unit::new_normalize(t),
        inliers: best.len(),
        median_parallax_rad: parallax[parallax.len() / 2],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points 1.5–4 m in front of view `a`, seen from `a` and from `b = R a + t`.
    fn scene(
        r_b_a: &Rotation3<f64>,
        t_b_a: &Vector3<f64>,
        n: usize,
    ) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let mut a = Vec::new();
        let mut b = Vec::new();
        for k in 0..n {
            let u = ((k * 37) % 101) as f64 / 101.0 - 0.5;
            let v = ((k * 53) % 89) as f64 / 89.0 - 0.5;
            let z = 1.5 + 2.5 * ((k * 29) % 97) as f64 / 97.0;
            let p = Vector3::new(u * z, 0.7 * v * z, z);
            a.push(p);
            b.push(r_b_a * p + t_b_a);
        }
        (a, b)
    }

    #[test]
    fn recovers_the_direction_and_its_sign_among_outliers() {
        let r = Rotation3::from_scaled_axis(Vector3::new(0.02, -0.15, 0.05));
        let t = Vector3::new(0.12, -0.03, 0.05);
        let (a, mut b) = scene(&r, &t, 80);
        // A quarter of the matches wrong.
        for k in (0..80).step_by(4) {
            b[k] = Vector3::new(-b[k].y, b[k].x, b[k].z);
        }
        let tv = translation_direction(&a, &b, &r, &TwoViewConfig::default()).expect("solved");
        let err = tv.t_b_a_dir.angle(&Unit::new_normalize(t));
        assert!(err < 1e-6, "{err} rad");
        assert_eq!(tv.inliers, 60);
        assert!(tv.median_parallax_rad > 0.01);
        // The opposite motion gives the opposite direction (the sign from the points in front).
        let (a2, b2) = scene(&r, &-t, 40);
        let back = translation_direction(&a2, &b2, &r, &TwoViewConfig::default()).unwrap();
        assert!(back.t_b_a_dir.angle(&Unit::new_normalize(-t)) < 1e-6);
    }

    #[test]
    fn noisy_rays_give_a_direction_within_a_degree() {
        let r = Rotation3::from_scaled_axis(Vector3::new(0.0, 0.1, 0.0));
        let t = Vector3::new(0.15, 0.0, 0.02);
        let (a, b) = scene(&r, &t, 100);
        // ±1 px at 460 px focal length, alternating.
        let b: Vec<Vector3<f64>> = b
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let s = if k % 2 == 0 { 1.0 } else { -1.0 };
                let q = p / p.z;
                Vector3::new(q.x + s / 460.0, q.y - s / 460.0, 1.0)
            })
            .collect();
        let tv = translation_direction(&a, &b, &r, &TwoViewConfig::default()).unwrap();
        let err = tv.t_b_a_dir.angle(&Unit::new_normalize(t));
        assert!(err < 1f64.to_radians(), "{} deg", err.to_degrees());
        assert!(tv.inliers >= 90, "{}", tv.inliers);
    }

    #[test]
    fn too_few_matches_give_nothing() {
        let r = Rotation3::identity();
        assert!(
            translation_direction(
                &[Vector3::z()],
                &[Vector3::z()],
                &r,
                &TwoViewConfig::default()
            )
            .is_none()
        );
        assert!(translation_direction(&[], &[], &r, &TwoViewConfig::default()).is_none());
    }
}
