//! Bounds-checked big-endian reads and writes (`None` / `false` instead of a panic).

/// Byte at `at`.
pub fn get_u8(b: &[u8], at: usize) -> Option<u8> {
    b.get(at).copied()
}

fn get_array<const N: usize>(b: &[u8], at: usize) -> Option<[u8; N]> {
    let end = at.checked_add(N)?;
    b.get(at..end)?.try_into().ok()
}

/// Big-endian `u16` at `at`.
pub fn get_u16(b: &[u8], at: usize) -> Option<u16> {
    get_array(b, at).map(u16::from_be_bytes)
}

/// Big-endian `u32` at `at`.
pub fn get_u32(b: &[u8], at: usize) -> Option<u32> {
    get_array(b, at).map(u32::from_be_bytes)
}

/// Big-endian IEEE-754 `f32` at `at`.
pub fn get_f32(b: &[u8], at: usize) -> Option<f32> {
    get_array(b, at).map(f32::from_be_bytes)
}

/// Big-endian IEEE-754 `f64` at `at`.
pub fn get_f64(b: &[u8], at: usize) -> Option<f64> {
    get_array(b, at).map(f64::from_be_bytes)
}

fn put(b: &mut [u8], at: usize, bytes: &[u8]) -> bool {
    match at
        .checked_add(bytes.len())
        .and_then(|end| b.get_mut(at..end))
    {
        Some(dst) => {
            dst.copy_from_slice(bytes);
            true
        }
        None => false,
    }
}

/// Writes a big-endian `u16`; `false` if it does not fit.
pub fn put_u16(b: &mut [u8], at: usize, v: u16) -> bool {
    put(b, at, &v.to_be_bytes())
}

/// Writes a big-endian `u32`; `false` if it does not fit.
pub fn put_u32(b: &mut [u8], at: usize, v: u32) -> bool {
    put(b, at, &v.to_be_bytes())
}

/// Writes a big-endian `f32`; `false` if it does not fit.
pub fn put_f32(b: &mut [u8], at: usize, v: f32) -> bool {
    put(b, at, &v.to_be_bytes())
}

/// Writes a big-endian `f64`; `false` if it does not fit.
pub fn put_f64(b: &mut [u8], at: usize, v: f64) -> bool {
    put(b, at, &v.to_be_bytes())
}
