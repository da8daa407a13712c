//! MicroStrain MIP protocol for the 3DM-GX4-25 IMU, written for vidslam.
//!
//! # Layers
//!
//! * [`wire`] — zero-copy views of packets and fields ([`wire::Packet`], [`wire::Field`]) and a
//!   writer that emits them, in the style of smoltcp's `wire` module. `#![no_std]`, no allocation,
//!   no panics: every accessor is bounds-checked and malformed input is an [`wire::Error`].
//! * [`imu`], [`command`], [`reply`] — parsed representations (`parse` / `emit`) of the IMU data
//!   set 0x80, the commands we send (base set 0x01, 3DM set 0x0C) and the device's replies.
//! * [`decoder`] — a streaming [`decoder::Decoder`] fed arbitrary byte chunks; it resynchronises
//!   after garbage or a bad checksum without losing the next valid packet and counts what it
//!   skipped ([`decoder::DecoderStats`]).
//! * `std` feature: [`sample`] — IMU samples in SI units with device time and host receive time.
//! * `serial` feature: [`gx4`] — the [`gx4::Gx4`] serial driver (configure, stream, reopen).
//!
//! # Packet format
//!
//! ```text
//! 0x75 0x65 | set | payload_len | field* | fletcher16 (2 bytes, big-endian)
//! field = len (incl. these 2 header bytes) | descriptor | data (big-endian)
//! ```
//! The checksum runs over sync bytes, header and payload.
//!
//! # Fuzzing
//!
//! `drivers/mip/fuzz` holds a cargo-fuzz target (not a workspace member):
//! `cd drivers/mip/fuzz && cargo +nightly fuzz run decoder`. It feeds arbitrary bytes to the
//! decoder in arbitrary chunkings and parses every packet found; the proptests in
//! `tests/decoder_props.rs` check the same invariants in CI.

#![cfg_attr(not(feature = "std"), no_std)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable
    )
)]

pub mod command;
pub mod decoder;
pub mod descriptor;
pub mod imu;
pub mod reply;
pub mod wire;

#[cfg(feature = "std")]
pub mod sample;

#[cfg(feature = "serial")]
pub mod gx4;

pub use decoder::{Decoder, DecoderStats};
pub use wire::{Error, Field, Packet, PacketWriter};
