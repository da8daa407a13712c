//! Device names and opening: `replay:PATH`, `v4l2:/dev/videoN`, otherwise an Aravis device id
//! (as `arv-tool-0.8` lists it, an IP address, or `Fake_1` for Aravis's in-process fake).

use crate::camera::{Camera, CameraError};
use crate::replay::{Pacing, ReplayCamera};
use std::path::PathBuf;

/// A parsed device name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceName {
    Replay(PathBuf),
    V4l2(PathBuf),
    Aravis(String),
}

impl DeviceName {
    pub fn parse(name: &str) -> Result<Self, CameraError> {
        let empty = |what: &str| CameraError::Open {
            device: name.to_string(),
            reason: format!("empty {what}"),
        };
        if let Some(p) = name.strip_prefix("replay:") {
            if p.is_empty() {
                return Err(empty("replay path"));
            }
            Ok(DeviceName::Replay(PathBuf::from(p)))
        } else if let Some(p) = name.strip_prefix("v4l2:") {
            if p.is_empty() {
                return Err(empty("V4L2 device path"));
            }
            Ok(DeviceName::V4l2(PathBuf::from(p)))
        } else if name.trim().is_empty() {
            Err(empty("device name"))
        } else {
            Ok(DeviceName::Aravis(name.to_string()))
        }
    }
}

/// Opens any device by name. Replays are paced as given.
pub fn open(name: &str, pacing: Pacing) -> Result<Box<dyn Camera>, CameraError> {
    match DeviceName::parse(name)? {
        DeviceName::Replay(path) => Ok(Box::new(ReplayCamera::open(&path, pacing)?)),
        DeviceName::V4l2(path) => open_v4l2(name, &path),
        DeviceName::Aravis(id) => open_aravis(&id),
    }
}

#[cfg(feature = "v4l2")]
fn open_v4l2(name: &str, path: &std::path::Path) -> Result<Box<dyn Camera>, CameraError> {
    let source = crate::v4l2::device::DeviceSource::open(path).map_err(|e| CameraError::Open {
        device: name.to_string(),
        reason: e.to_string(),
    })?;
    Ok(Box::new(crate::v4l2::V4l2Camera::new(source)))
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2(name: &str, _path: &std::path::Path) -> Result<Box<dyn Camera>, CameraError> {
    Err(CameraError::Unsupported {
        device: name.to_string(),
        reason: "this binary was built without the `v4l2` feature (rebuild with `--features v4l2`)"
            .into(),
    })
}

#[cfg(feature = "aravis")]
fn open_aravis(id: &str) -> Result<Box<dyn Camera>, CameraError> {
    Ok(Box::new(crate::aravis_backend::AravisCamera::open(id)?))
}

#[cfg(not(feature = "aravis"))]
fn open_aravis(id: &str) -> Result<Box<dyn Camera>, CameraError> {
    Err(CameraError::Unsupported {
        device: id.to_string(),
        reason: "names an Aravis (GenICam) device, but this binary was built without the `aravis` \
                 feature (rebuild with `--features aravis`; use `replay:PATH` or `v4l2:/dev/videoN` otherwise)"
            .into(),
    })
}

/// One line of `vidslam camera list`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ListedDevice {
    /// Name to pass to [`open`].
    pub name: String,
    pub description: String,
}

/// Lists the devices the enabled backends can see: Aravis devices (with `include_fake`, the
/// in-process `Fake_1` too) and `/dev/video*` nodes. Notes on backends left out of this build
/// are returned as the second value.
pub fn list(include_fake: bool) -> (Vec<ListedDevice>, Vec<String>) {
    let mut devices = Vec::new();
    let mut notes = Vec::new();
    #[cfg(feature = "aravis")]
    {
        if include_fake {
            crate::aravis_backend::enable_fake_interface();
        }
        for d in crate::aravis_backend::list_devices() {
            devices.push(ListedDevice {
                name: d.id.clone(),
                description: format!(
                    "{} {} serial {} ({}, {})",
                    d.vendor, d.model, d.serial, d.protocol, d.address
                ),
            });
        }
    }
    #[cfg(not(feature = "aravis"))]
    {
        let _ = include_fake;
        notes.push("Aravis devices not listed: built without the `aravis` feature".to_string());
    }
    let mut nodes: Vec<_> = std::fs::read_dir("/dev")
        .map(|rd| rd.filter_map(Result::ok).map(|e| e.path()).collect())
        .unwrap_or_default();
    nodes.retain(|p| {
        p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with("video"))
    });
    nodes.sort();
    for p in nodes {
        devices.push(ListedDevice {
            name: format!("v4l2:{}", p.display()),
            description: "V4L2 device node".into(),
        });
    }
    if !cfg!(feature = "v4l2") {
        notes.push(
            "V4L2 nodes are listed but cannot be opened: built without the `v4l2` feature"
                .to_string(),
        );
    }
    (devices, notes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_parsed_by_prefix() {
        assert_eq!(
            DeviceName::parse("replay:/a/b").unwrap(),
            DeviceName::Replay("/a/b".into())
        );
        assert_eq!(
            DeviceName::parse("v4l2:/dev/video0").unwrap(),
            DeviceName::V4l2("/dev/video0".into())
        );
        assert_eq!(
            DeviceName::parse("Fake_1").unwrap(),
            DeviceName::Aravis("Fake_1".into())
        );
        assert!(DeviceName::parse("replay:").is_err());
        assert!(DeviceName::parse(" ").is_err());
    }

    #[cfg(not(feature = "aravis"))]
    #[test]
    fn aravis_names_without_the_feature_say_so() {
        let err = open("Fake_1", Pacing::AsFastAsConsumed)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("without the `aravis` feature"), "{err}");
    }
}
