//! [`Packet`] and [`Field`] views over byte buffers, and [`PacketWriter`].

use super::{
    CHECKSUM_LEN, Error, FIELD_HEADER_LEN, HEADER_LEN, MAX_PAYLOAD_LEN, SYNC1, SYNC2, fletcher16,
    get_u8, get_u16,
};

/// A view of one MIP packet (sync, set, payload length, payload, checksum) over a buffer.
///
/// `new_unchecked` accepts any buffer; accessors then return 0 / empty for missing bytes.
/// `new_checked` verifies the sync bytes, the length and the checksum.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packet<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Packet<T> {
    /// Wraps a buffer without any check.
    pub const fn new_unchecked(buffer: T) -> Self {
        Packet { buffer }
    }

    /// Wraps a buffer holding a complete packet (trailing bytes allowed) after checking sync,
    /// length and checksum.
    pub fn new_checked(buffer: T) -> Result<Self, Error> {
        let p = Packet { buffer };
        p.check()?;
        Ok(p)
    }

    /// Sync, length and checksum check.
    pub fn check(&self) -> Result<(), Error> {
        let b = self.buffer.as_ref();
        if b.len() < HEADER_LEN {
            return Err(Error::Truncated);
        }
        if b.first() != Some(&SYNC1) || b.get(1) != Some(&SYNC2) {
            return Err(Error::BadSync);
        }
        if b.len() < self.total_len() {
            return Err(Error::Truncated);
        }
        let computed = self.compute_checksum();
        let stored = self.checksum();
        if computed != stored {
            return Err(Error::BadChecksum { computed, stored });
        }
        Ok(())
    }

    /// Descriptor set (byte 2).
    pub fn descriptor_set(&self) -> u8 {
        get_u8(self.buffer.as_ref(), 2).unwrap_or(0)
    }

    /// Payload length (byte 3).
    pub fn payload_len(&self) -> usize {
        get_u8(self.buffer.as_ref(), 3).unwrap_or(0) as usize
    }

    /// Header + payload + checksum length declared by the header.
    pub fn total_len(&self) -> usize {
        HEADER_LEN + self.payload_len() + CHECKSUM_LEN
    }

    /// The payload (all fields); shorter if the buffer is truncated.
    pub fn payload(&self) -> &[u8] {
        let b = self.buffer.as_ref();
        let end = (HEADER_LEN + self.payload_len()).min(b.len());
        b.get(HEADER_LEN.min(end)..end).unwrap_or(&[])
    }

    /// The packet bytes (header through checksum); shorter if the buffer is truncated.
    pub fn as_bytes(&self) -> &[u8] {
        let b = self.buffer.as_ref();
        b.get(..self.total_len().min(b.len())).unwrap_or(&[])
    }

    /// The checksum stored in the packet (wire order), 0 if truncated.
    pub fn checksum(&self) -> u16 {
        get_u16(self.buffer.as_ref(), HEADER_LEN + self.payload_len()).unwrap_or(0)
    }

    /// Fletcher-16 over sync, header and payload.
    pub fn compute_checksum(&self) -> u16 {
        let b = self.buffer.as_ref();
        let end = (HEADER_LEN + self.payload_len()).min(b.len());
        fletcher16(b.get(..end).unwrap_or(&[]))
    }

    /// Iterator over the payload's fields; yields one `Err` and stops at a malformed field.
    pub fn fields(&self) -> Fields<'_> {
        Fields {
            payload: self.payload(),
            offset: 0,
            failed: false,
        }
    }

    /// The first field with descriptor `descriptor`, if any (and well formed up to it).
    pub fn field(&self, descriptor: u8) -> Option<Field<&[u8]>> {
        self.fields()
            .map_while(Result::ok)
            .find(|f| f.descriptor() == descriptor)
    }

    /// Returns the wrapped buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }
}

/// A view of one field: length (incl. its 2 header bytes), descriptor, data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field<T: AsRef<[u8]>> {
    buffer: T,
}

