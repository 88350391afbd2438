//! Helpers shared by the fuzz targets.

// The checksum repair the core's integration tests use, from the same file.
// (`entry_at` there is for the tests only.)
#[allow(dead_code)]
#[path = "../../core/tests/common/swv_crc.rs"]
mod swv_crc;

pub use swv_crc::fix_checksums;
