//! The semidense mapping thread (section IV-A): it owns the keyframe under construction and turns
//! jobs from the tracking thread into immutable map snapshots.
//!
//! Tracking and mapping are joined by two bounded crossbeam channels (jobs in, snapshots out).
//! A snapshot is an `Arc`: the tracking thread swaps it in without a lock and never waits in
//! real-time mode (it drops views when the queue is full, holds a new keyframe back until there
//! is room, and drains snapshots with `try_recv`; the mapper skips stale views, [`MappingOptions`]).
//! In offline mode it waits for the snapshot of each job at a fixed frame lag, which makes a replay
//! deterministic. The dense (superpixel) thread of section IV-B will hang off the same snapshots:
//! [`MappingOutput::keyframe_maps`] is what it will consume.
//!
//! With a [`TrackerKeyframeBuilder`] the mapper also builds the tracker's keyframe of the maps the
//! tracking thread says it may install next ([`InstallHint`], sent with every view), so that
//! installing one costs the tracking thread nothing but the swap; the build does not depend on
//! the keyframe's pose, which the tracker sets when it installs it.

use super::true_view_poses::{TrueCameraPoses, ViewPoser};
use crate::camera::CameraModel;
use crate::image::{Image, Pyramid};
use crate::mapping::semidense::{SemidenseConfig, SemidenseKeyframe, SemidenseMap};
use crate::time::TimeNs;
use crate::tracking::{Keyframe, NUM_LEVELS};
use crossbeam_channel::{Receiver, Sender, bounded};
use nalgebra::{Isometry3, Point3};
use std::collections::VecDeque;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

/// A frame handed to the mapper: image and camera pose (from tracking or the IMU).
#[derive(Clone, Debug)]
pub struct MapFrame {
    pub t: TimeNs,
    pub image: Arc<Image<u8>>,
    pub t_world_cam: Isometry3<f64>,
}

/// Work for the mapping thread. Every job produces exactly one [`MapSnapshot`] with its `seq`.
#[derive(Clone, Debug)]
pub enum MapJob {
    /// Start keyframe `id` at `frame`: propagate the previous keyframe's map (or `seed`) into it
    /// (if `propagate`), then observe `history` (earlier frames, newest first).
    NewKeyframe {
        seq: u64,
        id: u32,
        frame: MapFrame,
        history: Vec<MapFrame>,
        propagate: bool,
        /// The map to propagate instead of the previous keyframe's (a stored keyframe the
        /// tracker returned to), posed in the mapper's world.
        seed: Option<Arc<SemidenseMap>>,
        /// Search range of inverse depth, 1/m (`None`: the configured one).
        inv_depth_range_m_inv: Option<(f64, f64)>,
        hint: InstallHint,
    },
    /// Another view of the current keyframe.
    Observe {
        seq: u64,
        frame: MapFrame,
        hint: InstallHint,
    },
    /// Keyframe `id`'s inverse depths multiplied by `factor` (its adjustment found the scale of
    /// the poses it was triangulated from off); ignored if `id` is no longer the current keyframe.
    ScaleDepths { seq: u64, id: u32, factor: f64 },
}

/// Which maps the tracking thread may install at its next frames, as it knows when it sends a
/// job (the last job's hint holds until the next): the mapper builds the tracker's keyframe of
/// those ([`MapSnapshot::tracker_keyframe`]).
/// A hint that misses costs only time: a map installed without its keyframe built is built then.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InstallHint {
    /// The new keyframe awaited (`pending`), from a map of `min_points` points.
    pub new: Option<NewKeyframeHint>,
    /// The keyframe tracked and the points above which a map of it is taken as a refresh.
    pub refresh: Option<(u32, usize)>,
}

/// The new keyframe the tracker awaits ([`InstallHint::new`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NewKeyframeHint {
    pub id: u32,
    pub min_points: usize,
}

impl InstallHint {
    /// Might a map of keyframe `id` with `points` points be installed?
    pub fn would_install(&self, id: u32, points: usize) -> bool {
        let new = self
            .new
            .is_some_and(|h| h.id == id && points >= h.min_points);
        let refresh = self
            .refresh
            .is_some_and(|(kf, above)| kf == id && points > above);
        new || refresh
    }
}

/// Builds the tracker's keyframe of a snapshot's map, posed at the identity (the tracker poses
/// it when it installs it): the odometry's [`super::map_keyframe::build`], handed in so that this
/// thread need not know the tracker's settings.
#[derive(Clone)]
pub struct TrackerKeyframeBuilder(pub Arc<dyn Fn(&MapSnapshot) -> Keyframe + Send + Sync>);