impl<'a> Field<&'a [u8]> {
    /// The field's data bytes (after length and descriptor), borrowed from the packet.
    pub fn data(&self) -> &'a [u8] {
        let b = self.buffer;
        let end = self.len().min(b.len());
        b.get(FIELD_HEADER_LEN.min(end)..end).unwrap_or(&[])
    }
}

impl<T: AsRef<[u8]>> Field<T> {
    /// Wraps a buffer starting at a field's length byte, after checking the length.
    pub fn new_checked(buffer: T) -> Result<Self, Error> {
        let b = buffer.as_ref();
        let len = get_u8(b, 0).ok_or(Error::Truncated)?;
        if (len as usize) < FIELD_HEADER_LEN || (len as usize) > b.len() {
            return Err(Error::BadFieldLength { offset: 0, len });
        }
        Ok(Field { buffer })
    }

    /// Field length including its 2 header bytes.
    #[allow(clippy::len_without_is_empty)]
    pub fn len(&self) -> usize {
        get_u8(self.buffer.as_ref(), 0).unwrap_or(0) as usize
    }

    /// Field descriptor.
    pub fn descriptor(&self) -> u8 {
        get_u8(self.buffer.as_ref(), 1).unwrap_or(0)
    }
}

/// Iterator over the fields of a payload. See [`Packet::fields`].
#[derive(Clone, Debug)]
pub struct Fields<'a> {
    payload: &'a [u8],
    offset: usize,
    failed: bool,
}

impl<'a> Iterator for Fields<'a> {
    type Item = Result<Field<&'a [u8]>, Error>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed || self.offset >= self.payload.len() {
            return None;
        }
        let rest = self.payload.get(self.offset..).unwrap_or(&[]);
        let len = get_u8(rest, 0).unwrap_or(0);
        let n = len as usize;
        if n < FIELD_HEADER_LEN || n > rest.len() {
            self.failed = true;
            return Some(Err(Error::BadFieldLength {
                offset: self.offset,
                len,
            }));
        }
        self.offset += n;
        Some(Ok(Field {
            buffer: rest.get(..n).unwrap_or(&[]),
        }))
    }
}

/// Emits a packet into a caller-provided buffer: header, fields one by one, then the checksum.
///
/// ```
/// use vidslam_mip::PacketWriter;
/// let mut buf = [0u8; 16];
/// let mut w = PacketWriter::new(&mut buf, 0x01).unwrap();
/// w.field(0x01, 0, |_| Ok(())).unwrap();
/// let n = w.finish().unwrap();
/// assert_eq!(&buf[..n], &[0x75, 0x65, 0x01, 0x02, 0x02, 0x01, 0xE0, 0xC6]);
/// ```
#[derive(Debug)]
pub struct PacketWriter<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl<'a> PacketWriter<'a> {
    /// Starts a packet of descriptor set `set`; `Err(NoSpace)` if `buf` cannot hold even an empty
    /// packet.
    pub fn new(buf: &'a mut [u8], set: u8) -> Result<Self, Error> {
        let header = buf.get_mut(..HEADER_LEN).ok_or(Error::NoSpace)?;
        header.copy_from_slice(&[SYNC1, SYNC2, set, 0]);
        Ok(PacketWriter {
            buf,
            len: HEADER_LEN,
        })
    }

    /// Appends a field with `data_len` data bytes, filled by `fill` (which gets exactly that many
    /// bytes, zeroed).
    pub fn field(
        &mut self,
        descriptor: u8,
        data_len: usize,
        fill: impl FnOnce(&mut [u8]) -> Result<(), Error>,
    ) -> Result<(), Error> {
        let field_len = FIELD_HEADER_LEN + data_len;
        let payload_len = self.len - HEADER_LEN + field_len;
        if field_len > u8::MAX as usize
            || payload_len > MAX_PAYLOAD_LEN
            || self.len + field_len + CHECKSUM_LEN > self.buf.len()
        {
            return Err(Error::NoSpace);
        }
        let dst = self
            .buf
            .get_mut(self.len..self.len + field_len)
            .ok_or(Error::NoSpace)?;
        dst.fill(0);
        let (head, data) = dst.split_at_mut(FIELD_HEADER_LEN);
        head.copy_from_slice(&[field_len as u8, descriptor]);
        fill(data)?;
        self.len += field_len;
        Ok(())
    }

