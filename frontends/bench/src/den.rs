//! VolPack's `.den` files; the reader lives in the file frontend
//! ([`shearwarp_file::formats::den`]).

pub use shearwarp_file::formats::den::read;