impl std::fmt::Debug for TrackerKeyframeBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TrackerKeyframeBuilder")
    }
}

impl MapJob {
    pub fn seq(&self) -> u64 {
        match self {
            MapJob::NewKeyframe { seq, .. }
            | MapJob::Observe { seq, .. }
            | MapJob::ScaleDepths { seq, .. } => *seq,
        }
    }
}

/// The current keyframe's map after a job.
#[derive(Clone, Debug)]
pub struct MapSnapshot {
    pub seq: u64,
    pub keyframe_id: u32,
    pub keyframe_t: TimeNs,
    pub keyframe_image: Arc<Image<u8>>,
    /// Its pyramid with gradients (built once per keyframe, on this thread): what the tracker's
    /// keyframe and the keyframe adjustment sample.
    pub keyframe_pyramid: Arc<Pyramid>,
    pub map: Arc<SemidenseMap>,
    /// Views observed by this keyframe so far.
    pub views: usize,
    /// Of these, views after the keyframe.
    pub forward_views: usize,
    /// Time the job took, s.
    pub time_s: f64,
    /// The tracker's keyframe of `map`, posed at the identity, where the tracker said it may
    /// install this map ([`InstallHint`]) and the mapper has a [`TrackerKeyframeBuilder`]. Built
    /// from `map` as sent: a snapshot whose map is replaced must drop it.
    pub tracker_keyframe: Option<Arc<Keyframe>>,
}

/// What the mapping thread leaves behind when its job queue closes.
#[derive(Clone, Debug, Default)]
pub struct MappingOutput {
    /// Every keyframe's last map, in order.
    pub keyframe_maps: Vec<Arc<SemidenseMap>>,
    /// The time of each keyframe of `keyframe_maps`.
    pub keyframe_times: Vec<TimeNs>,
    /// Time per job, s.
    pub job_times_s: Vec<f64>,
    /// Each view's scale against the propagated map, where measured
    /// ([`crate::mapping::semidense::ObserveStats::view_scale`]).
    pub view_scales: Vec<f32>,
    /// Real time: views of the keyframe the mapper skipped to keep up ([`MappingOptions`]).
    pub views_skipped: usize,
    /// Time of each tracker keyframe built here ([`MapSnapshot::tracker_keyframe`]), s.
    pub tracker_keyframe_build_s: Vec<f64>,
}

impl MappingOutput {
    /// All map points in the world frame, m.
    pub fn world_points(&self) -> Vec<Point3<f64>> {
        let mut out = Vec::new();
        for m in &self.keyframe_maps {
            for p in &m.points {
                let Some(ray) = m
                    .camera
                    .unproject(&nalgebra::Vector2::new(p.u_px as f64, p.v_px as f64))
                else {
                    continue;
                };
                out.push(m.t_world_cam * Point3::from(ray / p.inv_depth_m_inv as f64));
            }
        }
        out
    }
}

/// How the mapping thread runs.
#[derive(Clone, Debug)]
pub struct MappingOptions {
    /// Length of the job and snapshot queues.
    pub queue_len: usize,
    /// Real time: each time the mapper is free it takes every job waiting, drops the views
    /// (`Observe`) queued before a new keyframe (they would refine a keyframe already replaced)
    /// and keeps only the newest `max_view_backlog` views of the current one — the map follows the
    /// camera instead of a backlog. Offline every job is done, in order (deterministic).
    pub realtime: bool,
    /// Views kept waiting in real time (at least 1).
    pub max_view_backlog: usize,
    /// The thread's nice value is raised by this much ([`super::thread_priority`]).
    pub nice_increment: i32,
    /// Diagnostic (`vidslam replay --mapping-poses gt`): views are triangulated from the true
    /// motion from their keyframe instead of their tracked poses ([`super::true_view_poses`]).
    pub true_view_poses: Option<Arc<TrueCameraPoses>>,
    /// Builds the tracker's keyframes of the maps it may install next (`None`: the tracking
    /// thread builds them all).
    pub tracker_keyframes: Option<TrackerKeyframeBuilder>,
}

/// Handle of a running mapping thread.
pub struct MappingThread {
    pub jobs: Sender<MapJob>,
    pub snapshots: Receiver<MapSnapshot>,
    join: JoinHandle<MappingOutput>,
}

