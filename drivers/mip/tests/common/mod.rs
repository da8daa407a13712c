//! Test support: a fake 3DM-GX4-25 on a pseudo-terminal.

pub mod fake_gx4;
