//! The simulated world: a box-shaped room sized around the flight path, boxes standing on the
//! floor, free-standing panels and wall posters — all piecewise planar, like the paper's dense
//! prior. Every visible surface is a rectangle ([`Quad`]); `scene.json` stores the object list and
//! the flattened quads, so a consumer can intersect rays with the exact rendered geometry.
//!
//! A quad is `corner + a·û + b·v̂` for `a ∈ [0, |u|]`, `b ∈ [0, |v|]` (û = u/|u|, v̂ = v/|v|, u ⊥ v).
//! It is one-sided: it is seen only from the side its normal `n = û × v̂` points to (room faces
//! point inwards, box faces outwards, a panel is two quads back to back). Its texture is indexed by
//! `(a, b)` in metres. Room faces extend [`ROOM_FACE_OVERLAP_M`] past the room's edges so that
//! corners are closed. Shading is Lambertian with one fixed light, baked per quad into `shade`:
//! the rendered radiance is `albedo(a, b) · shade`, independent of the viewpoint.

use super::rng::SimRng;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Room faces are this much larger than the room on every edge.
pub const ROOM_FACE_OVERLAP_M: f64 = 0.01;
/// Lowest body position is taken as standing on the floor with this landing-gear height.
pub const GROUND_CLEARANCE_M: f64 = 0.12;
/// Horizontal margin between the flight path's bounding box and the walls.
pub const WALL_MARGIN_M: f64 = 1.5;
/// No object comes closer than this to the flight path.
pub const PATH_CLEARANCE_M: f64 = 0.8;

/// Material family: selects the procedural texture style.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceKind {
    Floor,
    Wall,
    Ceiling,
    Box,
    Panel,
    Poster,
}

/// One textured rectangle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quad {
    pub name: String,
    pub corner_m: [f64; 3],
    pub edge_u_m: [f64; 3],
    pub edge_v_m: [f64; 3],
    pub kind: SurfaceKind,
    /// Texture resolution, m per texel.
    pub texel_m: f64,
    pub texture_seed: u64,
    /// Lambertian shading factor in (0, 1].
    pub shade: f64,
}

/// An axis-aligned box standing on the floor (its bottom face is not rendered).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneBox {
    pub min_m: [f64; 3],
    pub max_m: [f64; 3],
}

/// A free-standing two-sided vertical panel or a poster on a wall: `corner + a u + b v`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Panel {
    pub corner_m: [f64; 3],
    pub edge_u_m: [f64; 3],
    pub edge_v_m: [f64; 3],
    pub two_sided: bool,
}

/// The whole scene, as written to `scene.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// `"vidslam-scene/1"`.
    pub format: String,
    /// Human-readable description of the conventions (quad parametrisation, depth encoding).
    pub conventions: String,
    pub seed: u64,
    pub room_min_m: [f64; 3],
    pub room_max_m: [f64; 3],
    pub boxes: Vec<SceneBox>,
    pub panels: Vec<Panel>,
    /// Every rendered surface (room faces, box faces, panel sides, posters).
    pub quads: Vec<Quad>,
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

fn arr(v: Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

const LIGHT_DIR: [f64; 3] = [0.3, -0.4, 1.0];

fn lambert(n: &Vector3<f64>) -> f64 {
    let l = v3(LIGHT_DIR).normalize();
    0.62 + 0.38 * n.dot(&l).max(0.0)
}

impl Quad {
    /// Unit normal of the visible side.
    pub fn normal(&self) -> Vector3<f64> {
        v3(self.edge_u_m).cross(&v3(self.edge_v_m)).normalize()
    }

    /// Ray parameter `λ > 0` of the hit of `origin + λ dir` with the visible side, if any.
    pub fn intersect(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        let n = self.normal();
        let denom = n.dot(dir);
        if denom >= 0.0 {
            return None;
        }
        let c = v3(self.corner_m);
        let lambda = n.dot(&(c - origin)) / denom;
        if lambda <= 0.0 {
            return None;
        }
        let rel = origin + dir * lambda - c;
        let (u, v) = (v3(self.edge_u_m), v3(self.edge_v_m));
        let a = rel.dot(&u) / u.norm_squared();
        let b = rel.dot(&v) / v.norm_squared();
        ((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)).then_some(lambda)
    }

    /// Distance from `p` to the rectangle, m.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        let (u, v) = (v3(self.edge_u_m), v3(self.edge_v_m));
        let rel = p - v3(self.corner_m);
        let a = (rel.dot(&u) / u.norm_squared()).clamp(0.0, 1.0);
        let b = (rel.dot(&v) / v.norm_squared()).clamp(0.0, 1.0);
        (rel - u * a - v * b).norm()
    }

    /// Width and height, m.
    pub fn size_m(&self) -> (f64, f64) {
        (v3(self.edge_u_m).norm(), v3(self.edge_v_m).norm())
    }
}

