//! Errors as values: every failure the core can detect, with enough detail to name it.

use core::fmt;

/// Everything that can go wrong inside the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// A caller-provided buffer is shorter than the configuration requires.
    BufferTooSmall {
        /// Which buffer.
        what: &'static str,
        /// Elements needed.
        needed: usize,
        /// Elements provided.
        got: usize,
    },
    /// Volume dimensions are zero, too large, or inconsistent with the data length.
    BadDimensions {
        /// Why they were rejected.
        reason: &'static str,
    },
    /// A voxel spacing is not a positive finite number.
    BadSpacing,
    /// A transfer function is malformed.
    BadTransferFunction {
        /// Why it was rejected.
        reason: &'static str,
    },
    /// A run-length-encoded stream is inconsistent (run lengths do not add up to the
    /// scanline width, or point past the voxel data).
    MalformedRle {
        /// What is inconsistent.
        reason: &'static str,
    },
    /// View or rendering parameters are invalid (image size, angles, thresholds).
    BadParameter {
        /// Which parameter and why.
        reason: &'static str,
    },
    /// A `.swv` stream is not a valid volume file (see [`crate::swv`]).
    Format {
        /// What is wrong.
        reason: &'static str,
    },
    /// Reading the underlying byte source failed.
    Io(crate::io::IoError),
    /// A volume source failed to deliver a slice (I/O error or corrupt data).
    Source {
        /// What failed.
        reason: &'static str,
    },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::BufferTooSmall { what, needed, got } => {
                write!(
                    f,
                    "buffer `{what}` too small: need {needed} elements, got {got}"
                )
            }
            Error::BadDimensions { reason } => write!(f, "bad volume dimensions: {reason}"),
            Error::BadSpacing => write!(f, "voxel spacing must be positive and finite"),
            Error::BadTransferFunction { reason } => write!(f, "bad transfer function: {reason}"),
            Error::MalformedRle { reason } => write!(f, "malformed run-length data: {reason}"),
            Error::BadParameter { reason } => write!(f, "bad parameter: {reason}"),
            Error::Format { reason } => write!(f, "invalid .swv volume: {reason}"),
            Error::Io(e) => match e {
                crate::io::IoError::UnexpectedEof => write!(f, "input ends early (truncated)"),
                crate::io::IoError::BadSeek => write!(f, "offset points past the end of the input"),
                crate::io::IoError::Device => write!(f, "read error"),
            },
            Error::Source { reason } => write!(f, "volume source failed: {reason}"),
        }
    }
}

impl core::error::Error for Error {}

impl From<crate::io::IoError> for Error {
    fn from(e: crate::io::IoError) -> Self {
        Error::Io(e)
    }
}

/// Returns `BufferTooSmall` unless `got >= needed`.
pub(crate) fn need(what: &'static str, needed: usize, got: usize) -> Result<(), Error> {
    if got < needed {
        Err(Error::BufferTooSmall { what, needed, got })
    } else {
        Ok(())
    }
}

/// The first `needed` entries of `buf`, or the error [`need`] gives.
pub(crate) fn prefix<'a, T>(
    what: &'static str,
    buf: &'a [T],
    needed: usize,
) -> Result<&'a [T], Error> {
    let got = buf.len();
    buf.get(..needed)
        .ok_or(Error::BufferTooSmall { what, needed, got })
}

/// [`prefix`] of a mutable buffer.
pub(crate) fn prefix_mut<'a, T>(
    what: &'static str,
    buf: &'a mut [T],
    needed: usize,
) -> Result<&'a mut [T], Error> {
    let got = buf.len();
    buf.get_mut(..needed)
        .ok_or(Error::BufferTooSmall { what, needed, got })
}
