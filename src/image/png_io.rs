//! PNG decode/encode for 8- and 16-bit grayscale (the `png` crate, pure Rust).

use super::Image;
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum PngError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: PNG decode: {msg}")]
    Decode { path: PathBuf, msg: String },
    #[error("{path}: PNG encode: {msg}")]
    Encode { path: PathBuf, msg: String },
    #[error("{path}: expected {expected}, found {found}")]
    Format {
        path: PathBuf,
        expected: &'static str,
        found: String,
    },
}

fn decode(path: &Path) -> Result<(png::OutputInfo, Vec<u8>), PngError> {
    let file = File::open(path).map_err(|source| PngError::Io {
        path: path.into(),
        source,
    })?;
    let dec = png::Decoder::new(BufReader::new(file));
    let derr = |e: png::DecodingError| PngError::Decode {
        path: path.into(),
        msg: e.to_string(),
    };
    let mut reader = dec.read_info().map_err(derr)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| PngError::Decode {
            path: path.into(),
            msg: "image too large".into(),
        })?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(derr)?;
    buf.truncate(info.buffer_size());
    Ok((info, buf))
}

/// Reads an 8-bit grayscale PNG. RGB(A) images are converted to luma (BT.601), and 16-bit gray is
/// scaled down, so any camera PNG loads.
pub fn read_png_gray8(path: &Path) -> Result<Image<u8>, PngError> {
    let (info, buf) = decode(path)?;
    let (w, h) = (info.width as usize, info.height as usize);
    let n = w * h;
    use png::{BitDepth as B, ColorType as C};
    let data: Vec<u8> = match (info.color_type, info.bit_depth) {
        (C::Grayscale, B::Eight) => buf,
        (C::Grayscale, B::Sixteen) => buf.chunks_exact(2).map(|c| c[0]).collect(),
        (C::Rgb, B::Eight) | (C::Rgba, B::Eight) => {
            let ch = if info.color_type == C::Rgb { 3 } else { 4 };
            buf.chunks_exact(ch)
                .map(|p| {
                    let l = 0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32;
                    l.round() as u8
                })
                .collect()
        }
        (c, b) => {
            return Err(PngError::Format {
                path: path.into(),
                expected: "8/16-bit gray or 8-bit RGB(A)",
                found: format!("{c:?} {b:?}"),
            });
        }
    };
    if data.len() != n {
        return Err(PngError::Decode {
            path: path.into(),
            msg: "short pixel buffer".into(),
        });
    }
    Ok(Image::from_vec(w, h, data))
}

/// Reads a 16-bit grayscale PNG (e.g. a depth map).
pub fn read_png_gray16(path: &Path) -> Result<Image<u16>, PngError> {
    let (info, buf) = decode(path)?;
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(PngError::Format {
            path: path.into(),
            expected: "16-bit grayscale",
            found: format!("{:?} {:?}", info.color_type, info.bit_depth),
        });
    }
    let data = buf
        .chunks_exact(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect();
    Ok(Image::from_vec(
        info.width as usize,
        info.height as usize,
        data,
    ))
}

fn encode(
    path: &Path,
    w: usize,
    h: usize,
    depth: png::BitDepth,
    bytes: &[u8],
) -> Result<(), PngError> {
    let file = File::create(path).map_err(|source| PngError::Io {
        path: path.into(),
        source,
    })?;
    let mut enc = png::Encoder::new(BufWriter::new(file), w as u32, h as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    let eerr = |e: png::EncodingError| PngError::Encode {
        path: path.into(),
        msg: e.to_string(),
    };
    let mut writer = enc.write_header().map_err(eerr)?;
    writer.write_image_data(bytes).map_err(eerr)?;
    writer.finish().map_err(eerr)
}

/// Writes an 8-bit grayscale PNG.
pub fn write_png_gray8(path: &Path, img: &Image<u8>) -> Result<(), PngError> {
    let mut bytes = Vec::with_capacity(img.width() * img.height());
    for y in 0..img.height() {
        bytes.extend_from_slice(img.row(y));
    }
    encode(
        path,
        img.width(),
        img.height(),
        png::BitDepth::Eight,
        &bytes,
    )
}

/// Writes a 16-bit grayscale PNG (big-endian samples, as PNG stores them).
pub fn write_png_gray16(path: &Path, img: &Image<u16>) -> Result<(), PngError> {
    let mut bytes = Vec::with_capacity(2 * img.width() * img.height());
    for y in 0..img.height() {
        for v in img.row(y) {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
    }
    encode(
        path,
        img.width(),
        img.height(),
        png::BitDepth::Sixteen,
        &bytes,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_8_and_16_bit() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let a = Image::from_fn(7, 3, |x, y| (x * 30 + y) as u8);
        write_png_gray8(&dir.join("a.png"), &a).unwrap();
        assert_eq!(read_png_gray8(&dir.join("a.png")).unwrap(), a);
        let b = Image::from_fn(5, 4, |x, y| (x * 10_000 + y * 7) as u16);
        write_png_gray16(&dir.join("b.png"), &b).unwrap();
        assert_eq!(read_png_gray16(&dir.join("b.png")).unwrap(), b);
        let err = read_png_gray16(&dir.join("a.png")).unwrap_err().to_string();
        assert!(err.contains("a.png") && err.contains("16-bit"), "{err}");
        let err = read_png_gray8(&dir.join("missing.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("missing.png"), "{err}");
    }
}
