//! `vidslam sim` end to end through the binary: output readable by the dataset reader and by
//! `vidslam dataset info`, deterministic per seed, refuses to overwrite, clear input errors.

mod cli;
mod scratch;

use cli::vidslam;
use std::path::Path;
use vidslam::camera::CameraModel;
use vidslam::dataset::{AslDataset, CameraSensor, write_camera_yaml};
use vidslam::sim::write::euroc_cam0_t_body_cam;

fn files_under(root: &Path) -> Vec<std::path::PathBuf> {
    let mut out = vec![];
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

#[test]
fn sim_cli_writes_a_readable_deterministic_dataset() {
    let tmp = scratch::dir("sim-cli");
    std::fs::create_dir_all(&tmp).unwrap();
    let yaml = tmp.join("cam.yaml");
    write_camera_yaml(
        &yaml,
        &CameraSensor {
            model: CameraModel::euroc_cam0().scaled_to_level(2),
            t_body_cam: euroc_cam0_t_body_cam(),
            rate_hz: 20.0,
        },
        "test camera",
    )
    .unwrap();
    let run = |out: &Path, seed: &str| {
        vidslam(&[
            "sim",
            "--out",
            out.to_str().unwrap(),
            "--camera",
            yaml.to_str().unwrap(),
            "--start-s",
            "1.5",
            "--seconds",
            "1",
            "--seed",
            seed,
            "--quiet",
        ])
    };
    let (a, b, c) = (tmp.join("a"), tmp.join("b"), tmp.join("c"));
    for (dir, seed) in [(&a, "5"), (&b, "5"), (&c, "6")] {
        let o = run(dir, seed);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let refused = String::from_utf8_lossy(&run(&a, "5").stderr).to_string();
    assert!(
        refused.contains("already exists") && refused.contains("--force"),
        "{refused}"
    );

    let ds = AslDataset::open(&a).unwrap();
    assert_eq!(ds.camera.model.width, 188);
    let frames: Vec<_> = ds.frames().unwrap().map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), 21);
    let imu: Vec<_> = ds.imu_samples().unwrap().map(|s| s.unwrap()).collect();
    assert_eq!(imu.len(), 201);
    // Camera timestamps are exact multiples of the IMU period from the first IMU sample.
    for f in &frames {
        assert_eq!(f.t.ns_since(imu[0].t) % 5_000_000, 0);
        assert!(ds.load_depth_m(f.t).unwrap().is_some());
    }
    let info = vidslam(&["dataset", "info", a.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        info.status.success() && text.contains("groundtruth+") && text.contains("depth0"),
        "{text}"
    );

    // Same seed: byte-identical files (the timing report aside); another seed: other images.
    let (fa, fb) = (files_under(&a), files_under(&b));
    assert_eq!(fa.len(), fb.len());
    for (pa, pb) in fa.iter().zip(&fb) {
        assert_eq!(pa.strip_prefix(&a).unwrap(), pb.strip_prefix(&b).unwrap());
        if pa.ends_with("sim_report.json") {
            continue;
        }
        assert!(
            std::fs::read(pa).unwrap() == std::fs::read(pb).unwrap(),
            "{} differs",
            pa.display()
        );
    }
    let img = |d: &Path| {
        std::fs::read(
            d.join("mav0/cam0/data")
                .join(frames[10].path.file_name().unwrap()),
        )
        .unwrap()
    };
    assert_ne!(img(&a), img(&c));

    // Bad input: the error names the file and line.
    let bad = tmp.join("bad.csv");
    std::fs::write(&bad, "#t,x\n1,0,0,0,1,0,0,0\n2,0,zero,0,1,0,0,0\n").unwrap();
    let o = vidslam(&[
        "sim",
        "--out",
        tmp.join("d").to_str().unwrap(),
        "--trajectory",
        bad.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("bad.csv:3"), "{err}");
    let o = vidslam(&[
        "sim",
        "--out",
        tmp.join("e").to_str().unwrap(),
        "--trajectory",
        "builtin:nope",
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("available: demo"));
    std::fs::remove_dir_all(&tmp).ok();
}
