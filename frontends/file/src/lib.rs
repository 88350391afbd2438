pub mod tfspec;
pub mod volume;
