//! Minimal byte-source traits, shaped like `embedded-io`'s `Read` and `Seek`, so the
//! renderer can stream a volume from flash, an SD card or a file without `std`.
//!
//! The core implements them for `&[u8]` (reading advances the slice, as in
//! `embedded-io`) and for [`SliceReader`] (a seekable cursor over bytes). Frontends wrap
//! their own sources, e.g. `std::fs::File`.

/// An I/O failure, reduced to what the renderer can act on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IoError {
    /// The source ended before the requested bytes.
    UnexpectedEof,
    /// A seek to a position the source cannot reach.
    BadSeek,
    /// Any other failure of the underlying device.
    Device,
}

/// Reads bytes. A read may return fewer bytes than asked for; zero means end of input.
pub trait Read {
    /// Reads up to `buf.len()` bytes into `buf`, returning how many were read.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, IoError>;

    /// Fills `buf` completely, looping over short reads.
    fn read_exact(&mut self, mut buf: &mut [u8]) -> Result<(), IoError> {
        while !buf.is_empty() {
            let n = self.read(buf)?;
            if n == 0 || n > buf.len() {
                return Err(IoError::UnexpectedEof);
            }
            buf = &mut buf[n..];
        }
        Ok(())
    }
}

/// Moves the read position to an absolute byte offset.
pub trait Seek {
    /// Seeks to `pos` bytes from the start.
    fn seek(&mut self, pos: u64) -> Result<(), IoError>;
}

impl Read for &[u8] {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, IoError> {
        let n = buf.len().min(self.len());
        let (head, tail) = self.split_at(n);
        buf[..n].copy_from_slice(head);
        *self = tail;
        Ok(n)
    }
}

/// A seekable reader over a byte slice (e.g. a volume in flash via `include_bytes!`).
#[derive(Clone, Copy, Debug)]
pub struct SliceReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> SliceReader<'a> {
    /// Starts at offset 0.
    pub const fn new(data: &'a [u8]) -> Self {
        SliceReader { data, pos: 0 }
    }
}

impl Read for SliceReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, IoError> {
        let rest = self.data.get(self.pos..).unwrap_or(&[]);
        let n = buf.len().min(rest.len());
        buf[..n].copy_from_slice(&rest[..n]);
        self.pos += n;
        Ok(n)
    }
}

impl Seek for SliceReader<'_> {
    fn seek(&mut self, pos: u64) -> Result<(), IoError> {
        if pos > self.data.len() as u64 {
            return Err(IoError::BadSeek);
        }
        self.pos = pos as usize;
        Ok(())
    }
}

/// CRC-32 (IEEE 802.3, reflected, as in zlib and PNG), computed incrementally.
#[derive(Clone, Copy, Debug)]
pub struct Crc32(u32);

const CRC_TABLE: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// Empty checksum.
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }
    /// Adds bytes.
    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.0;
        for &b in bytes {
            c = CRC_TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8);
        }
        self.0 = c;
    }
    /// The checksum of everything added.
    pub const fn finish(&self) -> u32 {
        !self.0
    }
    /// Checksum of one buffer.
    pub fn of(bytes: &[u8]) -> u32 {
        let mut c = Self::new();
        c.update(bytes);
        c.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_matches_the_standard_check_value() {
        assert_eq!(Crc32::of(b"123456789"), 0xCBF4_3926);
        assert_eq!(Crc32::of(b""), 0);
        let mut c = Crc32::new();
        c.update(b"1234");
        c.update(b"56789");
        assert_eq!(c.finish(), 0xCBF4_3926);
    }

    #[test]
    fn slice_reader_reads_seeks_and_reports_eof() {
        let data = [1u8, 2, 3, 4, 5];
        let mut r = SliceReader::new(&data);
        let mut b = [0u8; 3];
        r.read_exact(&mut b).unwrap();
        assert_eq!(b, [1, 2, 3]);
        assert_eq!(r.read_exact(&mut b), Err(IoError::UnexpectedEof));
        r.seek(1).unwrap();
        r.read_exact(&mut b).unwrap();
        assert_eq!(b, [2, 3, 4]);
        assert_eq!(r.seek(6), Err(IoError::BadSeek));
        let mut s: &[u8] = &data;
        let mut two = [0u8; 2];
        s.read_exact(&mut two).unwrap();
        assert_eq!(s, &[3, 4, 5]);
    }
}
