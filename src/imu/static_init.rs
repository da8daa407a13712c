//! Static-start detection and initial attitude / gyro bias from a resting IMU.
