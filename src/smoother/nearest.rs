//! The `k` nearest neighbours of every point of a set (3-D, Euclidean), on a uniform grid.
//!
//! The photometric bundle pulls each inverse depth toward the median of its image neighbours'
//! (`smoothness_rel_std`); a keyframe's 3000 host points took ~95 ms by brute force (O(n²)), a
//! third of a keyframe adjustment. Bucketed in cubic cells of about `k` points each, a point's
//! neighbours are found by visiting shells of cells around its own until the `k`-th best distance
//! is closer than any unvisited cell can be.
//!
//! Ties are broken by index (the neighbours are the first `k` of the others ordered by
//! `(squared distance, index)`), so the result does not depend on the search order.

use nalgebra::Vector3;
use std::collections::HashMap;

type Cell = (i64, i64, i64);

/// For each point of `points`, the indices of its `k` nearest others (fewer if there are fewer
/// others), nearest first. Non-finite points have no neighbours and are nobody's neighbour.
pub fn k_nearest(points: &[Vector3<f64>], k: usize) -> Vec<Vec<u32>> {
    let n = points.len();
    let mut out = vec![Vec::new(); n];
    let finite: Vec<usize> = (0..n)
        .filter(|&i| points[i].iter().all(|c| c.is_finite()))
        .collect();
    if k == 0 || finite.len() < 2 {
        return out;
    }
    let (lo, hi) = finite.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), &i| (lo.inf(&points[i]), hi.sup(&points[i])),
    );
    let cell = cell_size(&(hi - lo), finite.len(), k);
    let key = |p: &Vector3<f64>| -> Cell {
        let c = (p - lo) / cell;
        (c.x as i64, c.y as i64, c.z as i64)
    };
    let mut grid: HashMap<Cell, Vec<u32>> = HashMap::new();
    for &i in &finite {
        grid.entry(key(&points[i])).or_default().push(i as u32);
    }
    let extent = key(&hi);
    let max_ring = extent.0.max(extent.1).max(extent.2) + 1;
    let want = k.min(finite.len() - 1);
    // The best `want` so far, sorted by (squared distance, index).
    let mut best: Vec<(f64, u32)> = Vec::with_capacity(want + 1);
    for &i in &finite {
        let p = &points[i];
        let c = key(p);
        best.clear();
        for r in 0..=max_ring {
            for_each_shell_cell(c, r, |cc| {
                let Some(members) = grid.get(&cc) else { return };
                for &j in members {
                    if j as usize == i {
                        continue;
                    }
                    let d = (points[j as usize] - p).norm_squared();
                    let cand = (d, j);
                    if best.len() == want && !less(cand, best[want - 1]) {
                        continue;
                    }
                    let at = best.partition_point(|&b| less(b, cand));
                    best.insert(at, cand);
                    best.truncate(want);
                }
            });
            // Every point in a cell beyond ring r is at least r cells away along some axis.
            let reach = r as f64 * cell;
            if best.len() == want && best[want - 1].0 <= reach * reach {
                break;
            }
        }
        out[i] = best.iter().map(|b| b.1).collect();
    }
    out
}

fn less(a: (f64, u32), b: (f64, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// A cube edge giving about `k` points per cell if the points fill the box's widest dimensions
/// (those not flat next to the widest). Only the speed depends on it, never the result.
fn cell_size(extent: &Vector3<f64>, n: usize, k: usize) -> f64 {
    let mut e = [extent.x, extent.y, extent.z];
    e.sort_by(|a, b| b.total_cmp(a));
    let filled = |x: f64| x > 1e-3 * e[0];
    let (volume, dims) = if filled(e[2]) {
        (e[0] * e[1] * e[2], 3.0)
    } else if filled(e[1]) {
        (e[0] * e[1], 2.0)
    } else {
        (e[0], 1.0)
    };
    let size = ((volume / n as f64) * k.max(1) as f64).powf(1.0 / dims);
    if size.is_finite() && size > 0.0 {
        size
    } else {
        1.0
    }
}

/// Calls `f` for every cell at Chebyshev distance exactly `r` from `c`.
fn for_each_shell_cell(c: Cell, r: i64, mut f: impl FnMut(Cell)) {
    if r == 0 {
        f(c);
        return;
    }
    for dz in -r..=r {
        for dy in -r..=r {
            let on_face = dz.abs() == r || dy.abs() == r;
            if on_face {
                for dx in -r..=r {
                    f((c.0 + dx, c.1 + dy, c.2 + dz));
                }
            } else {
                f((c.0 - r, c.1 + dy, c.2 + dz));
                f((c.0 + r, c.1 + dy, c.2 + dz));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_force(points: &[Vector3<f64>], k: usize) -> Vec<Vec<u32>> {
        (0..points.len())
            .map(|i| {
                let mut d: Vec<(f64, u32)> = (0..points.len())
                    .filter(|&j| j != i)
                    .map(|j| ((points[j] - points[i]).norm_squared(), j as u32))
                    .collect();
                d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                d.iter().take(k).map(|x| x.1).collect()
            })
            .collect()
    }

    /// Rays of pixels of a keyframe's 400x240 corner (z = 1, f = 460 px), on a pixel grid with
    /// gaps: many exact ties, as in a real keyframe.
    fn keyframe_rays() -> Vec<Vector3<f64>> {
        let mut rays = Vec::new();
        let mut s = 12345u64;
        for v in (5..245).step_by(3) {
            for u in (5..405).step_by(2) {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                if (s >> 33).is_multiple_of(4) {
                    rays.push(Vector3::new(
                        (u as f64 - 376.0) / 460.0,
                        (v as f64 - 240.0) / 460.0,
                        1.0,
                    ));
                }
            }
        }
        rays
    }

    #[test]
    fn the_grid_finds_the_brute_force_neighbours_ties_included() {
        let rays = keyframe_rays();
        assert!(rays.len() > 1000, "{}", rays.len());
        assert_eq!(k_nearest(&rays, 8), brute_force(&rays, 8));
        // Unit rays (not on a plane) and a clustered set: the same.
        let unit: Vec<_> = rays.iter().map(|r| r.normalize()).collect();
        assert_eq!(k_nearest(&unit, 8), brute_force(&unit, 8));
        let clustered: Vec<_> = (0..300)
            .map(|i| {
                let c = if i % 3 == 0 { 10.0 } else { 0.0 };
                Vector3::new(
                    c + (i as f64 * 0.37).sin(),
                    (i as f64 * 0.71).cos(),
                    (i as f64 * 0.13).sin(),
                )
            })
            .collect();
        assert_eq!(k_nearest(&clustered, 5), brute_force(&clustered, 5));
    }

    #[test]
    fn small_and_degenerate_sets() {
        assert!(k_nearest(&[], 8).is_empty());
        assert_eq!(k_nearest(&[Vector3::zeros()], 8), vec![Vec::<u32>::new()]);
        let two = [Vector3::zeros(), Vector3::new(1.0, 0.0, 0.0)];
        assert_eq!(k_nearest(&two, 8), vec![vec![1], vec![0]]);
        // All on one spot: every other point ties, the lowest indices win.
        let same = vec![Vector3::new(0.5, 0.5, 1.0); 6];
        assert_eq!(k_nearest(&same, 3)[4], vec![0, 1, 2]);
        // A NaN point is skipped both ways.
        let with_nan = [Vector3::zeros(), Vector3::repeat(f64::NAN), Vector3::x()];
        assert_eq!(k_nearest(&with_nan, 2), vec![vec![2], vec![], vec![0]]);
        assert_eq!(k_nearest(&two, 0), vec![Vec::<u32>::new(); 2]);
    }
}
