//! Lossless grayscale PNG in and out of frame buffers (8-bit ↔ Mono8, 16-bit ↔ Mono16; PNG
//! stores 16-bit samples big-endian, frames little-endian).

use crate::frame::PixelFormat;
use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::Path;

/// Size and format of a grayscale PNG, from its header only.
pub fn read_header(path: &Path) -> Result<(u32, u32, PixelFormat), String> {
    let file = File::open(path).map_err(|e| e.to_string())?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    let info = decoder.read_header_info().map_err(|e| e.to_string())?;
    let format = gray_format(info.color_type, info.bit_depth)?;
    Ok((info.width, info.height, format))
}

fn gray_format(color: png::ColorType, depth: png::BitDepth) -> Result<PixelFormat, String> {
    match (color, depth) {
        (png::ColorType::Grayscale, png::BitDepth::Eight) => Ok(PixelFormat::Mono8),
        (png::ColorType::Grayscale, png::BitDepth::Sixteen) => Ok(PixelFormat::Mono16),
        (c, d) => Err(format!("{c:?} {d:?} PNG is not 8- or 16-bit grayscale")),
    }
}

/// Decodes a grayscale PNG of exactly `width x height` `format` into `out` (tightly packed).
pub fn decode_into(
    path: &Path,
    width_px: u32,
    height_px: u32,
    format: PixelFormat,
    out: &mut [u8],
) -> Result<(), String> {
    let file = File::open(path).map_err(|e| e.to_string())?;
    let mut reader = png::Decoder::new(BufReader::new(file))
        .read_info()
        .map_err(|e| e.to_string())?;
    let info = reader.info();
    let found = gray_format(info.color_type, info.bit_depth)?;
    if (info.width, info.height, found) != (width_px, height_px, format) {
        return Err(format!(
            "image is {}x{} {found}, the stream is {width_px}x{height_px} {format}",
            info.width, info.height
        ));
    }
    reader.next_frame(out).map_err(|e| e.to_string())?;
    if format == PixelFormat::Mono16 {
        for px in out.chunks_exact_mut(2) {
            px.swap(0, 1);
        }
    }
    Ok(())
}

/// Writes tightly packed pixels as a grayscale PNG. `scratch` holds the big-endian copy of
/// Mono16 data and is reused across calls (no allocation once it has grown).
pub fn encode(
    path: &Path,
    width_px: u32,
    height_px: u32,
    format: PixelFormat,
    pixels: &[u8],
    scratch: &mut Vec<u8>,
) -> std::io::Result<()> {
    let file = File::create(path)?;
    let mut w = BufWriter::new(file);
    let mut encoder = png::Encoder::new(&mut w, width_px, height_px);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_compression(png::Compression::Fast);
    let data = match format {
        PixelFormat::Mono8 => {
            encoder.set_depth(png::BitDepth::Eight);
            pixels
        }
        PixelFormat::Mono16 => {
            encoder.set_depth(png::BitDepth::Sixteen);
            scratch.clear();
            scratch.extend(pixels.chunks_exact(2).flat_map(|p| [p[1], p[0]]));
            scratch.as_slice()
        }
    };
    let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
    writer
        .write_image_data(data)
        .map_err(std::io::Error::other)?;
    writer.finish().map_err(std::io::Error::other)?;
    w.flush()
}
