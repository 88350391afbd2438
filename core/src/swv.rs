//! The `.swv` file: a run-length-encoded classified volume that can be streamed one slice
//! at a time from any [`Read`] + [`Seek`] source, with fixed-size buffers.
//!
//! # Format, version 2
//!
//! All integers little-endian; `f32`/`f64` are IEEE 754 little-endian. Offsets are
//! absolute from the start of the file.
//!
//! ## Header: bytes 0..64
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 8]` | magic `89 53 57 56 0D 0A 1A 0A` (`\x89SWV\r\n\x1a\n`, PNG-style: catches text-mode and 7-bit transfers) |
//! | 8 | `u16` | version = 2 (version 1 is read too: its layout byte is 0) |
//! | 10 | `u16` | reserved, 0 |
//! | 12 | `u32 × 3` | dims `nx, ny, nz` (each 1..=4096) |
//! | 24 | `f64 × 3` | spacing `sx, sy, sz` (positive, finite) |
//! | 48 | `u16 × 2` | raw value range `lo, hi` that the 8-bit scalars were quantised over |
//! | 52 | `u8` | opacity threshold: stored voxels have opacity > threshold |
//! | 53 | `u8` | layout: bit `a` set if the copy for principal axis `a` (0 = x, 1 = y, 2 = z) runs its scanlines along the second of its cycle's in-slice axes ([`crate::rle::Layout`]); bits 3–7 zero |
//! | 54 | `u16` | reserved, 0 |
//! | 56 | `u32` | CRC-32 of bytes `64 .. TABLES_END` (look block and slice tables) |
//! | 60 | `u32` | CRC-32 of bytes `0..60` |
//!
//! ## Look block: bytes 64..1728
//!
//! The default appearance a renderer uses for this file (a frontend may override it).
//!
//! | offset | type | field |
//! |---|---|---|
//! | 64 | `[u16; 3] × 256` | colour table: Q15 RGB per 8-bit scalar (values ≤ 32768) |
//! | 1600 | `u8` | 1 if shading is on, else 0 |
//! | 1601 | `u8` | number of lights, 0..=4 |
//! | 1602 | `u16` | reserved, 0 |
//! | 1604 | `f32 × 4` | `ka, kd, ks, shininess` |
//! | 1620 | `(f32 × 3, f32 × 3) × 4` | per light: direction (camera space), RGB colour; unused lights zero |
//! | 1716 | `[u8; 12]` | reserved, 0 |
//!
//! ## Slice tables: bytes 1728..TABLES_END
//!
//! Three tables, for principal axis x, then y, then z; the table for an axis has one
//! 24-byte entry per slice along that axis (`nx`, `ny`, `nz` entries), so
//! `TABLES_END = 1728 + 24·(nx + ny + nz)` and any slice of any axis is reached with one
//! seek, in either traversal direction.
//!
//! | offset in entry | type | field |
//! |---|---|---|
//! | 0 | `u64` | offset of the slice record |
//! | 8 | `u32` | number of run lengths in the slice |
//! | 12 | `u32` | number of stored (non-transparent) voxels in the slice |
//! | 16 | `u32` | CRC-32 of the slice record |
//! | 20 | `u32` | reserved, 0 |
//!
//! ## Slice records
//!
//! A slice perpendicular to principal axis `a` has `nj` scanlines of `ni` voxels, with
//! `(ni, nj)` as in [`crate::rle::Layout::permuted_dims`] for the header's layout. Its
//! record is
//!
//! 1. `nj + 1` scanline entries `(u32 first run, u32 first voxel)`, relative to the
//!    slice (the first is `(0, 0)`, the last is `(runs, voxels)`);
//! 2. `runs` run lengths (`u8`), alternating transparent / non-transparent, starting with
//!    transparent, an even number per scanline, summing to `ni` per scanline
//!    (see [`crate::rle`]);
//! 3. `voxels` voxel records of 4 bytes: opacity `u8` (per unit of the smallest spacing,
//!    before view-dependent correction), quantised scalar `u8`, normal code `u16`
//!    ([`crate::normal`]).
//!
//! Record length = `8·(nj + 1) + runs + 4·voxels`.
//!
//! # Reading
//!
//! [`HeaderParser`] and [`RecordParser`] are sans-io: they are fed bytes in chunks of any
//! size and produce the same result however the input is split. [`StreamSource`] drives
//! them from a reader and holds exactly one slice, in buffers whose capacity is fixed by
//! const generics; every field is validated before use, so a corrupt or hostile file
//! produces an [`Error`], never a panic or an out-of-bounds read.

use crate::classify::{ColorTable, Grid, Voxel};
use crate::error::Error;
use crate::io::{Crc32, IoError, Read, Seek};
use crate::rle::{Axis, Layout, RleSlice, ScanIndex};
use crate::shade::{Light, Lighting, MAX_LIGHTS};
use crate::source::{RleVolume, SliceSource};

/// File signature.
pub const MAGIC: [u8; 8] = [0x89, b'S', b'W', b'V', b'\r', b'\n', 0x1a, b'\n'];
/// Format version this code writes; it reads this one and version 1 (the same format,
/// written before the layout byte, whose copies all follow [`Layout::CYCLE`]).
pub const VERSION: u16 = 2;
/// Header length.
pub const HEADER_LEN: usize = 64;
/// Look block length.
pub const LOOK_LEN: usize = 1664;
/// Offset of the first slice table.
pub const TABLES_START: usize = HEADER_LEN + LOOK_LEN;
/// Bytes per slice-table entry.
pub const ENTRY_LEN: usize = 24;

/// A sink for bytes (the writer side of [`Read`]).
pub trait Write {
    /// Writes all of `buf`.
    fn write_all(&mut self, buf: &[u8]) -> Result<(), IoError>;
}

impl Write for Crc32 {
    fn write_all(&mut self, buf: &[u8]) -> Result<(), IoError> {
        self.update(buf);
        Ok(())
    }
}

/// Default appearance stored with a volume.
#[derive(Clone, Debug)]
pub struct Look {
    /// Colour table (Q15 RGB).
    pub color: ColorTable,
    /// Lighting, `None` for unshaded.
    pub lighting: Option<Lighting>,
}

impl Look {
    /// The settings a file renders with by default: its colours and lighting,
    /// front-to-back compositing, early ray termination at 0.95, no depth cueing and
    /// no shadows (callers change fields as they need).
    pub fn settings(&self) -> crate::render::Settings<'_> {
        crate::render::Settings {
            mode: crate::composite::Mode::Composite,
            color: &self.color,
            lighting: self.lighting.as_ref(),
            ert_threshold: 0.95,
            depth_cue: None,
            shadows: false,
            flat_voxels: Default::default(),
            clip: crate::clip::Clip::NONE,
        }
    }
}

/// Parsed header and look block.
#[derive(Clone, Debug)]
pub struct Header {
    /// Geometry.
    pub grid: Grid,
    /// Raw value range of the quantised scalars.
    pub range: (u16, u16),
    /// Opacity threshold used when encoding.
    pub threshold: u8,
    /// Default look.
    pub look: Look,
    tables_crc: u32,
}

impl Header {
    /// End of the slice tables.
    pub fn tables_end(&self) -> u64 {
        let d = self.grid.dims;
        (TABLES_START + ENTRY_LEN * (d[0] + d[1] + d[2])) as u64
    }

    fn table_entry_offset(&self, axis: Axis, k: usize) -> u64 {
        let d = self.grid.dims;
        let before = match axis {
            Axis::X => 0,
            Axis::Y => d[0],
            Axis::Z => d[0] + d[1],
        };
        (TABLES_START + ENTRY_LEN * (before + k)) as u64
    }
}

/// The `N` bytes at offset `o` of `b`. The callers read fixed offsets of fixed-size
/// buffers, always inside them; past the end would read zeros rather than panic.
fn bytes_at<const N: usize>(b: &[u8], o: usize) -> [u8; N] {
    let bytes = b.get(o..).and_then(|b| b.first_chunk::<N>());
    bytes.copied().unwrap_or([0; N])
}
fn u16_at(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes(bytes_at(b, o))
}
fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(bytes_at(b, o))
}

/// A voxel from its four stored bytes (opacity, scalar, normal little-endian), as
/// `write_record` stores it.
fn voxel_of([opacity, scalar, n0, n1]: [u8; 4]) -> Voxel {
    Voxel {
        opacity,
        scalar,
        normal: u16::from_le_bytes([n0, n1]),
    }
}

/// Copies as many bytes as both slices hold and returns how many: a `copy_from_slice`
/// without its panic on unequal lengths.
fn copy_bytes(dst: &mut [u8], src: &[u8]) -> usize {
    let n = dst.len().min(src.len());
    for (d, s) in dst.iter_mut().zip(src) {
        *d = *s;
    }
    n
}
fn f32_at(b: &[u8], o: usize) -> f32 {
    f32::from_bits(u32_at(b, o))
}
fn f64_at(b: &[u8], o: usize) -> f64 {
    let lo = u32_at(b, o) as u64;
    let hi = u32_at(b, o + 4) as u64;
    f64::from_bits(lo | (hi << 32))
}

/// Sans-io parser for the header and look block: feed it bytes from offset 0 until
/// [`HeaderParser::finish`] succeeds.
pub struct HeaderParser {
    buf: [u8; TABLES_START],
    len: usize,
}

impl Default for HeaderParser {
    fn default() -> Self {
        Self::new()
    }
}

impl HeaderParser {
    /// A parser that has seen nothing.
    pub const fn new() -> Self {
        HeaderParser {
            buf: [0; TABLES_START],
            len: 0,
        }
    }

    /// Bytes still needed.
    pub fn needed(&self) -> usize {
        TABLES_START - self.len
    }

    /// Consumes as many of `bytes` as the header needs; returns how many were taken.
    /// Checks the magic as soon as it is complete, so a wrong file fails fast.
    pub fn feed(&mut self, bytes: &[u8]) -> Result<usize, Error> {
        // The free end of the buffer is `needed()` bytes long.
        let n = copy_bytes(self.buf.get_mut(self.len..).unwrap_or_default(), bytes);
        let before = self.len;
        self.len += n;
        if before < 8 && self.len >= 8 && self.buf[..8] != MAGIC {
            return Err(Error::Format {
                reason: "wrong magic: not a .swv volume",
            });
        }
        Ok(n)
    }

    /// Validates and decodes the complete header and look block.
    pub fn finish(&self) -> Result<Header, Error> {
        if self.len < TABLES_START {
            return Err(Error::Io(IoError::UnexpectedEof));
        }
        let b = &self.buf;
        if b[..8] != MAGIC {
            return Err(Error::Format {
                reason: "wrong magic: not a .swv volume",
            });
        }
        let version = u16_at(b, 8);
        if version != VERSION && version != 1 {
            return Err(Error::Format {
                reason: "unsupported version (this reader knows versions 1 and 2)",
            });
        }
        if u32_at(b, 60) != Crc32::of(&b[..60]) {
            return Err(Error::Format {
                reason: "header checksum mismatch",
            });
        }
        let dims = [
            u32_at(b, 12) as usize,
            u32_at(b, 16) as usize,
            u32_at(b, 20) as usize,
        ];
        let spacing = [f64_at(b, 24), f64_at(b, 32), f64_at(b, 40)];
        let layout = match version {
            // Version 1 wrote the byte as reserved, zero.
            1 => (b[53] == 0).then_some(Layout::CYCLE),
            _ => Layout::from_bits(b[53]),
        };
        let Some(layout) = layout else {
            return Err(Error::Format {
                reason: "unknown bits in the layout byte",
            });
        };
        let grid = Grid::new(dims, spacing)?.with_layout(layout);
        let range = (u16_at(b, 48), u16_at(b, 50));
        if range.0 > range.1 {
            return Err(Error::Format {
                reason: "value range is inverted",
            });
        }
        let mut color = [[0u16; 3]; 256];
        for (q, c) in color.iter_mut().enumerate() {
            for (ch, v) in c.iter_mut().enumerate() {
                *v = u16_at(b, 64 + 6 * q + 2 * ch);
                if *v as u32 > crate::fixed::ONE {
                    return Err(Error::Format {
                        reason: "colour table entry above 1.0",
                    });
                }
            }
        }
        let l = 1600;
        let count = b[l + 1] as usize;
        if count > MAX_LIGHTS || b[l] > 1 {
            return Err(Error::Format {
                reason: "bad lighting block (flag or light count)",
            });
        }
        let lighting = if b[l] == 1 {
            let mut lights = heapless::Vec::new();
            for i in 0..count {
                let o = l + 20 + 24 * i;
                let v = |j: usize| f32_at(b, o + 4 * j) as f64;
                let _ = lights.push(Light {
                    direction: [v(0), v(1), v(2)],
                    color: [v(3), v(4), v(5)],
                });
            }
            let lighting = Lighting {
                ka: f32_at(b, l + 4) as f64,
                kd: f32_at(b, l + 8) as f64,
                ks: f32_at(b, l + 12) as f64,
                shininess: f32_at(b, l + 16) as f64,
                lights,
            };
            lighting.validate().map_err(|_| Error::Format {
                reason: "bad lighting block (coefficients or directions)",
            })?;
            Some(lighting)
        } else {
            None
        };
        Ok(Header {
            grid,
            range,
            threshold: b[52],
            look: Look { color, lighting },
            tables_crc: u32_at(b, 56),
        })
    }
}

/// One slice-table entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceEntry {
    /// Record offset.
    pub offset: u64,
    /// Run lengths.
    pub runs: u32,
    /// Stored voxels.
    pub voxels: u32,
    /// CRC-32 of the record.
    pub crc: u32,
}

impl SliceEntry {
    fn parse(b: &[u8; ENTRY_LEN]) -> Self {
        SliceEntry {
            offset: u32_at(b, 0) as u64 | ((u32_at(b, 4) as u64) << 32),
            runs: u32_at(b, 8),
            voxels: u32_at(b, 12),
            crc: u32_at(b, 16),
        }
    }
    fn bytes(&self) -> [u8; ENTRY_LEN] {
        let mut b = [0u8; ENTRY_LEN];
        b[..8].copy_from_slice(&self.offset.to_le_bytes());
        b[8..12].copy_from_slice(&self.runs.to_le_bytes());
        b[12..16].copy_from_slice(&self.voxels.to_le_bytes());
        b[16..20].copy_from_slice(&self.crc.to_le_bytes());
        b
    }
}

/// Sans-io parser for one slice record, writing into caller buffers.
pub struct RecordParser<'b> {
    scans: &'b mut [ScanIndex],
    runs: &'b mut [u8],
    voxels: &'b mut [Voxel],
    n_scans: usize,
    n_runs: usize,
    n_voxels: usize,
    got_scans: usize,
    got_runs: usize,
    got_voxels: usize,
    pending: [u8; 8],
    pending_len: usize,
    crc: Crc32,
}

impl<'b> RecordParser<'b> {
    /// Prepares to parse a record of `nj` scanlines with the entry's counts; fails if the
    /// buffers are too small for it.
    pub fn new(
        nj: usize,
        entry: &SliceEntry,
        scans: &'b mut [ScanIndex],
        runs: &'b mut [u8],
        voxels: &'b mut [Voxel],
    ) -> Result<Self, Error> {
        let (n_runs, n_voxels) = (entry.runs as usize, entry.voxels as usize);
        crate::error::need("slice scanline capacity", nj + 1, scans.len())?;
        crate::error::need("slice run capacity", n_runs, runs.len())?;
        crate::error::need("slice voxel capacity", n_voxels, voxels.len())?;
        Ok(RecordParser {
            scans,
            runs,
            voxels,
            n_scans: nj + 1,
            n_runs,
            n_voxels,
            got_scans: 0,
            got_runs: 0,
            got_voxels: 0,
            pending: [0; 8],
            pending_len: 0,
            crc: Crc32::new(),
        })
    }

    /// Bytes still needed.
    pub fn remaining(&self) -> usize {
        8 * (self.n_scans - self.got_scans)
            + (self.n_runs - self.got_runs)
            + 4 * (self.n_voxels - self.got_voxels)
            - self.pending_len
    }

    /// Consumes up to the rest of the record from `bytes`; returns bytes taken.
    pub fn feed(&mut self, mut bytes: &[u8]) -> usize {
        let total = bytes.len();
        while !bytes.is_empty() && self.remaining() > 0 {
            // `new` checked that the buffers hold the record's counts, so every `get`
            // below finds its range; had one not, taking nothing ends the loop instead
            // of spinning, and `finish` reports the record short.
            let taken;
            if self.got_scans < self.n_scans {
                let pending = self.pending.get_mut(self.pending_len..8);
                taken = copy_bytes(pending.unwrap_or_default(), bytes);
                self.pending_len += taken;
                if self.pending_len == 8 {
                    if let Some(s) = self.scans.get_mut(self.got_scans) {
                        *s = ScanIndex {
                            run: u32_at(&self.pending, 0),
                            voxel: u32_at(&self.pending, 4),
                        };
                    }
                    self.got_scans += 1;
                    self.pending_len = 0;
                }
            } else if self.got_runs < self.n_runs {
                let runs = self.runs.get_mut(self.got_runs..self.n_runs);
                taken = copy_bytes(runs.unwrap_or_default(), bytes);
                self.got_runs += taken;
            } else if self.pending_len == 0 && bytes.len() >= 4 {
                // Whole voxels straight from the input.
                let dst = self.voxels.get_mut(self.got_voxels..self.n_voxels);
                let dst = dst.unwrap_or_default();
                let whole = (bytes.len() / 4).min(dst.len());
                for (v, c) in dst.iter_mut().zip(bytes.chunks_exact(4)) {
                    *v = voxel_of(bytes_at(c, 0));
                }
                self.got_voxels += whole;
                taken = 4 * whole;
            } else {
                // A voxel split between two inputs, through `pending`.
                let pending = self.pending.get_mut(self.pending_len..4);
                taken = copy_bytes(pending.unwrap_or_default(), bytes);
                self.pending_len += taken;
                if self.pending_len == 4 {
                    if let Some(v) = self.voxels.get_mut(self.got_voxels) {
                        *v = voxel_of(bytes_at(&self.pending, 0));
                    }
                    self.got_voxels += 1;
                    self.pending_len = 0;
                }
            }
            let Some((used, rest)) = bytes.split_at_checked(taken).filter(|_| taken > 0) else {
                break;
            };
            self.crc.update(used);
            bytes = rest;
        }
        total - bytes.len()
    }

    /// Checks the checksum and structure of the complete record and returns the slice.
    pub fn finish(self, ni: usize, nj: usize, crc: u32) -> Result<RleSlice<'b>, Error> {
        if self.remaining() != 0 {
            return Err(Error::Io(IoError::UnexpectedEof));
        }
        if self.crc.finish() != crc {
            return Err(Error::Format {
                reason: "slice checksum mismatch",
            });
        }
        let slice = RleSlice {
            ni,
            nj,
            base: ScanIndex::default(),
            runs: &self.runs[..self.n_runs],
            voxels: &self.voxels[..self.n_voxels],
            scans: &self.scans[..self.n_scans],
            flat: &[],
        };
        slice.validate()?;
        Ok(slice)
    }
}

/// Streams slices of a `.swv` from a reader into fixed buffers: at most `SCANS`
/// scanline entries (the largest `nj + 1`), `RUNS` run lengths and `VOXELS` voxels per
/// slice. Memory: `8·SCANS + RUNS + 4·VOXELS` bytes plus the reader, held once.
pub struct StreamSource<R, const SCANS: usize, const RUNS: usize, const VOXELS: usize> {
    reader: R,
    header: Header,
    scans: [ScanIndex; SCANS],
    runs: [u8; RUNS],
    voxels: [Voxel; VOXELS],
    chunk: usize,
}

/// Bytes read per call from the underlying reader while streaming.
const CHUNK: usize = 256;

impl<R: Read + Seek, const SCANS: usize, const RUNS: usize, const VOXELS: usize>
    StreamSource<R, SCANS, RUNS, VOXELS>
{
    /// Reads and checks the header, look block and slice tables (their checksum), and
    /// checks that every scanline count fits `SCANS`.
    pub fn open(mut reader: R) -> Result<Self, Error> {
        let header = read_header(&mut reader)?;
        for axis in Axis::ALL {
            let [_, nj, _] = header.grid.permuted_dims(axis);
            crate::error::need("slice scanline capacity", nj + 1, SCANS)?;
        }
        Ok(StreamSource {
            reader,
            header,
            scans: [ScanIndex { run: 0, voxel: 0 }; SCANS],
            runs: [0; RUNS],
            voxels: [Voxel {
                opacity: 0,
                scalar: 0,
                normal: 0,
            }; VOXELS],
            chunk: CHUNK,
        })
    }

    /// The parsed header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Gives back the reader.
    pub fn into_inner(self) -> R {
        self.reader
    }

    /// Bytes requested per read (1..=256); the image does not depend on it.
    pub fn set_chunk(&mut self, chunk: usize) {
        self.chunk = chunk.clamp(1, CHUNK);
    }

    /// Reads the table entry of slice `k` along `axis`.
    pub fn entry(&mut self, axis: Axis, k: usize) -> Result<SliceEntry, Error> {
        read_entry(&mut self.reader, &self.header, axis, k)
    }
}

/// Reads and checks the header, look block and slice tables of a `.swv` from offset 0.
pub fn read_header<R: Read + Seek>(reader: &mut R) -> Result<Header, Error> {
    reader.seek(0)?;
    let mut hp = HeaderParser::new();
    let mut buf = [0u8; CHUNK];
    while hp.needed() > 0 {
        let want = hp.needed().min(CHUNK);
        let n = reader.read(&mut buf[..want])?;
        if n == 0 || n > want {
            return Err(Error::Io(IoError::UnexpectedEof));
        }
        hp.feed(&buf[..n])?;
    }
    let header = hp.finish()?;
    let mut crc = Crc32::new();
    crc.update(&hp.buf[HEADER_LEN..]);
    let mut left = header.tables_end() - TABLES_START as u64;
    while left > 0 {
        let want = (left as usize).min(CHUNK);
        let n = reader.read(&mut buf[..want])?;
        if n == 0 || n > want {
            return Err(Error::Io(IoError::UnexpectedEof));
        }
        crc.update(&buf[..n]);
        left -= n as u64;
    }
    if crc.finish() != header.tables_crc {
        return Err(Error::Format {
            reason: "slice table checksum mismatch",
        });
    }
    Ok(header)
}

/// Reads the table entry of slice `k` along `axis`.
pub fn read_entry<R: Read + Seek>(
    reader: &mut R,
    header: &Header,
    axis: Axis,
    k: usize,
) -> Result<SliceEntry, Error> {
    let [_, _, nk] = header.grid.permuted_dims(axis);
    if k >= nk {
        return Err(Error::Source {
            reason: "slice index past the end of the volume",
        });
    }
    reader.seek(header.table_entry_offset(axis, k))?;
    let mut b = [0u8; ENTRY_LEN];
    reader.read_exact(&mut b)?;
    let e = SliceEntry::parse(&b);
    if e.offset < header.tables_end() {
        return Err(Error::Format {
            reason: "slice offset points into the header or tables",
        });
    }
    Ok(e)
}

/// Reads and validates the record of `entry` (slice `k` along `axis`) into caller
/// buffers, `chunk` bytes per read.
#[allow(clippy::too_many_arguments)]
pub fn read_slice<'b, R: Read + Seek>(
    reader: &mut R,
    header: &Header,
    axis: Axis,
    entry: &SliceEntry,
    chunk: usize,
    scans: &'b mut [ScanIndex],
    runs: &'b mut [u8],
    voxels: &'b mut [Voxel],
) -> Result<RleSlice<'b>, Error> {
    let [ni, nj, _] = header.grid.permuted_dims(axis);
    reader.seek(entry.offset)?;
    let mut parser = RecordParser::new(nj, entry, scans, runs, voxels)?;
    let mut buf = [0u8; CHUNK];
    let chunk = chunk.clamp(1, CHUNK);
    while parser.remaining() > 0 {
        let want = parser.remaining().min(chunk);
        let got = buf.get_mut(..want).unwrap_or_default();
        let n = reader.read(got)?;
        match got.get(..n) {
            Some(read) if n > 0 => parser.feed(read),
            _ => return Err(Error::Io(IoError::UnexpectedEof)),
        };
    }
    parser.finish(ni, nj, entry.crc)
}

impl<R: Read + Seek, const SCANS: usize, const RUNS: usize, const VOXELS: usize> SliceSource
    for StreamSource<R, SCANS, RUNS, VOXELS>
{
    fn grid(&self) -> Grid {
        self.header.grid
    }

    fn with_slice<T>(
        &mut self,
        axis: Axis,
        k: usize,
        f: impl FnOnce(&RleSlice<'_>) -> T,
    ) -> Result<T, Error> {
        let entry = self.entry(axis, k)?;
        let slice = read_slice(
            &mut self.reader,
            &self.header,
            axis,
            &entry,
            self.chunk,
            &mut self.scans,
            &mut self.runs,
            &mut self.voxels,
        )?;
        Ok(f(&slice))
    }
}

/// Serialises one slice record.
fn write_record<W: Write>(w: &mut W, s: &RleSlice<'_>) -> Result<(), IoError> {
    for sc in s.scans {
        let mut b = [0u8; 8];
        b[..4].copy_from_slice(&(sc.run - s.base.run).to_le_bytes());
        b[4..].copy_from_slice(&(sc.voxel - s.base.voxel).to_le_bytes());
        w.write_all(&b)?;
    }
    w.write_all(s.runs)?;
    for v in s.voxels {
        let n = v.normal.to_le_bytes();
        w.write_all(&[v.opacity, v.scalar, n[0], n[1]])?;
    }
    Ok(())
}

fn look_bytes(look: &Look) -> Result<[u8; LOOK_LEN], Error> {
    let mut b = [0u8; LOOK_LEN];
    for (q, c) in look.color.iter().enumerate() {
        for (ch, v) in c.iter().enumerate() {
            let o = 6 * q + 2 * ch;
            b[o..o + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    let l = 1600 - HEADER_LEN;
    if let Some(lt) = &look.lighting {
        lt.validate()?;
        b[l] = 1;
        b[l + 1] = lt.lights.len() as u8;
        for (i, x) in [lt.ka, lt.kd, lt.ks, lt.shininess].iter().enumerate() {
            b[l + 4 + 4 * i..l + 8 + 4 * i].copy_from_slice(&(*x as f32).to_le_bytes());
        }
        // At most MAX_LIGHTS lights, which the block has room for.
        for (i, light) in lt.lights.iter().enumerate() {
            let o = l + 20 + 24 * i;
            for (j, x) in light.direction.iter().chain(light.color.iter()).enumerate() {
                let at = b.get_mut(o + 4 * j..).unwrap_or_default();
                copy_bytes(at, &(*x as f32).to_le_bytes());
            }
        }
    }
    Ok(b)
}

/// Visits every slice-table entry in file order, computing record offsets and CRCs.
fn for_each_entry(
    vol: &RleVolume<'_>,
    mut f: impl FnMut(&SliceEntry) -> Result<(), IoError>,
) -> Result<(), Error> {
    let d = vol.grid().dims;
    let mut offset = (TABLES_START + ENTRY_LEN * (d[0] + d[1] + d[2])) as u64;
    for axis in Axis::ALL {
        let a = vol.axis(axis);
        let [_, nj, nk] = vol.grid().permuted_dims(axis);
        for k in 0..nk {
            let s = a.slice(k).ok_or(Error::Source {
                reason: "slice index past the end of the volume",
            })?;
            let mut crc = Crc32::new();
            write_record(&mut crc, &s)?;
            let e = SliceEntry {
                offset,
                runs: s.runs.len() as u32,
                voxels: s.voxels.len() as u32,
                crc: crc.finish(),
            };
            f(&e)?;
            offset += (8 * (nj + 1) + s.runs.len() + 4 * s.voxels.len()) as u64;
        }
    }
    Ok(())
}

/// Writes `vol` as a `.swv` stream.
pub fn write<W: Write>(
    w: &mut W,
    vol: &RleVolume<'_>,
    range: (u16, u16),
    threshold: u8,
    look: &Look,
) -> Result<(), Error> {
    let grid = vol.grid();
    let look_b = look_bytes(look)?;
    let mut tables_crc = Crc32::new();
    tables_crc.update(&look_b);
    for_each_entry(vol, |e| {
        tables_crc.update(&e.bytes());
        Ok(())
    })?;
    let mut h = [0u8; HEADER_LEN];
    h[..8].copy_from_slice(&MAGIC);
    h[8..10].copy_from_slice(&VERSION.to_le_bytes());
    for i in 0..3 {
        h[12 + 4 * i..16 + 4 * i].copy_from_slice(&(grid.dims[i] as u32).to_le_bytes());
        h[24 + 8 * i..32 + 8 * i].copy_from_slice(&grid.spacing[i].to_le_bytes());
    }
    h[48..50].copy_from_slice(&range.0.to_le_bytes());
    h[50..52].copy_from_slice(&range.1.to_le_bytes());
    h[52] = threshold;
    h[53] = grid.layout().bits();
    h[56..60].copy_from_slice(&tables_crc.finish().to_le_bytes());
    let hc = Crc32::of(&h[..60]);
    h[60..64].copy_from_slice(&hc.to_le_bytes());
    w.write_all(&h)?;
    w.write_all(&look_b)?;
    for_each_entry(vol, |e| w.write_all(&e.bytes()))?;
    for axis in Axis::ALL {
        let a = vol.axis(axis);
        let [_, _, nk] = grid.permuted_dims(axis);
        for k in 0..nk {
            if let Some(s) = a.slice(k) {
                write_record(w, &s)?;
            }
        }
    }
    Ok(())
}

/// Buffer capacities a [`StreamSource`] needs for a volume of `dims` in the worst case
/// (every voxel stored, every other voxel transparent), for a file of either layout
/// of its copies: `(SCANS, RUNS, VOXELS)`.
pub const fn worst_case_capacity(dims: [usize; 3]) -> (usize, usize, usize) {
    let mut scans = 0;
    let mut runs = 0;
    let mut voxels = 0;
    let axes = [Axis::X, Axis::Y, Axis::Z];
    let mut a = 0;
    while a < 6 {
        let layout = if a < 3 {
            Layout::CYCLE
        } else {
            Layout::ALL_SWAPPED
        };
        let [ni, nj, _] = layout.permuted_dims(axes[a % 3], dims);
        if nj + 1 > scans {
            scans = nj + 1;
        }
        // Alternating voxels give ni + 1 runs, rounded up to even, per scanline.
        let r = nj * (ni + 2);
        if r > runs {
            runs = r;
        }
        if ni * nj > voxels {
            voxels = ni * nj;
        }
        a += 1;
    }
    (scans, runs, voxels)
}

/// Bytes of the slice buffers of a [`StreamSource`] sized by [`worst_case_capacity`].
pub const fn stream_buffer_bytes(dims: [usize; 3]) -> usize {
    let (scans, runs, voxels) = worst_case_capacity(dims);
    8 * scans + runs + 4 * voxels
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::classify::{self, OpacityTf, Scalars};
    use crate::render::{render, StaticWorkspace};
    use crate::rle::{self, RleAxis};
    use crate::view::Camera;
    use crate::warp::FrameBuffer;
    use std::vec;
    use std::vec::Vec;

    struct VecWriter(Vec<u8>);
    impl Write for VecWriter {
        fn write_all(&mut self, buf: &[u8]) -> Result<(), IoError> {
            self.0.extend_from_slice(buf);
            Ok(())
        }
    }

    /// A reader that returns pseudo-random short reads.
    struct Choppy<'a> {
        inner: crate::io::SliceReader<'a>,
        state: u32,
        max: usize,
    }
    impl Read for Choppy<'_> {
        fn read(&mut self, buf: &mut [u8]) -> Result<usize, IoError> {
            self.state = self.state.wrapping_mul(1664525).wrapping_add(1013904223);
            let n = 1 + (self.state >> 16) as usize % self.max;
            let n = n.min(buf.len());
            self.inner.read(&mut buf[..n])
        }
    }
    impl Seek for Choppy<'_> {
        fn seek(&mut self, pos: u64) -> Result<(), IoError> {
            self.inner.seek(pos)
        }
    }

    const DIMS: [usize; 3] = [20, 14, 17];

    type AxisArrays = (Vec<u8>, Vec<Voxel>, Vec<ScanIndex>);

    fn encoded() -> (Grid, Vec<AxisArrays>) {
        encoded_as(Grid::new(DIMS, [1.0, 1.2, 0.9]).unwrap().layout())
    }

    /// The test volume, its copies laid out as `layout`.
    fn encoded_as(layout: Layout) -> (Grid, Vec<AxisArrays>) {
        let grid = Grid::new(DIMS, [1.0, 1.2, 0.9])
            .unwrap()
            .with_layout(layout);
        let mut data = Vec::new();
        for z in 0..DIMS[2] {
            for y in 0..DIMS[1] {
                for x in 0..DIMS[0] {
                    let d = (x as i32 - 9).pow(2) + (y as i32 - 7).pow(2) + (z as i32 - 8).pow(2);
                    data.push((250 - 4 * d).clamp(0, 255) as u8);
                }
            }
        }
        let pts = [(50.0, [0.0]), (200.0, [0.8])];
        let mut table = [0u8; 256];
        OpacityTf::new(&pts).unwrap().build_table(&mut table);
        let mut dense = vec![Voxel::default(); grid.voxel_count()];
        classify::classify(&grid, Scalars::U8(&data), &table, None, &mut dense).unwrap();
        let mut out = Vec::new();
        for axis in Axis::ALL {
            let sz = rle::measure(&dense, &grid, axis, 2).unwrap();
            let mut r = vec![0; sz.runs];
            let mut v = vec![Voxel::default(); sz.voxels];
            let mut s = vec![ScanIndex::default(); sz.scans];
            rle::encode(&dense, &grid, axis, 2, &mut r, &mut v, &mut s).unwrap();
            out.push((r, v, s));
        }
        (grid, out)
    }

    fn look() -> Look {
        Look {
            color: core::array::from_fn(|q| [(q as u16) << 7, 20000, 32768 - ((q as u16) << 7)]),
            lighting: Some(Lighting::default()),
        }
    }

    fn file() -> Vec<u8> {
        file_of(encoded())
    }

    /// The copies `store` of a volume on `grid`, as one.
    fn volume_of(grid: Grid, store: &[AxisArrays]) -> RleVolume<'_> {
        let axes = Axis::ALL.map(|a| {
            let (r, v, s) = &store[a as usize];
            RleAxis::new(&grid, a, r, v, s).unwrap()
        });
        RleVolume::new(grid, axes).unwrap()
    }

    fn file_of((grid, store): (Grid, Vec<AxisArrays>)) -> Vec<u8> {
        let vol = volume_of(grid, &store);
        let mut w = VecWriter(Vec::new());
        write(&mut w, &vol, (0, 255), 2, &look()).unwrap();
        w.0
    }

    const CAP: (usize, usize, usize) = worst_case_capacity(DIMS);
    type Src<R> = StreamSource<R, { CAP.0 }, { CAP.1 }, { CAP.2 }>;

    fn render_with<S: SliceSource>(src: &mut S, lk: &Look) -> Vec<[u8; 4]> {
        let cam = Camera {
            rotate_x: 25.0,
            rotate_y: -40.0,
            width: 32,
            height: 32,
        };
        let settings = lk.settings();
        let mut ws = std::boxed::Box::new(StaticWorkspace::<2000, 64, 32>::new());
        let mut px = vec![[0u8; 4]; 32 * 32];
        let mut sink = FrameBuffer {
            width: 32,
            pixels: &mut px,
        };
        render(src, &cam, &settings, &mut ws.workspace(), &mut sink).unwrap();
        px
    }

    #[test]
    fn streamed_rendering_equals_in_memory_for_any_chunking() {
        let bytes = file();
        let (grid, store) = encoded();
        let mut mem = volume_of(grid, &store);
        let lk = look();
        let expect = render_with(&mut mem, &lk);
        assert!(expect.iter().any(|p| p[3] > 50));

        let mut whole: Src<_> = StreamSource::open(crate::io::SliceReader::new(&bytes)).unwrap();
        let stored = whole.header().look.clone();
        assert_eq!(stored.color, lk.color);
        assert_eq!(render_with(&mut whole, &stored), expect);
        for (seed, max) in [(1u32, 1usize), (7, 3), (99, 17), (5, 256)] {
            let r = Choppy {
                inner: crate::io::SliceReader::new(&bytes),
                state: seed,
                max,
            };
            let mut s: Src<_> = StreamSource::open(r).unwrap();
            s.set_chunk(max);
            assert_eq!(render_with(&mut s, &stored), expect, "chunks up to {max}");
        }
    }

    #[test]
    fn the_layout_is_written_and_read_back() {
        // DIMS run the x copy's scanlines along z (longer than y) and the y copy's along
        // x (longer than z), both across the cycle, and the z copy's along x, the cycle's.
        assert_eq!(encoded().0.layout().bits(), 0b011);
        for layout in [Layout::CYCLE, Layout::ALL_SWAPPED, encoded().0.layout()] {
            let bytes = file_of(encoded_as(layout));
            assert_eq!(u16_at(&bytes, 8), VERSION);
            let s: Src<_> = StreamSource::open(crate::io::SliceReader::new(&bytes)).unwrap();
            assert_eq!(s.header().grid.layout(), layout);
        }
    }

    #[test]
    fn version_1_files_are_read_in_the_cycle_layout() {
        // A version 1 file is a version 2 file of the cycle layout with its version
        // number changed: it renders as the volume does in memory.
        let (grid, store) = encoded_as(Layout::CYCLE);
        let mut bytes = file_of((grid, store.clone()));
        bytes[8..10].copy_from_slice(&1u16.to_le_bytes());
        refresh_crcs(&mut bytes, None);
        let mut s: Src<_> = StreamSource::open(crate::io::SliceReader::new(&bytes)).unwrap();
        assert_eq!(s.header().grid.layout(), Layout::CYCLE);
        let mut mem = volume_of(grid, &store);
        let lk = look();
        let stored = s.header().look.clone();
        assert_eq!(render_with(&mut s, &stored), render_with(&mut mem, &lk));
        // A version 1 file with a layout byte is corrupt.
        bytes[53] = 1;
        refresh_crcs(&mut bytes, None);
        assert!(matches!(open_err(&bytes), Error::Format { .. }));
    }

    fn open_err(bytes: &[u8]) -> Error {
        match Src::open(crate::io::SliceReader::new(bytes)) {
            Err(e) => e,
            Ok(mut s) => {
                // Header fine: the error must come from the slices.
                for axis in Axis::ALL {
                    let [_, _, nk] = s.header().grid.permuted_dims(axis);
                    for k in 0..nk {
                        if let Err(e) = s.with_slice(axis, k, |_| ()) {
                            return e;
                        }
                    }
                }
                panic!("corrupt file was accepted");
            }
        }
    }

    fn refresh_crcs(b: &mut [u8], slice_entry: Option<usize>) {
        if let Some(e) = slice_entry {
            let o = TABLES_START + ENTRY_LEN * e;
            let off = u32_at(b, o) as usize;
            let runs = u32_at(b, o + 8) as usize;
            let vox = u32_at(b, o + 12) as usize;
            // Entry e < nx is an x-axis slice.
            let [_, nj, _] = encoded().0.permuted_dims(Axis::X);
            let len = 8 * (nj + 1) + runs + 4 * vox;
            let c = Crc32::of(&b[off..off + len]);
            b[o + 16..o + 20].copy_from_slice(&c.to_le_bytes());
        }
        let end = TABLES_START + ENTRY_LEN * (DIMS[0] + DIMS[1] + DIMS[2]);
        let t = Crc32::of(&b[HEADER_LEN..end]);
        b[56..60].copy_from_slice(&t.to_le_bytes());
        let h = Crc32::of(&b[..60]);
        b[60..64].copy_from_slice(&h.to_le_bytes());
    }

    #[test]
    fn hostile_files_get_specific_errors() {
        let good = file();
        let fmt = |e: Error| match e {
            Error::Format { reason } => reason,
            other => panic!("expected a format error, got {other:?}"),
        };
        // Wrong magic.
        let mut b = good.clone();
        b[1] = b'X';
        assert!(fmt(open_err(&b)).contains("magic"));
        // Wrong version.
        let mut b = good.clone();
        b[8] = 3;
        refresh_crcs(&mut b, None);
        assert!(fmt(open_err(&b)).contains("version"));
        // A layout bit past the three axes.
        let mut b = good.clone();
        b[53] |= 8;
        refresh_crcs(&mut b, None);
        assert!(fmt(open_err(&b)).contains("layout"));
        // Header checksum.
        let mut b = good.clone();
        b[20] ^= 1;
        assert!(fmt(open_err(&b)).contains("header checksum"));
        // Table checksum.
        let mut b = good.clone();
        b[TABLES_START + 3] ^= 1;
        assert!(fmt(open_err(&b)).contains("table checksum"));
        // Slice checksum: flip a voxel byte at the end of the file.
        let mut b = good.clone();
        let last = b.len() - 2;
        b[last] ^= 0x55;
        assert!(fmt(open_err(&b)).contains("slice checksum"));
        // Truncated: inside the header, inside the tables, inside a record.
        for cut in [10, TABLES_START + 5, good.len() - 3] {
            assert_eq!(
                open_err(&good[..cut]),
                Error::Io(IoError::UnexpectedEof),
                "cut {cut}"
            );
        }
        // Offset past the end.
        let mut b = good.clone();
        b[TABLES_START + 4] = 0x10;
        refresh_crcs(&mut b, None);
        assert_eq!(open_err(&b), Error::Io(IoError::BadSeek));
        // Offset pointing back into the tables.
        let mut b = good.clone();
        b[TABLES_START..TABLES_START + 8].copy_from_slice(&100u64.to_le_bytes());
        refresh_crcs(&mut b, None);
        assert!(fmt(open_err(&b)).contains("offset points into"));
        // A run longer than its scanline (checksums recomputed so only structure is wrong).
        let mut b = good.clone();
        let off = u32_at(&b, TABLES_START) as usize;
        let first_run = off + 8 * (DIMS[2] + 1);
        b[first_run] = 200;
        refresh_crcs(&mut b, Some(0));
        assert!(matches!(open_err(&b), Error::MalformedRle { .. }));
        // Runs count beyond the compiled capacity.
        let mut b = good.clone();
        b[TABLES_START + 8..TABLES_START + 12].copy_from_slice(&u32::MAX.to_le_bytes());
        refresh_crcs(&mut b, None);
        assert!(matches!(open_err(&b), Error::BufferTooSmall { .. }));
        // Dims beyond capacity: a source compiled for smaller volumes refuses at open.
        let small = StreamSource::<_, 4, 64, 64>::open(crate::io::SliceReader::new(&good));
        assert!(matches!(small, Err(Error::BufferTooSmall { .. })));
        // Absurd dims.
        let mut b = good.clone();
        b[12..16].copy_from_slice(&100_000u32.to_le_bytes());
        refresh_crcs(&mut b, None);
        assert!(matches!(open_err(&b), Error::BadDimensions { .. }));
        // Every single-byte truncation and every bit flip in the first kilobyte and the
        // last records errors or renders, but never panics.
        for cut in (0..good.len()).step_by(97) {
            let _ = open_err_or_ok(&good[..cut]);
        }
        for i in (0..good.len()).step_by(13) {
            let mut b = good.clone();
            b[i] ^= 0xA5;
            let _ = open_err_or_ok(&b);
        }
    }

    fn open_err_or_ok(bytes: &[u8]) -> Result<(), Error> {
        let mut s = Src::open(crate::io::SliceReader::new(bytes))?;
        let lk = s.header().look.clone();
        let cam = Camera {
            rotate_x: 10.0,
            rotate_y: 80.0,
            width: 16,
            height: 16,
        };
        let settings = lk.settings();
        let mut ws = std::boxed::Box::new(StaticWorkspace::<2000, 64, 16>::new());
        let mut px = vec![[0u8; 4]; 256];
        let mut sink = FrameBuffer {
            width: 16,
            pixels: &mut px,
        };
        render(&mut s, &cam, &settings, &mut ws.workspace(), &mut sink)
    }
}
