//! Ray-casting renderer: per-pixel rays through the (distorted) camera model, 2x2 stratified
//! supersampling with mip-mapped texture filtering, exposure-time motion blur, vignetting, shot and
//! read noise, 8-bit quantisation; plus the ground-truth depth of every pixel.
//!
//! * Rays: each pixel has [`SAMPLES_PER_PIXEL`] sub-pixel rays at offsets `±0.25 px` and one centre
//!   ray, unprojected once through the camera model (so lens distortion is exact) and stored as
//!   normalised coordinates `(x, y)` of the camera-frame direction `(x, y, 1)`. Because that
//!   direction has unit z, a hit's ray parameter is its z-depth.
//! * Motion blur costs nothing extra: the camera pose is evaluated at [`SAMPLES_PER_PIXEL`] times
//!   stratified over the exposure interval (centred on the frame timestamp), and sub-pixel sample
//!   `k` of pixel `(x, y)` uses time slot `(k + x + 2y) mod 4`, so each pixel integrates the whole
//!   exposure and neighbouring pixels use different space-time pairings.
//! * Culling: quads are clipped to the near plane and projected (undistorted normalised
//!   coordinates) at every time slot; each 16x16-pixel tile only tests the quads whose projected
//!   bounding box overlaps the tile's ray bounds.
//! * Texture filtering: trilinear mip lookup with footprint `z · pitch · sqrt(|d| / |n·d|)`, the
//!   geometric mean of the footprint's two axes, `pitch` being the local sub-sample spacing in
//!   normalised coordinates.
//! * Depth: the centre ray at the frame timestamp; z-depth in the camera frame (m along the optical
//!   axis), NaN where nothing is hit.
//! * Rows are rendered in parallel (rayon); noise uses one random stream per (seed, frame, row), so
//!   the output does not depend on scheduling.

use super::exposure::{Exposure, noise_std_dn, vignette_model};
use super::rng::SimRng;
use super::scene::Scene;
use super::texture::Texture;
use crate::camera::CameraModel;
use crate::image::Image;
use nalgebra::{Isometry3, Vector2, Vector3};
use rayon::prelude::*;

/// Sub-pixel samples per pixel (2x2 stratified).
pub const SAMPLES_PER_PIXEL: usize = 4;
/// Culling tile size, pixels.
pub const TILE_PX: usize = 16;
const Z_NEAR_M: f64 = 1e-3;
const NOISE_STREAM: u64 = 0x4015E;

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "camera model: pixel ({0:.2}, {1:.2}) cannot be unprojected (distortion not invertible there)"
    )]
    Unproject(f64, f64),
    #[error("scene has {0} quads; at most 65535 are supported")]
    TooManyQuads(usize),
}

#[derive(Clone, Copy, Debug)]
struct QuadF {
    corner: [f32; 3],
    n: [f32; 3],
    u: [f32; 3],
    v: [f32; 3],
    len_u: f32,
    len_v: f32,
    shade: f32,
}

/// The scene prepared for rendering: quads in `f32` and their generated textures.
pub struct RenderScene {
    quads: Vec<QuadF>,
    corners: Vec<[Vector3<f64>; 4]>,
    normals: Vec<Vector3<f64>>,
    textures: Vec<Texture>,
}

