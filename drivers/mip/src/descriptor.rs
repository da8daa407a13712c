//! Descriptor numbers of the MIP sets and fields this crate knows (3DM-GX4-25 DCP manual).

/// Base command set.
pub mod base {
    pub const SET: u8 = 0x01;
    pub const PING: u8 = 0x01;
    pub const SET_IDLE: u8 = 0x02;
    pub const GET_DEVICE_INFO: u8 = 0x03;
    pub const RESUME: u8 = 0x06;
    /// "Device reset" in the DCP manual: a soft reset of the firmware.
    pub const SOFT_RESET: u8 = 0x7E;
    /// Reply field: device information.
    pub const REPLY_DEVICE_INFO: u8 = 0x81;
}

/// 3DM command set.
pub mod dm3 {
    pub const SET: u8 = 0x0C;
    pub const GET_IMU_BASE_RATE: u8 = 0x06;
    pub const IMU_MESSAGE_FORMAT: u8 = 0x08;
    pub const ENABLE_STREAM: u8 = 0x11;
    pub const SAVE_STARTUP_SETTINGS: u8 = 0x30;
    pub const UART_BAUD: u8 = 0x40;
    /// Reply fields.
    pub const REPLY_IMU_MESSAGE_FORMAT: u8 = 0x80;
    pub const REPLY_IMU_BASE_RATE: u8 = 0x83;
    pub const REPLY_ENABLE_STREAM: u8 = 0x85;
    pub const REPLY_UART_BAUD: u8 = 0x87;
}

/// IMU data set.
pub mod imu {
    pub const SET: u8 = 0x80;
    pub const SCALED_ACCEL: u8 = 0x04;
    pub const SCALED_GYRO: u8 = 0x05;
    pub const DELTA_THETA: u8 = 0x07;
    pub const DELTA_VELOCITY: u8 = 0x08;
    pub const INTERNAL_TIMESTAMP: u8 = 0x0E;
    pub const GPS_TIMESTAMP: u8 = 0x12;
}

/// Field descriptor of the ACK/NACK reply field, in every command set.
pub const ACK_NACK: u8 = 0xF1;

/// Whether `set` is a descriptor set this crate interprets.
pub fn is_known_set(set: u8) -> bool {
    matches!(set, base::SET | dm3::SET | imu::SET)
}

/// Whether `field` is a field descriptor this crate interprets within `set`.
pub fn is_known_field(set: u8, field: u8) -> bool {
    match set {
        base::SET => matches!(
            field,
            base::PING
                | base::SET_IDLE
                | base::GET_DEVICE_INFO
                | base::RESUME
                | base::SOFT_RESET
                | base::REPLY_DEVICE_INFO
                | ACK_NACK
        ),
        dm3::SET => matches!(
            field,
            dm3::GET_IMU_BASE_RATE
                | dm3::IMU_MESSAGE_FORMAT
                | dm3::ENABLE_STREAM
                | dm3::SAVE_STARTUP_SETTINGS
                | dm3::UART_BAUD
                | dm3::REPLY_IMU_MESSAGE_FORMAT
                | dm3::REPLY_IMU_BASE_RATE
                | dm3::REPLY_ENABLE_STREAM
                | dm3::REPLY_UART_BAUD
                | ACK_NACK
        ),
        imu::SET => matches!(
            field,
            imu::SCALED_ACCEL
                | imu::SCALED_GYRO
                | imu::DELTA_THETA
                | imu::DELTA_VELOCITY
                | imu::INTERNAL_TIMESTAMP
                | imu::GPS_TIMESTAMP
        ),
        _ => false,
    }
}