impl MappingThread {
    /// Starts the thread.
    pub fn spawn(cfg: SemidenseConfig, camera: CameraModel, opts: MappingOptions) -> Self {
        let queue_len = opts.queue_len.max(1);
        let (jtx, jrx) = bounded::<MapJob>(queue_len);
        let (stx, srx) = bounded::<MapSnapshot>(queue_len);
        let join = std::thread::Builder::new()
            .name("vidslam-mapping".into())
            .spawn(move || {
                // `[mapping] parallel`: the candidates are searched on a pool of the mapper's own,
                // whose threads are as low in priority as the mapper.
                let (nice, parallel) = (opts.nice_increment, cfg.parallel);
                super::thread_priority::run_lowered("vidslam-mapping", nice, parallel, || {
                    run(cfg, camera, opts, jrx, stx)
                })
            })
            .expect("spawn the mapping thread");
        MappingThread {
            jobs: jtx,
            snapshots: srx,
            join,
        }
    }

    /// Closes the job queue and waits for the thread's output.
    pub fn finish(self) -> MappingOutput {
        drop(self.jobs);
        // Drain so that a thread blocked on a full snapshot queue can finish.
        let rx = self.snapshots;
        let drain = std::thread::spawn(move || while rx.recv().is_ok() {});
        let out = self.join.join().unwrap_or_default();
        let _ = drain.join();
        out
    }
}

struct Current {
    id: u32,
    t: TimeNs,
    image: Arc<Image<u8>>,
    pyramid: Arc<Pyramid>,
    kf: SemidenseKeyframe,
    views: usize,
    forward_views: usize,
}

/// Real time: drops the views waiting before the last new keyframe and all but the newest
/// `max_views` views after it. Returns how many were dropped.
fn thin_backlog(backlog: &mut VecDeque<MapJob>, max_views: usize) -> usize {
    let before = backlog.len();
    let last_new = backlog
        .iter()
        .rposition(|j| matches!(j, MapJob::NewKeyframe { .. }));
    let mut views_after = backlog
        .iter()
        .skip(last_new.map_or(0, |i| i + 1))
        .filter(|j| matches!(j, MapJob::Observe { .. }))
        .count();
    let mut i = 0;
    backlog.retain(|j| {
        let keep = match j {
            MapJob::Observe { .. } if last_new.is_some_and(|n| i < n) => false,
            MapJob::Observe { .. } if views_after > max_views.max(1) => {
                views_after -= 1;
                false
            }
            _ => true,
        };
        i += 1;
        keep
    });
    before - backlog.len()
}