fn f3(v: &Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

#[inline]
fn dot(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl RenderScene {
    /// Converts the quads and generates every texture (in parallel, each from its own seed).
    pub fn new(scene: &Scene) -> Result<Self, RenderError> {
        if scene.quads.len() > u16::MAX as usize {
            return Err(RenderError::TooManyQuads(scene.quads.len()));
        }
        let textures = scene
            .quads
            .par_iter()
            .map(|q| {
                let (w, h) = q.size_m();
                Texture::generate(w, h, q.texel_m, q.kind, q.texture_seed)
            })
            .collect();
        let v = |a: [f64; 3]| Vector3::new(a[0], a[1], a[2]);
        let quads = scene
            .quads
            .iter()
            .map(|q| {
                let (u, vv) = (v(q.edge_u_m), v(q.edge_v_m));
                QuadF {
                    corner: f3(&v(q.corner_m)),
                    n: f3(&q.normal()),
                    u: f3(&u.normalize()),
                    v: f3(&vv.normalize()),
                    len_u: u.norm() as f32,
                    len_v: vv.norm() as f32,
                    shade: q.shade as f32,
                }
            })
            .collect();
        let corners = scene
            .quads
            .iter()
            .map(|q| {
                let (c, u, vv) = (v(q.corner_m), v(q.edge_u_m), v(q.edge_v_m));
                [c, c + u, c + u + vv, c + vv]
            })
            .collect();
        let normals = scene.quads.iter().map(|q| q.normal()).collect();
        Ok(RenderScene {
            quads,
            corners,
            normals,
            textures,
        })
    }

    /// The generated texture of quad `i`.
    pub fn texture(&self, i: usize) -> &Texture {
        &self.textures[i]
    }
}

/// Per-camera precomputed rays, pixel pitches, vignetting and tile bounds.
pub struct CameraRays {
    width: usize,
    height: usize,
    /// `SAMPLES_PER_PIXEL` normalised directions per pixel, row-major.
    samples: Vec<[f32; 2]>,
    centre: Vec<[f32; 2]>,
    /// Sub-sample spacing in normalised coordinates.
    pitch: Vec<f32>,
    vignette: Vec<f32>,
    tiles_x: usize,
    tiles_y: usize,
    /// `[min_x, max_x, min_y, max_y]` of all rays of each tile.
    tile_bounds: Vec<[f32; 4]>,
}

impl CameraRays {
    pub fn new(cam: &CameraModel) -> Result<Self, RenderError> {
        let (w, h) = (cam.width, cam.height);
        let unproject = |u: f64, v: f64| -> Result<[f32; 2], RenderError> {
            let r = cam
                .unproject(&Vector2::new(u, v))
                .ok_or(RenderError::Unproject(u, v))?;
            Ok([r.x as f32, r.y as f32])
        };
        type RowRays = (Vec<[f32; 2]>, Vec<[f32; 2]>);
        let rows: Vec<Result<RowRays, RenderError>> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut s = Vec::with_capacity(w * SAMPLES_PER_PIXEL);
                let mut c = Vec::with_capacity(w);
                for x in 0..w {
                    for k in 0..SAMPLES_PER_PIXEL {
                        let (ox, oy) = (0.5 * (k % 2) as f64 - 0.25, 0.5 * (k / 2) as f64 - 0.25);
                        s.push(unproject(x as f64 + ox, y as f64 + oy)?);
                    }
                    c.push(unproject(x as f64, y as f64)?);
                }
                Ok((s, c))
            })
            .collect();
        let mut samples = Vec::with_capacity(w * h * SAMPLES_PER_PIXEL);
        let mut centre = Vec::with_capacity(w * h);
        for r in rows {
            let (s, c) = r?;
            samples.extend(s);
            centre.extend(c);
        }
        let dist =
            |a: [f32; 2], b: [f32; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        let mut pitch = vec![0.0f32; w * h];
        let mut vignette = vec![1.0f32; w * h];
        let vig = vignette_model(cam);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (xn, xp) = if x + 1 < w { (i, i + 1) } else { (i - 1, i) };
                let (yn, yp) = if y + 1 < h { (i, i + w) } else { (i - w, i) };
                let px = if w > 1 {
                    dist(centre[xn], centre[xp])
                } else {
                    1.0 / cam.fx as f32
                };
                let py = if h > 1 {
                    dist(centre[yn], centre[yp])
                } else {
                    1.0 / cam.fy as f32
                };
                pitch[i] = 0.5 * (px * py).sqrt();
                vignette[i] = vig.factor(x as f64, y as f64) as f32;
            }
        }
        let (tiles_x, tiles_y) = (w.div_ceil(TILE_PX), h.div_ceil(TILE_PX));
        let mut tile_bounds = vec![
            [
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::INFINITY,
                f32::NEG_INFINITY
            ];
            tiles_x * tiles_y
        ];
        for y in 0..h {
            for x in 0..w {
                let b = &mut tile_bounds[(y / TILE_PX) * tiles_x + x / TILE_PX];
                let i = y * w + x;
                for r in samples[i * SAMPLES_PER_PIXEL..(i + 1) * SAMPLES_PER_PIXEL]
                    .iter()
                    .chain(std::iter::once(&centre[i]))
                {
                    b[0] = b[0].min(r[0]);
                    b[1] = b[1].max(r[0]);
                    b[2] = b[2].min(r[1]);
                    b[3] = b[3].max(r[1]);
                }
            }
        }
        Ok(CameraRays {
            width: w,
            height: h,
            samples,
            centre,
            pitch,
            vignette,
            tiles_x,
            tiles_y,
            tile_bounds,
        })
    }
}

