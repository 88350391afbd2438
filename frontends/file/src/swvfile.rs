//! `.swv` files on disk: the core's streamed format read and written through
//! `std::fs::File`.

use crate::scene::Encoded;
use shearwarp_core::classify::Voxel;
use shearwarp_core::rle::{Axis, ScanIndex};
use shearwarp_core::Error;
use shearwarp_core::{io, swv};

/// `std::fs::File` (buffered) as the core's byte source.
pub struct FileReader(std::io::BufReader<std::fs::File>);

impl FileReader {
    /// Opens `path` for reading.
    pub fn open(path: &std::path::Path) -> std::io::Result<Self> {
        Ok(FileReader(std::io::BufReader::new(std::fs::File::open(
            path,
        )?)))
    }
}

impl io::Read for FileReader {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, io::IoError> {
        std::io::Read::read(&mut self.0, buf).map_err(|_| io::IoError::Device)
    }
}

impl io::Seek for FileReader {
    fn seek(&mut self, pos: u64) -> Result<(), io::IoError> {
        let len = self
            .0
            .get_ref()
            .metadata()
            .map_err(|_| io::IoError::Device)?
            .len();
        if pos > len {
            return Err(io::IoError::BadSeek);
        }
        std::io::Seek::seek(&mut self.0, std::io::SeekFrom::Start(pos))
            .map(|_| ())
            .map_err(|_| io::IoError::Device)
    }
}

struct FileWriter(std::io::BufWriter<std::fs::File>);

impl swv::Write for FileWriter {
    fn write_all(&mut self, buf: &[u8]) -> Result<(), io::IoError> {
        std::io::Write::write_all(&mut self.0, buf).map_err(|_| io::IoError::Device)
    }
}

/// Failure to read or write a `.swv` file.
#[derive(Debug)]
pub enum SwvError {
    /// The file could not be opened or measured for reading.
    Open(std::path::PathBuf, std::io::Error),
    /// The file's contents are not a valid volume: truncated, corrupt, or inconsistent.
    Invalid(std::path::PathBuf, Error),
    /// The output file could not be created or written.
    Write(std::path::PathBuf, std::io::Error),
    /// The core refused to write the volume.
    Encode(std::path::PathBuf, Error),
}

impl SwvError {
    /// Whether the file read was at fault (the CLI's bad input, exit code 2), rather
    /// than the writing of one.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, SwvError::Open(..) | SwvError::Invalid(..))
    }
}

impl std::fmt::Display for SwvError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SwvError::Open(p, e) | SwvError::Write(p, e) => write!(f, "{}: {e}", p.display()),
            SwvError::Invalid(p, e) | SwvError::Encode(p, e) => write!(f, "{}: {e}", p.display()),
        }
    }
}

impl std::error::Error for SwvError {}

/// Writes `enc` with its default look as a `.swv` file.
pub fn write_swv(enc: &Encoded, look: &swv::Look, path: &std::path::Path) -> Result<(), SwvError> {
    let err = |e| SwvError::Encode(path.to_path_buf(), e);
    let io_err = |e| SwvError::Write(path.to_path_buf(), e);
    let file = std::fs::File::create(path).map_err(io_err)?;
    let mut w = FileWriter(std::io::BufWriter::new(file));
    let vol = enc.volume().map_err(err)?;
    swv::write(&mut w, &vol, enc.range, enc.threshold, look).map_err(err)?;
    std::io::Write::flush(&mut w.0).map_err(io_err)
}

/// True if `path` starts with the `.swv` signature.
pub fn is_swv(path: &std::path::Path) -> bool {
    let mut magic = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
        .is_ok()
        && magic == swv::MAGIC
}

/// Reads a whole `.swv` file into memory (every slice checked), with its default look.
pub fn read_swv(path: &std::path::Path) -> Result<(Encoded, swv::Look), SwvError> {
    let err = |e| SwvError::Invalid(path.to_path_buf(), e);
    let open_err = |e| SwvError::Open(path.to_path_buf(), e);
    let mut r = FileReader::open(path).map_err(open_err)?;
    let file_len = std::fs::metadata(path).map_err(open_err)?.len();
    let header = swv::read_header(&mut r).map_err(err)?;
    let grid = header.grid;
    let mut runs: [Vec<u8>; 3] = Default::default();
    let mut voxels: [Vec<Voxel>; 3] = Default::default();
    let mut scans: [Vec<ScanIndex>; 3] = Default::default();
    for axis in Axis::ALL {
        let a = axis as usize;
        let [_, nj, nk] = grid.permuted_dims(axis);
        scans[a].push(ScanIndex::default());
        for k in 0..nk {
            let e = swv::read_entry(&mut r, &header, axis, k).map_err(err)?;
            // Bound allocations by what one slice can hold, and by the file's length,
            // before trusting the counts.
            let [ni, _, _] = grid.permuted_dims(axis);
            let record = 8 * (nj as u64 + 1) + e.runs as u64 + 4 * e.voxels as u64;
            if e.runs as usize > nj * (ni + 2)
                || e.voxels as usize > ni * nj
                || e.offset.saturating_add(record) > file_len
            {
                return Err(err(Error::Format {
                    reason: "slice counts exceed what the slice or the file can hold",
                }));
            }
            let mut s = vec![ScanIndex::default(); nj + 1];
            let mut rb = vec![0u8; e.runs as usize];
            let mut vb = vec![Voxel::default(); e.voxels as usize];
            let slice = swv::read_slice(&mut r, &header, axis, &e, 256, &mut s, &mut rb, &mut vb)
                .map_err(err)?;
            let (r0, v0) = (runs[a].len() as u32, voxels[a].len() as u32);
            for sc in &slice.scans[1..] {
                scans[a].push(ScanIndex {
                    run: r0 + sc.run,
                    voxel: v0 + sc.voxel,
                });
            }
            runs[a].extend_from_slice(slice.runs);
            voxels[a].extend_from_slice(slice.voxels);
        }
    }
    let enc = Encoded {
        grid,
        range: header.range,
        threshold: header.threshold,
        runs,
        voxels,
        scans,
        flat: Default::default(),
    };
    enc.volume().map_err(err)?;
    Ok((enc, header.look))
}