fn run(
    cfg: SemidenseConfig,
    camera: CameraModel,
    opts: MappingOptions,
    jobs: Receiver<MapJob>,
    snapshots: Sender<MapSnapshot>,
) -> MappingOutput {
    let mut out = MappingOutput::default();
    let mut cur: Option<Current> = None;
    let mut scratch = Image::<f32>::new(camera.width, camera.height);
    let mut backlog = VecDeque::new();
    let mut poser = opts.true_view_poses.clone().map(ViewPoser::new);
    let mut hint = InstallHint::default();
    loop {
        if backlog.is_empty() {
            match jobs.recv() {
                Ok(j) => backlog.push_back(j),
                Err(_) => break,
            }
        }
        if opts.realtime {
            backlog.extend(jobs.try_iter());
            out.views_skipped += thin_backlog(&mut backlog, opts.max_view_backlog);
        }
        let Some(job) = backlog.pop_front() else {
            continue;
        };
        let started = Instant::now();
        let seq = job.seq();
        match job {
            MapJob::NewKeyframe {
                id,
                frame,
                history,
                propagate,
                seed,
                inv_depth_range_m_inv,
                hint: h,
                ..
            } => {
                hint = h;
                let previous = cur.take().map(|c| {
                    let m = Arc::new(c.kf.map());
                    out.keyframe_maps.push(m.clone());
                    out.keyframe_times.push(c.t);
                    m
                });
                if let Some(p) = poser.as_mut() {
                    p.start_keyframe(frame.t, &frame.t_world_cam);
                }
                to_f32(&frame.image, &mut scratch);
                let mut kf = SemidenseKeyframe::new(&scratch, &camera, &frame.t_world_cam, &cfg);
                if let Some((lo, hi)) = inv_depth_range_m_inv {
                    kf.set_inv_depth_range(lo, hi);
                }
                if propagate && let Some(src) = seed.as_ref().or(previous.as_ref()) {
                    kf.propagate_from(src);
                }
                let mut views = 0;
                for h in &history {
                    to_f32(&h.image, &mut scratch);
                    let st = kf.observe(&scratch, &view_pose(&poser, h));
                    out.view_scales.extend(st.view_scale);
                    views += 1;
                }
                cur = Some(Current {
                    id,
                    t: frame.t,
                    pyramid: Arc::new(Pyramid::from_u8(&frame.image, NUM_LEVELS)),
                    image: frame.image,
                    kf,
                    views,
                    forward_views: 0,
                });
            }
            MapJob::Observe { frame, hint: h, .. } => {
                hint = h;
                if let Some(c) = cur.as_mut() {
                    to_f32(&frame.image, &mut scratch);
                    let st = c.kf.observe(&scratch, &view_pose(&poser, &frame));
                    out.view_scales.extend(st.view_scale);
                    c.views += 1;
                    if frame.t > c.t {
                        c.forward_views += 1;
                    }
                }
            }
            MapJob::ScaleDepths { id, factor, .. } => {
                if let Some(c) = cur.as_mut().filter(|c| c.id == id) {
                    c.kf.scale_inv_depths(factor);
                }
            }
        }
        let time_s = started.elapsed().as_secs_f64();
        out.job_times_s.push(time_s);
        let Some(c) = cur.as_ref() else { continue };
        let mut snap = MapSnapshot {
            seq,
            keyframe_id: c.id,
            keyframe_t: c.t,
            keyframe_image: c.image.clone(),
            keyframe_pyramid: c.pyramid.clone(),
            map: Arc::new(c.kf.map()),
            views: c.views,
            forward_views: c.forward_views,
            time_s,
            tracker_keyframe: None,
        };
        if let Some(TrackerKeyframeBuilder(build)) = &opts.tracker_keyframes
            && hint.would_install(c.id, snap.map.points.len())
        {
            let started = Instant::now();
            snap.tracker_keyframe = Some(Arc::new(build(&snap)));
            out.tracker_keyframe_build_s
                .push(started.elapsed().as_secs_f64());
        }
        if snapshots.send(snap).is_err() {
            break;
        }
    }
    if let Some(c) = cur {
        out.keyframe_maps.push(Arc::new(c.kf.map()));
        out.keyframe_times.push(c.t);
    }
    out
}

/// The pose `f` is triangulated from: its tracked one, or the diagnostic's.
fn view_pose(poser: &Option<ViewPoser>, f: &MapFrame) -> Isometry3<f64> {
    poser
        .as_ref()
        .map_or(f.t_world_cam, |p| p.view_pose(f.t, &f.t_world_cam))
}