/// A quad centred at `c` spanning `size_a` along `a_hat` and `size_b` along `b_hat`; the visible
/// side is `a_hat × b_hat`.
fn quad(
    name: String,
    c: Vector3<f64>,
    a_hat: Vector3<f64>,
    b_hat: Vector3<f64>,
    (size_a, size_b): (f64, f64),
    kind: SurfaceKind,
    rng: &mut SimRng,
) -> Quad {
    let n = a_hat.cross(&b_hat);
    let texel_m = match kind {
        SurfaceKind::Floor | SurfaceKind::Wall | SurfaceKind::Ceiling => 0.006,
        _ => 0.004,
    };
    Quad {
        name,
        corner_m: arr(c - a_hat * (0.5 * size_a) - b_hat * (0.5 * size_b)),
        edge_u_m: arr(a_hat * size_a),
        edge_v_m: arr(b_hat * size_b),
        kind,
        texel_m,
        texture_seed: rng.next_u64(),
        shade: lambert(&n),
    }
}

/// The five visible faces of a box on the floor, outward normals, textures upright.
fn box_quads(i: usize, b: &SceneBox, rng: &mut SimRng) -> Vec<Quad> {
    let (lo, hi) = (v3(b.min_m), v3(b.max_m));
    let c = (lo + hi) * 0.5;
    let s = hi - lo;
    let z = Vector3::z();
    let mut out = vec![];
    for (label, n, half, (sa, sb)) in [
        ("+x", Vector3::x(), 0.5 * s.x, (s.y, s.z)),
        ("-x", -Vector3::x(), 0.5 * s.x, (s.y, s.z)),
        ("+y", Vector3::y(), 0.5 * s.y, (s.x, s.z)),
        ("-y", -Vector3::y(), 0.5 * s.y, (s.x, s.z)),
    ] {
        let a_hat = z.cross(&n);
        out.push(quad(
            format!("box{i}.{label}"),
            c + n * half,
            a_hat,
            z,
            (sa, sb),
            SurfaceKind::Box,
            rng,
        ));
    }
    out.push(quad(
        format!("box{i}.top"),
        c + z * (0.5 * s.z),
        Vector3::x(),
        Vector3::y(),
        (s.x, s.y),
        SurfaceKind::Box,
        rng,
    ));
    out
}

/// Distance from `p` to an axis-aligned box.
fn box_distance(lo: &Vector3<f64>, hi: &Vector3<f64>, p: &Vector3<f64>) -> f64 {
    let d = Vector3::new(
        (lo.x - p.x).max(0.0).max(p.x - hi.x),
        (lo.y - p.y).max(0.0).max(p.y - hi.y),
        (lo.z - p.z).max(0.0).max(p.z - hi.z),
    );
    d.norm()
}