/// Camera poses of one frame: one per time slot of the exposure, and the one at the timestamp.
#[derive(Clone, Debug)]
pub struct FramePoses {
    /// `t_world_cam` at the stratified sample times (all equal for an ideal, blur-free image).
    pub slots: [Isometry3<f64>; SAMPLES_PER_PIXEL],
    /// `t_world_cam` at the frame timestamp (used for depth).
    pub centre: Isometry3<f64>,
}

/// One rendered frame.
#[derive(Clone, Debug)]
pub struct RenderedFrame {
    pub image: Image<u8>,
    /// z-depth (m) of the pixel-centre ray; NaN where no surface was hit.
    pub depth_m: Image<f32>,
    /// Mean vignetted radiance (what the auto exposure meters).
    pub mean_radiance: f64,
    /// Rays that hit nothing (0 in a closed room).
    pub missed_rays: usize,
}

/// A view (pose) prepared for casting.
struct View {
    r_wc: [[f32; 3]; 3],
    /// Per quad: signed distance of the camera to the plane (>0 in front), and the camera's
    /// position along the quad's u and v axes relative to its corner.
    per_quad: Vec<[f32; 3]>,
}

impl View {
    fn new(scene: &RenderScene, t_world_cam: &Isometry3<f64>) -> Self {
        let r = t_world_cam.rotation.to_rotation_matrix();
        let m = r.matrix();
        let o = t_world_cam.translation.vector;
        let of = f3(&o);
        let per_quad = scene
            .quads
            .iter()
            .map(|q| {
                let oc = [
                    of[0] - q.corner[0],
                    of[1] - q.corner[1],
                    of[2] - q.corner[2],
                ];
                [dot(&q.n, &oc), dot(&q.u, &oc), dot(&q.v, &oc)]
            })
            .collect();
        View {
            r_wc: [
                [m[(0, 0)] as f32, m[(0, 1)] as f32, m[(0, 2)] as f32],
                [m[(1, 0)] as f32, m[(1, 1)] as f32, m[(1, 2)] as f32],
                [m[(2, 0)] as f32, m[(2, 1)] as f32, m[(2, 2)] as f32],
            ],
            per_quad,
        }
    }

    #[inline]
    fn dir(&self, r: [f32; 2]) -> [f32; 3] {
        let m = &self.r_wc;
        [
            m[0][0] * r[0] + m[0][1] * r[1] + m[0][2],
            m[1][0] * r[0] + m[1][1] * r[1] + m[1][2],
            m[2][0] * r[0] + m[2][1] * r[1] + m[2][2],
        ]
    }
}

struct Hit {
    quad: usize,
    z_m: f32,
    a_m: f32,
    b_m: f32,
    cos_ratio: f32,
}

#[inline(always)]
fn cast(scene: &RenderScene, view: &View, cands: &[u16], d: &[f32; 3]) -> Option<Hit> {
    let mut best_q = usize::MAX;
    let (mut best_z, mut best_a, mut best_b, mut best_c) = (f32::INFINITY, 0.0, 0.0, 0.0);
    for &qi in cands {
        let qi = qi as usize;
        let pq = &view.per_quad[qi];
        if pq[0] <= 0.0 {
            continue;
        }
        let q = &scene.quads[qi];
        let denom = dot(&q.n, d);
        // z = -pq0 / denom must be positive (denom < 0) and nearer than the best so far.
        if denom >= 0.0 || pq[0] >= best_z * -denom {
            continue;
        }
        let z = -pq[0] / denom;
        let a = pq[1] + z * dot(&q.u, d);
        if !(0.0..=q.len_u).contains(&a) {
            continue;
        }
        let b = pq[2] + z * dot(&q.v, d);
        if !(0.0..=q.len_v).contains(&b) {
            continue;
        }
        (best_q, best_z, best_a, best_b, best_c) = (qi, z, a, b, -denom);
    }
    (best_q != usize::MAX).then_some(Hit {
        quad: best_q,
        z_m: best_z,
        a_m: best_a,
        b_m: best_b,
        cos_ratio: best_c,
    })
}