fn to_f32(src: &Image<u8>, dst: &mut Image<f32>) {
    if (dst.width(), dst.height()) != (src.width(), src.height()) {
        dst.resize(src.width(), src.height());
    }
    for y in 0..src.height() {
        for (d, s) in dst.row_mut(y).iter_mut().zip(src.row(y)) {
            *d = *s as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t_ns: i64) -> MapFrame {
        MapFrame {
            t: TimeNs(t_ns),
            image: Arc::new(Image::new(4, 4)),
            t_world_cam: Isometry3::identity(),
        }
    }

    fn view(seq: u64) -> MapJob {
        MapJob::Observe {
            seq,
            frame: frame(seq as i64),
            hint: InstallHint::default(),
        }
    }

    fn new_keyframe(seq: u64) -> MapJob {
        MapJob::NewKeyframe {
            seq,
            id: seq as u32,
            frame: frame(seq as i64),
            history: Vec::new(),
            propagate: true,
            seed: None,
            inv_depth_range_m_inv: None,
            hint: InstallHint::default(),
        }
    }

    fn seqs(b: &VecDeque<MapJob>) -> Vec<u64> {
        b.iter().map(MapJob::seq).collect()
    }

    #[test]
    fn a_real_time_backlog_keeps_keyframes_and_the_newest_views_of_the_last_one() {
        let mut b: VecDeque<MapJob> = [
            view(1),
            new_keyframe(2),
            view(3),
            MapJob::ScaleDepths {
                seq: 4,
                id: 2,
                factor: 1.1,
            },
            view(5),
            new_keyframe(6),
            view(7),
            view(8),
            view(9),
        ]
        .into_iter()
        .collect();
        assert_eq!(thin_backlog(&mut b, 2), 4);
        assert_eq!(seqs(&b), vec![2, 4, 6, 8, 9]);
    }

    #[test]
    fn a_short_backlog_is_left_alone() {
        let mut b: VecDeque<MapJob> = [new_keyframe(1), view(2), view(3)].into_iter().collect();
        assert_eq!(thin_backlog(&mut b, 2), 0);
        assert_eq!(seqs(&b), vec![1, 2, 3]);
        let mut only_views: VecDeque<MapJob> = (1..=5).map(view).collect();
        assert_eq!(
            thin_backlog(&mut only_views, 0),
            4,
            "at least one view is kept"
        );
        assert_eq!(seqs(&only_views), vec![5]);
    }

    #[test]
    fn a_hint_names_the_new_keyframe_awaited_and_the_refresh_taken() {
        let hint = InstallHint {
            new: Some(NewKeyframeHint {
                id: 5,
                min_points: 100,
            }),
            refresh: Some((4, 1000)),
        };
        assert!(hint.would_install(5, 100));
        assert!(
            !hint.would_install(5, 99),
            "too few points for a new keyframe"
        );
        assert!(hint.would_install(4, 1001));
        assert!(!hint.would_install(4, 1000), "not grown past the refresh");
        assert!(!hint.would_install(3, 100_000), "a keyframe left behind");
        assert!(!InstallHint::default().would_install(5, 100_000));
    }

    #[test]
    fn the_mapper_builds_the_trackers_keyframe_of_the_maps_hinted_only() {
        use crate::camera::{Distortion, PixelRays};
        use crate::tracking::TrackerConfig;
        let camera = CameraModel::new(64, 48, [50.0, 50.0, 31.5, 23.5], Distortion::None).unwrap();
        let (rays, cfg) = (PixelRays::new(&camera), TrackerConfig::default());
        let builds = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let counted = builds.clone();
        let builder = TrackerKeyframeBuilder(Arc::new(move |s: &MapSnapshot| {
            counted.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            super::super::map_keyframe::build(s, Vec::new(), Isometry3::identity(), &rays, &cfg)
        }));
        let mapper = MappingThread::spawn(
            SemidenseConfig::default(),
            camera,
            MappingOptions {
                queue_len: 8,
                realtime: false,
                max_view_backlog: 2,
                nice_increment: 0,
                true_view_poses: None,
                tracker_keyframes: Some(builder),
            },
        );
        let image = Arc::new(Image::from_fn(64, 48, |x, y| {
            (((x / 4 + y / 4) % 2) * 180 + 30) as u8
        }));
        let at = |t_ns: i64, x_m: f64| MapFrame {
            t: TimeNs(t_ns),
            image: image.clone(),
            t_world_cam: Isometry3::translation(x_m, 0.0, 0.0),
        };
        let awaited = |id| InstallHint {
            new: Some(NewKeyframeHint { id, min_points: 0 }),
            refresh: None,
        };
        let jobs = [
            MapJob::NewKeyframe {
                seq: 1,
                id: 7,
                frame: at(0, 0.0),
                history: Vec::new(),
                propagate: false,
                seed: None,
                inv_depth_range_m_inv: None,
                hint: awaited(7),
            },
            MapJob::Observe {
                seq: 2,
                frame: at(1, 0.02),
                hint: InstallHint::default(),
            },
            MapJob::Observe {
                seq: 3,
                frame: at(2, 0.04),
                hint: awaited(6), // (another keyframe's)
            },
            MapJob::Observe {
                seq: 4,
                frame: at(3, 0.06),
                hint: awaited(7),
            },
        ];
        for j in jobs {
            mapper.jobs.send(j).unwrap();
        }
        let snaps: Vec<MapSnapshot> = (0..4).map(|_| mapper.snapshots.recv().unwrap()).collect();
        let out = mapper.finish();
        let built: Vec<bool> = snaps.iter().map(|s| s.tracker_keyframe.is_some()).collect();
        assert_eq!(built, [true, false, false, true]);
        assert_eq!(builds.load(std::sync::atomic::Ordering::SeqCst), 2);
        assert_eq!(out.tracker_keyframe_build_s.len(), 2);
        let kf = snaps[3].tracker_keyframe.as_ref().unwrap();
        assert_eq!((kf.id, kf.t), (7, TimeNs(0)));
        assert_eq!(
            kf.t_world_cam,
            Isometry3::identity(),
            "posed by the tracker"
        );
    }
}
