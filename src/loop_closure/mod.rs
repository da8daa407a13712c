//! Loop closure: the odometry's drift taken out of the published pose when the camera comes back
//! to a place it mapped long ago. Not in the paper (which is an odometry with local maps); it is
//! the standard complement of a visual-inertial odometry (VINS-Mono, ORB-SLAM3): roll and pitch
//! are observed by gravity and stay the odometry's, heading and position drift and are corrected
//! by a 4-DoF pose graph over the keyframes.
//!
//! Layers, each using only the ones above it: [`features`] (corners and binary descriptors on a
//! keyframe's image, guided matching), [`pnp`] (a camera pose from 3D points of an old keyframe's
//! semidense map and their matches in a new keyframe), [`pose_graph`] (the 4-DoF graph);
//! [`loop_shift`] the move a loop asks of the graph, to check one loop against the next;
//! [`two_view`] the direction of a translation between two views whose rotation the gyro gives.

pub mod closer;
pub mod features;
pub mod loop_shift;
pub mod pnp;
pub mod pose_graph;
pub mod two_view;