/// Clips the quad (camera coordinates) to `z >= Z_NEAR_M` and returns the bounding box of its
/// projection in normalised coordinates, or `None` if nothing is in front.
fn projected_bounds(corners_cam: &[Vector3<f64>; 4]) -> Option<[f32; 4]> {
    let mut pts: Vec<Vector3<f64>> = Vec::with_capacity(6);
    for i in 0..4 {
        let (a, b) = (corners_cam[i], corners_cam[(i + 1) % 4]);
        let (ina, inb) = (a.z >= Z_NEAR_M, b.z >= Z_NEAR_M);
        if ina {
            pts.push(a);
        }
        if ina != inb {
            let t = (Z_NEAR_M - a.z) / (b.z - a.z);
            pts.push(a + (b - a) * t);
        }
    }
    if pts.is_empty() {
        return None;
    }
    let mut bb = [
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    for p in pts {
        let (x, y) = ((p.x / p.z) as f32, (p.y / p.z) as f32);
        bb[0] = bb[0].min(x);
        bb[1] = bb[1].max(x);
        bb[2] = bb[2].min(y);
        bb[3] = bb[3].max(y);
    }
    Some(bb)
}

/// Renders frames of one scene through one camera.
pub struct Renderer {
    scene: RenderScene,
    rays: CameraRays,
}

impl Renderer {
    pub fn new(scene: &Scene, camera: &CameraModel) -> Result<Self, RenderError> {
        Ok(Renderer {
            scene: RenderScene::new(scene)?,
            rays: CameraRays::new(camera)?,
        })
    }

    pub fn scene(&self) -> &RenderScene {
        &self.scene
    }

    /// Per-tile candidate quads (flat list + offsets) for the given views.
    fn candidates(&self, poses: &[&Isometry3<f64>]) -> (Vec<u32>, Vec<u16>) {
        let nq = self.scene.quads.len();
        let mut bounds: Vec<Option<[f32; 4]>> = vec![None; nq];
        for pose in poses {
            let inv = pose.inverse();
            let cam_pos = pose.translation.vector;
            for (qi, b) in bounds.iter_mut().enumerate() {
                let c = &self.scene.corners[qi];
                if self.scene.normals[qi].dot(&(cam_pos - c[0])) <= 0.0 {
                    continue; // seen from behind
                }
                let cc = [
                    inv.transform_point(&c[0].into()).coords,
                    inv.transform_point(&c[1].into()).coords,
                    inv.transform_point(&c[2].into()).coords,
                    inv.transform_point(&c[3].into()).coords,
                ];
                if let Some(bb) = projected_bounds(&cc) {
                    *b = Some(match *b {
                        None => bb,
                        Some(o) => [
                            o[0].min(bb[0]),
                            o[1].max(bb[1]),
                            o[2].min(bb[2]),
                            o[3].max(bb[3]),
                        ],
                    });
                }
            }
        }
        let nt = self.rays.tiles_x * self.rays.tiles_y;
        let mut offsets = Vec::with_capacity(nt + 1);
        let mut list = Vec::with_capacity(nt * 4);
        offsets.push(0u32);
        for tb in &self.rays.tile_bounds {
            for (qi, b) in bounds.iter().enumerate() {
                if let Some(b) = b
                    && b[0] <= tb[1]
                    && b[1] >= tb[0]
                    && b[2] <= tb[3]
                    && b[3] >= tb[2]
                {
                    list.push(qi as u16);
                }
            }
            offsets.push(list.len() as u32);
        }
        (offsets, list)
    }

    /// Renders frame number `frame_index` (used to key the noise) at `poses`. With `realism`,
    /// applies vignetting and noise; `exposure` scales radiance to grey levels either way.
    pub fn render(
        &self,
        frame_index: u64,
        poses: &FramePoses,
        exposure: &Exposure,
        realism: bool,
        seed: u64,
    ) -> RenderedFrame {
        let (w, h) = (self.rays.width, self.rays.height);
        let mut pose_refs: Vec<&Isometry3<f64>> = poses.slots.iter().collect();
        pose_refs.push(&poses.centre);
        let (offsets, list) = self.candidates(&pose_refs);
        let views: Vec<View> = pose_refs
            .iter()
            .map(|p| View::new(&self.scene, p))
            .collect();
        let centre_view = &views[SAMPLES_PER_PIXEL];
        let mut image = Image::<u8>::new(w, h);
        let mut depth = Image::<f32>::new(w, h);
        let dn_per_l = exposure.dn_per_radiance() as f32;
        let gain = exposure.gain as f32;
        let rays = &self.rays;
        let scene = &self.scene;
        let row_stats: Vec<(f64, usize)> = image
            .data_mut()
            .par_chunks_mut(w)
            .zip(depth.data_mut().par_chunks_mut(w))
            .enumerate()
            .map(|(y, (img_row, depth_row))| {
                let mut rng = SimRng::from_keys(seed, &[NOISE_STREAM, frame_index, y as u64]);
                let mut sum = 0.0f64;
                let mut missed = 0usize;
                let ty = y / TILE_PX;
                for x in 0..w {
                    let t = ty * rays.tiles_x + x / TILE_PX;
                    let cands = &list[offsets[t] as usize..offsets[t + 1] as usize];
                    let i = y * w + x;
                    let pitch = rays.pitch[i];
                    let mut acc = 0.0f32;
                    for k in 0..SAMPLES_PER_PIXEL {
                        let slot = (k + x + 2 * y) % SAMPLES_PER_PIXEL;
                        let view = &views[slot];
                        let r = rays.samples[i * SAMPLES_PER_PIXEL + k];
                        let d = view.dir(r);
                        match cast(scene, view, cands, &d) {
                            Some(hit) => {
                                let dn = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                                let fp = hit.z_m * pitch * (dn / hit.cos_ratio).sqrt();
                                let tex = &scene.textures[hit.quad];
                                acc +=
                                    tex.sample(hit.a_m, hit.b_m, fp) * scene.quads[hit.quad].shade;
                            }
                            None => missed += 1,
                        }
                    }
                    let mut l = acc * (1.0 / SAMPLES_PER_PIXEL as f32);
                    if realism {
                        l *= rays.vignette[i];
                    }
                    sum += l as f64;
                    let mut dn = l * dn_per_l;
                    if realism {
                        // Irwin-Hall (4 uniforms) approximation of a standard normal.
                        let bits = rng.next_u64();
                        let u: f32 = (0..4)
                            .map(|j| ((bits >> (16 * j)) & 0xFFFF) as f32 * (1.0 / 65536.0))
                            .sum();
                        dn += noise_std_dn(dn, gain) * (u - 2.0) * 1.732_050_8;
                    }
                    img_row[x] = (dn.clamp(0.0, 255.0) + 0.5) as u8; // round half up
                    let dc = centre_view.dir(rays.centre[i]);
                    depth_row[x] = cast(scene, centre_view, cands, &dc).map_or(f32::NAN, |h| h.z_m);
                }
                (sum, missed)
            })
            .collect();
        let (sum, missed) = row_stats
            .iter()
            .fold((0.0, 0), |(s, m), (rs, rm)| (s + rs, m + rm));
        RenderedFrame {
            image,
            depth_m: depth,
            mean_radiance: sum / (w * h) as f64,
            missed_rays: missed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_does_not_depend_on_the_thread_count() {
        let path: Vec<Vector3<f64>> = (0..50)
            .map(|k| Vector3::new(0.05 * k as f64, 0.0, 1.2))
            .collect();
        let scene = Scene::build(&path, 4);
        let cam = CameraModel::euroc_cam0().scaled_to_level(3);
        let r = Renderer::new(&scene, &cam).unwrap();
        // Camera looking along world x (optical axis z_cam = x_world, image y down = -z_world).
        let rot = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0,
        ));
        let pose = |x: f64| {
            Isometry3::from_parts(
                nalgebra::Translation3::new(x, 0.0, 1.2),
                nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
            )
        };
        let poses = FramePoses {
            slots: [pose(0.0), pose(0.01), pose(0.02), pose(0.03)],
            centre: pose(0.015),
        };
        let exp = Exposure::ideal();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| r.render(7, &poses, &exp, true, 9))
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(a.image, b.image);
        assert_eq!(
            a.depth_m
                .data()
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>(),
            b.depth_m
                .data()
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        );
        assert_eq!(a.missed_rays, 0);
        // Looking at the +x wall from x = 0.015: depth is positive and below the room size.
        let room_x = scene.room_max_m[0];
        let d = a.depth_m.get(47, 30) as f64;
        assert!(d > 0.1 && d <= room_x - 0.015 + 1e-3, "{d}");
    }

    #[test]
    fn clipping_keeps_points_in_front() {
        let c = [
            Vector3::new(-1.0, -1.0, -1.0),
            Vector3::new(1.0, -1.0, -1.0),
            Vector3::new(1.0, -1.0, 2.0),
            Vector3::new(-1.0, -1.0, 2.0),
        ];
        let bb = projected_bounds(&c).unwrap();
        // The clipped edge at z = 1 mm projects far out: the box must be huge.
        assert!(bb[0] < -100.0 && bb[1] > 100.0 && bb[3] < -0.4);
        let behind = c.map(|p| Vector3::new(p.x, p.y, -1.0));
        assert!(projected_bounds(&behind).is_none());
    }
}