impl Scene {
    /// Builds a room around `path_m` (positions the camera/body passes through) with seeded
    /// boxes, panels and posters that keep [`PATH_CLEARANCE_M`] from the path.
    pub fn build(path_m: &[Vector3<f64>], seed: u64) -> Scene {
        assert!(!path_m.is_empty(), "scene needs at least one path point");
        let mut rng = SimRng::from_keys(seed, &[0x5C3E]);
        let mut lo = path_m[0];
        let mut hi = path_m[0];
        for p in path_m {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let mut rmin = Vector3::new(
            lo.x - WALL_MARGIN_M,
            lo.y - WALL_MARGIN_M,
            lo.z - GROUND_CLEARANCE_M,
        );
        let mut rmax = Vector3::new(hi.x + WALL_MARGIN_M, hi.y + WALL_MARGIN_M, 0.0);
        rmax.z = (hi.z + 1.0).max(rmin.z + 3.0);
        for ax in 0..2 {
            let short = 6.0 - (rmax[ax] - rmin[ax]);
            if short > 0.0 {
                rmin[ax] -= 0.5 * short;
                rmax[ax] += 0.5 * short;
            }
        }
        let size = rmax - rmin;
        let centre = (rmin + rmax) * 0.5;
        let mut quads = vec![];
        let ov = 2.0 * ROOM_FACE_OVERLAP_M;
        let z = Vector3::z();
        quads.push(quad(
            "floor".into(),
            Vector3::new(centre.x, centre.y, rmin.z),
            Vector3::x(),
            Vector3::y(),
            (size.x + ov, size.y + ov),
            SurfaceKind::Floor,
            &mut rng,
        ));
        quads.push(quad(
            "ceiling".into(),
            Vector3::new(centre.x, centre.y, rmax.z),
            -Vector3::x(),
            Vector3::y(),
            (size.x + ov, size.y + ov),
            SurfaceKind::Ceiling,
            &mut rng,
        ));
        for (label, n, pos, width) in [
            ("wall.-x", Vector3::x(), rmin.x, size.y),
            ("wall.+x", -Vector3::x(), rmax.x, size.y),
            ("wall.-y", Vector3::y(), rmin.y, size.x),
            ("wall.+y", -Vector3::y(), rmax.y, size.x),
        ] {
            let mut c = centre;
            let ax = if n.x != 0.0 { 0 } else { 1 };
            c[ax] = pos;
            quads.push(quad(
                label.into(),
                c,
                z.cross(&n),
                z,
                (width + ov, size.z + ov),
                SurfaceKind::Wall,
                &mut rng,
            ));
        }
        // Path points thinned to <= 2000 for clearance checks.
        let step = path_m.len().div_ceil(2000).max(1);
        let path: Vec<Vector3<f64>> = path_m.iter().step_by(step).copied().collect();
        let clear_of_path =
            |d: &dyn Fn(&Vector3<f64>) -> f64| path.iter().all(|p| d(p) >= PATH_CLEARANCE_M);

        let mut boxes: Vec<SceneBox> = vec![];
        for _ in 0..400 {
            if boxes.len() == 8 {
                break;
            }
            let (sx, sy) = (rng.range(0.4, 1.2), rng.range(0.4, 1.2));
            let sz = rng.range(0.35, 1.7);
            let x0 = rng.range(rmin.x + 0.05, rmax.x - 0.05 - sx);
            let y0 = rng.range(rmin.y + 0.05, rmax.y - 0.05 - sy);
            let blo = Vector3::new(x0, y0, rmin.z);
            let bhi = Vector3::new(x0 + sx, y0 + sy, rmin.z + sz);
            let overlaps = boxes
                .iter()
                .any(|b| (0..2).all(|a| blo[a] < b.max_m[a] + 0.1 && bhi[a] > b.min_m[a] - 0.1));
            if overlaps || !clear_of_path(&|p| box_distance(&blo, &bhi, p)) {
                continue;
            }
            boxes.push(SceneBox {
                min_m: arr(blo),
                max_m: arr(bhi),
            });
        }
        for (i, b) in boxes.iter().enumerate() {
            quads.extend(box_quads(i, b, &mut rng));
        }

        let mut panels: Vec<Panel> = vec![];
        let mut free = 0;
        for _ in 0..400 {
            if free == 4 {
                break;
            }
            let (w, h) = (rng.range(0.8, 1.8), rng.range(0.7, 1.5));
            let yaw = rng.range(0.0, std::f64::consts::PI);
            let bottom = rmin.z + rng.range(0.0, 0.9);
            let c = Vector3::new(
                rng.range(rmin.x + 0.1, rmax.x - 0.1),
                rng.range(rmin.y + 0.1, rmax.y - 0.1),
                bottom + 0.5 * h,
            );
            let a_hat = Vector3::new(yaw.cos(), yaw.sin(), 0.0);
            let front = quad(
                format!("panel{}.front", panels.len()),
                c,
                a_hat,
                z,
                (w, h),
                SurfaceKind::Panel,
                &mut rng,
            );
            let corners = [
                v3(front.corner_m),
                v3(front.corner_m) + v3(front.edge_u_m),
                v3(front.corner_m) + v3(front.edge_v_m),
                v3(front.corner_m) + v3(front.edge_u_m) + v3(front.edge_v_m),
            ];
            let inside = corners
                .iter()
                .all(|p| (0..3).all(|a| p[a] > rmin[a] + 0.05 && p[a] < rmax[a] - 0.05));
            let (plo, phi) = corners
                .iter()
                .fold((corners[0], corners[0]), |(l, h), p| (l.inf(p), h.sup(p)));
            let hits_box = boxes
                .iter()
                .any(|b| (0..3).all(|a| plo[a] < b.max_m[a] + 0.05 && phi[a] > b.min_m[a] - 0.05));
            if !inside || hits_box || !clear_of_path(&|p| front.distance(p)) {
                continue;
            }
            let back = quad(
                format!("panel{}.back", panels.len()),
                c,
                -a_hat,
                z,
                (w, h),
                SurfaceKind::Panel,
                &mut rng,
            );
            panels.push(Panel {
                corner_m: front.corner_m,
                edge_u_m: front.edge_u_m,
                edge_v_m: front.edge_v_m,
                two_sided: true,
            });
            quads.push(front);
            quads.push(back);
            free += 1;
        }
        // Posters, 1 cm in front of the walls.
        for k in 0..4 {
            let wall = quads[2 + rng.below(4)].clone();
            let n = wall.normal();
            let (ww, wh) = wall.size_m();
            let (w, h) = (rng.range(0.6, 1.4), rng.range(0.5, 1.0));
            let a = rng.range(0.5 * w + 0.2, ww - 0.5 * w - 0.2);
            let b = (rng.range(1.0, 2.0)).min(wh - 0.5 * h - 0.1);
            let c =
                v3(wall.corner_m) + v3(wall.edge_u_m).normalize() * a + Vector3::z() * b + n * 0.01;
            let poster = quad(
                format!("poster{k}"),
                c,
                z.cross(&n),
                z,
                (w, h),
                SurfaceKind::Poster,
                &mut rng,
            );
            panels.push(Panel {
                corner_m: poster.corner_m,
                edge_u_m: poster.edge_u_m,
                edge_v_m: poster.edge_v_m,
                two_sided: false,
            });
            quads.push(poster);
        }
        Scene {
            format: "vidslam-scene/1".into(),
            conventions:
                "World frame: gravity-aligned, z up, metres. Each quad is corner + a*u/|u| + \
                          b*v/|v|, a in [0,|u|], b in [0,|v|], visible only from the side of its \
                          normal u x v. Rendered radiance = albedo(a,b) * shade. Depth maps in \
                          mav0/depth0 are z-depth in the camera frame (m along the optical axis) \
                          of the nearest quad hit by the pixel-centre ray at the frame timestamp, \
                          16-bit PNG, value = depth_m * 5000, 0 = no depth."
                    .into(),
            seed,
            room_min_m: arr(rmin),
            room_max_m: arr(rmax),
            boxes,
            panels,
            quads,
        }
    }

    /// Nearest visible quad hit by `origin + λ dir`: `(quad index, λ)`.
    pub fn intersect(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<(usize, f64)> {
        self.quads
            .iter()
            .enumerate()
            .filter_map(|(i, q)| q.intersect(origin, dir).map(|l| (i, l)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Writes `scene.json` (pretty-printed).
    pub fn write_json(&self, path: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        std::fs::write(path, text)
    }

    /// Reads a `scene.json`; errors name the file and the JSON line/column.
    pub fn read_json(path: &Path) -> Result<Scene, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path() -> Vec<Vector3<f64>> {
        (0..200)
            .map(|k| {
                let a = k as f64 * 0.05;
                Vector3::new(1.5 * a.sin(), 1.0 * (2.0 * a).sin(), 1.2 + 0.3 * a.cos())
            })
            .collect()
    }

    #[test]
    fn room_encloses_path_and_objects_keep_clearance() {
        let p = path();
        let s = Scene::build(&p, 11);
        assert!(s.boxes.len() >= 6, "{} boxes", s.boxes.len());
        assert!(s.panels.len() >= 6, "{} panels", s.panels.len());
        for q in &s.quads {
            for x in &p {
                for a in 0..3 {
                    assert!(x[a] > s.room_min_m[a] && x[a] < s.room_max_m[a]);
                }
                if !q.name.starts_with("wall") && q.name != "floor" && q.name != "ceiling" {
                    assert!(q.distance(x) >= PATH_CLEARANCE_M - 1e-9, "{}", q.name);
                }
            }
        }
        // Every ray from a path point hits something (closed room), at positive distance.
        for (k, x) in p.iter().enumerate().step_by(17) {
            let d = Vector3::new(
                (k as f64).cos(),
                (k as f64).sin(),
                0.3 * (k as f64 * 0.7).sin(),
            );
            let (_, l) = s.intersect(x, &d).expect("closed room");
            assert!(l > 0.0);
        }
        // Same seed, same scene; JSON round trip.
        assert_eq!(Scene::build(&p, 11), s);
        assert_ne!(Scene::build(&p, 12), s);
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("scene.json");
        s.write_json(&f).unwrap();
        assert_eq!(Scene::read_json(&f).unwrap(), s);
    }

    #[test]
    fn quads_are_one_sided() {
        let mut rng = SimRng::new(1);
        let q = quad(
            "q".into(),
            Vector3::zeros(),
            Vector3::x(),
            Vector3::y(),
            (2.0, 2.0),
            SurfaceKind::Wall,
            &mut rng,
        );
        let down = Vector3::new(0.1, 0.2, -1.0);
        assert!((q.intersect(&Vector3::new(0.0, 0.0, 2.0), &down).unwrap() - 2.0).abs() < 1e-12);
        assert!(
            q.intersect(&Vector3::new(0.0, 0.0, -2.0), &(-down))
                .is_none()
        );
        assert!(q.intersect(&Vector3::new(3.0, 0.0, 2.0), &down).is_none());
    }
}
