pub mod cases;
pub mod metrics;
pub mod reference;
pub mod synth;