    /// Appends a field whose data is `data`.
    pub fn field_bytes(&mut self, descriptor: u8, data: &[u8]) -> Result<(), Error> {
        self.field(descriptor, data.len(), |d| {
            d.copy_from_slice(data);
            Ok(())
        })
    }

    /// Writes the payload length and checksum; returns the packet length in bytes.
    pub fn finish(self) -> Result<usize, Error> {
        let payload_len = self.len - HEADER_LEN;
        let len_byte = self.buf.get_mut(3).ok_or(Error::NoSpace)?;
        *len_byte = payload_len as u8;
        let sum = fletcher16(self.buf.get(..self.len).ok_or(Error::NoSpace)?);
        let dst = self
            .buf
            .get_mut(self.len..self.len + CHECKSUM_LEN)
            .ok_or(Error::NoSpace)?;
        dst.copy_from_slice(&sum.to_be_bytes());
        Ok(self.len + CHECKSUM_LEN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_of_a_two_field_packet() {
        let mut buf = [0u8; 32];
        let mut w = PacketWriter::new(&mut buf, 0x80).unwrap();
        w.field_bytes(0x0E, &[0, 0, 1, 0]).unwrap();
        w.field_bytes(0x99, &[7]).unwrap();
        let n = w.finish().unwrap();
        let p = Packet::new_checked(&buf[..n]).unwrap();
        assert_eq!(p.descriptor_set(), 0x80);
        assert_eq!(p.payload_len(), 9);
        let fields: Vec<_> = p.fields().map(|f| f.unwrap()).collect();
        assert_eq!(fields.len(), 2);
        assert_eq!(fields[0].descriptor(), 0x0E);
        assert_eq!(fields[0].data(), &[0, 0, 1, 0]);
        assert_eq!(fields[1].data(), &[7]);
        assert_eq!(p.field(0x99).unwrap().len(), 3);
    }

    #[test]
    fn checked_view_rejects_damage() {
        let ping = [0x75, 0x65, 0x01, 0x02, 0x02, 0x01, 0xE0, 0xC6];
        assert!(Packet::new_checked(&ping[..]).is_ok());
        assert_eq!(
            Packet::new_checked(&ping[..7]).unwrap_err(),
            Error::Truncated
        );
        let mut bad = ping;
        bad[5] = 0x02;
        assert!(matches!(
            Packet::new_checked(&bad[..]),
            Err(Error::BadChecksum { .. })
        ));
        bad[0] = 0x00;
        assert_eq!(Packet::new_checked(&bad[..]).unwrap_err(), Error::BadSync);
    }

    #[test]
    fn malformed_field_length_is_an_error_not_a_panic() {
        // Payload of 3 bytes whose first field claims 9.
        let mut buf = [0x75, 0x65, 0x80, 0x03, 0x09, 0x04, 0x00, 0, 0];
        let sum = fletcher16(&buf[..7]);
        buf[7..9].copy_from_slice(&sum.to_be_bytes());
        let p = Packet::new_checked(&buf[..]).unwrap();
        let mut it = p.fields();
        assert!(matches!(
            it.next(),
            Some(Err(Error::BadFieldLength { offset: 0, len: 9 }))
        ));
        assert!(it.next().is_none());
    }

    #[test]
    fn writer_refuses_overflow() {
        let mut buf = [0u8; 300];
        let mut w = PacketWriter::new(&mut buf, 0x80).unwrap();
        for _ in 0..2 {
            w.field(0x01, 100, |_| Ok(())).unwrap();
        }
        assert_eq!(w.field(0x01, 100, |_| Ok(())), Err(Error::NoSpace));
        let mut small = [0u8; 8];
        let mut w = PacketWriter::new(&mut small, 0x01).unwrap();
        assert_eq!(w.field(0x01, 1, |_| Ok(())), Err(Error::NoSpace));
    }
}
