//! The ASL reader on the real EuRoC V1_01 clip (shared data) and on a written/re-read dataset.

mod scratch;

use nalgebra::{Isometry3, Vector3};
use vidslam::camera::CameraModel;
use vidslam::dataset::{
    AslDataset, AslWriter, CameraSensor, Event, GroundTruth, GroundTruthState, ImuSensor,
    shared_data_or_skip,
};
use vidslam::image::Image;
use vidslam::imu::{ImuNoise, ImuSample};
use vidslam::time::TimeNs;

fn v101() -> Option<std::path::PathBuf> {
    shared_data_or_skip("euroc/V1_01_easy_micro")
}

#[test]
fn v101_streams_95_frames_and_29120_imu_samples_in_time_order() {
    let Some(root) = v101() else { return };
    let ds = AslDataset::open(&root).unwrap();
    assert_eq!(ds.camera.model, CameraModel::euroc_cam0());
    assert_eq!(ds.camera.rate_hz, 20.0);
    assert!(
        (ds.camera.t_body_cam.translation.vector
            - Vector3::new(-0.0216401454975, -0.064676986768, 0.00981073058949))
        .norm()
            < 1e-12
    );
    assert_eq!(ds.imu.noise, ImuNoise::euroc_adis16448());
    let (mut frames, mut imu, mut last) = (0usize, 0usize, TimeNs(i64::MIN));
    let mut first_frame = None;
    for ev in ds.events().unwrap() {
        let t = match ev.unwrap() {
            Event::Imu(s) => {
                imu += 1;
                s.t
            }
            Event::Frame(f) => {
                frames += 1;
                first_frame.get_or_insert(f.clone());
                f.t
            }
        };
        assert!(t >= last, "events out of order at {t}");
        last = t;
    }
    assert_eq!((frames, imu), (95, 29_120));
    let img = first_frame.unwrap().load().unwrap();
    assert_eq!((img.width(), img.height()), (752, 480));
    let gt = ds.ground_truth().unwrap().unwrap();
    assert_eq!(gt.states.len(), 28_712);
    assert_eq!(gt.states[0].t, TimeNs(1_403_715_274_302_140_000));
    assert!(gt.states[0].v_world_m_s.is_none());
}

fn tmpdir(name: &str) -> std::path::PathBuf {
    scratch::path(&format!("ds-{name}"))
}

fn sensors() -> (CameraSensor, ImuSensor) {
    let model = CameraModel::new(
        64,
        48,
        [50.0, 50.0, 31.5, 23.5],
        vidslam::camera::Distortion::None,
    )
    .unwrap();
    (
        CameraSensor {
            model,
            t_body_cam: Isometry3::identity(),
            rate_hz: 20.0,
        },
        ImuSensor {
            noise: ImuNoise::euroc_adis16448(),
            t_body_imu: Isometry3::identity(),
            rate_hz: 200.0,
        },
    )
}

#[test]
fn written_dataset_reads_back_identically() {
    let root = tmpdir("rt");
    let (cam, imu) = sensors();
    let mut w = AslWriter::create(&root, &cam, &imu, true, "round trip").unwrap();
    let mut gt = GroundTruth::default();
    for k in 0..40i64 {
        let t = TimeNs(1_000_000_000 + k * 5_000_000);
        w.write_imu(&ImuSample {
            t,
            gyro_rad_s: Vector3::new(0.01 * k as f64, 0.0, -0.5),
            accel_m_s2: Vector3::new(0.0, 0.1, 9.81),
        })
        .unwrap();
        gt.states.push(GroundTruthState {
            t,
            t_world_body: Isometry3::new(
                Vector3::new(k as f64 * 0.01, 0.0, 1.0),
                Vector3::new(0.0, 0.0, 0.01 * k as f64),
            ),
            v_world_m_s: Some(Vector3::new(2.0, 0.0, 0.0)),
            gyro_bias_rad_s: Some(Vector3::new(1e-3, 0.0, 0.0)),
            accel_bias_m_s2: Some(Vector3::new(0.0, -0.02, 0.0)),
        });
        if k % 10 == 0 {
            let img = Image::from_fn(64, 48, |x, y| ((x + y + k as usize) % 256) as u8);
            w.write_frame(t, &img).unwrap();
            let depth = Image::from_fn(
                64,
                48,
                |x, _| if x == 0 { 0.0 } else { 1.0 + x as f32 * 0.01 },
            );
            w.write_depth(t, &depth).unwrap();
        }
    }
    w.write_groundtruth(&gt).unwrap();
    w.finish().unwrap();

    let ds = AslDataset::open(&root).unwrap();
    assert_eq!(ds.camera, cam);
    let evs: Vec<Event> = ds.events().unwrap().map(Result::unwrap).collect();
    assert_eq!(evs.len(), 44);
    // At equal time stamps the IMU sample precedes the frame.
    assert!(matches!(evs[0], Event::Imu(_)) && matches!(evs[1], Event::Frame(_)));
    let Event::Frame(f) = &evs[1] else {
        unreachable!()
    };
    assert_eq!(f.load().unwrap().get(5, 7), 12);
    let depth = ds.load_depth_m(f.t).unwrap().unwrap();
    assert_eq!(depth.get(0, 3), 0.0);
    assert!((depth.get(50, 3) - 1.5).abs() < 1e-4);
    let back = ds.ground_truth().unwrap().unwrap();
    assert_eq!(back.states.len(), 40);
    let d = back.states[7].v_world_m_s.unwrap() - gt.states[7].v_world_m_s.unwrap();
    assert!(d.norm() < 1e-9);
    std::fs::remove_dir_all(&root).ok();
}

#[test]
fn broken_datasets_give_file_and_line_errors() {
    let root = tmpdir("broken");
    let (cam, imu) = sensors();
    let w = AslWriter::create(&root, &cam, &imu, false, "broken").unwrap();
    w.finish().unwrap();
    let mav0 = root.join("mav0");
    std::fs::write(
        mav0.join("imu0/data.csv"),
        "#h\n10,0,0,0,0,0,9.8\n5,0,0,0,0,0,9.8\n",
    )
    .unwrap();
    let ds = AslDataset::open(&root).unwrap();
    let e = ds
        .imu_samples()
        .unwrap()
        .nth(1)
        .unwrap()
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("imu0/data.csv:3") && e.contains("not after"),
        "{e}"
    );
    std::fs::write(mav0.join("imu0/data.csv"), "10,0,0,zz,0,0,9.8\n").unwrap();
    let e = ds
        .imu_samples()
        .unwrap()
        .next()
        .unwrap()
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("imu0/data.csv:1") && e.contains("column 4"),
        "{e}"
    );
    std::fs::write(mav0.join("cam0/data.csv"), "#h\n10,10.png\n").unwrap();
    let e = ds
        .frames()
        .unwrap()
        .next()
        .unwrap()
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cam0/data.csv:2") && e.contains("does not exist"),
        "{e}"
    );
    std::fs::write(
        mav0.join("cam0/sensor.yaml"),
        "%YAML:1.0\nresolution: [1, 2]\n",
    )
    .unwrap();
    let e = AslDataset::open(&root).unwrap_err().to_string();
    assert!(
        e.contains("cam0/sensor.yaml") && e.contains("'intrinsics'"),
        "{e}"
    );
    std::fs::remove_dir_all(&root).ok();
}
