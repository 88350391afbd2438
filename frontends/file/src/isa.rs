//! Which instruction-set build of the core's compositing loop to run.
//!
//! The core compiles its band compositor three times on x86-64: for the baseline
//! (SSE2), for x86-64-v3 (AVX2) and for x86-64-v4 (AVX-512). All three run the same
//! integer code, so their images are bit-identical; the wider builds are faster because
//! the per-pixel "over" kernel multiplies 32-bit lanes, which SSE2 cannot do in one
//! vector instruction, and because they prefetch the rows ahead instead of loading
//! them. The core may not call the wider builds itself (it has no way to ask the CPU and
//! forbids `unsafe`), so this module asks at run time and dispatches.

use shearwarp_core::composite::{Intermediate, Rgba, SliceTables};
use shearwarp_core::render::{self, Frame};
use shearwarp_core::source::SliceSource;
use shearwarp_core::Error;

/// An instruction-set level of the compositing loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// The build every CPU of the target runs (SSE2 on x86-64).
    Baseline,
    /// x86-64-v3: AVX2, BMI1/2, FMA, LZCNT, POPCNT.
    X86V3,
    /// x86-64-v4: v3 plus AVX-512 F/BW/VL/DQ/CD.
    X86V4,
}

impl Isa {
    /// Every level, lowest first.
    pub const ALL: [Isa; 3] = [Isa::Baseline, Isa::X86V3, Isa::X86V4];

    /// The highest level this CPU runs.
    pub fn detect() -> Isa {
        Isa::X86V4.effective()
    }

    /// The level that runs when this one is asked for: the highest level at or below it
    /// that this CPU has.
    pub fn effective(self) -> Isa {
        Isa::ALL
            .into_iter()
            .rev()
            .find(|i| *i <= self && i.available())
            .unwrap_or(Isa::Baseline)
    }

    /// Whether this CPU runs the level (the standard library caches the answer, so this
    /// is a load and a test).
    pub fn available(self) -> bool {
        match self {
            Isa::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Isa::X86V3 => v3(),
            #[cfg(target_arch = "x86_64")]
            Isa::X86V4 => v3() && v4(),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The level's name, as `--isa` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::X86V3 => "x86-64-v3",
            Isa::X86V4 => "x86-64-v4",
        }
    }

    /// The level named `s` (see [`Isa::name`]).
    pub fn parse(s: &str) -> Option<Isa> {
        Isa::ALL.into_iter().find(|i| i.name() == s)
    }
}

impl std::str::FromStr for Isa {
    type Err = String;

    fn from_str(s: &str) -> Result<Isa, String> {
        Isa::parse(s).ok_or_else(|| {
            let names: Vec<&str> = Isa::ALL.iter().map(|i| i.name()).collect();
            format!(
                "unknown instruction-set level {s:?} (one of {})",
                names.join(", ")
            )
        })
    }
}

#[cfg(target_arch = "x86_64")]
fn v3() -> bool {
    std::is_x86_feature_detected!("avx2")
        && std::is_x86_feature_detected!("bmi1")
        && std::is_x86_feature_detected!("bmi2")
        && std::is_x86_feature_detected!("fma")
        && std::is_x86_feature_detected!("lzcnt")
        && std::is_x86_feature_detected!("popcnt")
}

#[cfg(target_arch = "x86_64")]
fn v4() -> bool {
    std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx512bw")
        && std::is_x86_feature_detected!("avx512vl")
        && std::is_x86_feature_detected!("avx512dq")
        && std::is_x86_feature_detected!("avx512cd")
}

/// [`render::composite_band_until`] in the build for `isa`, or the highest available
/// level below it when this CPU lacks it (so any `Isa` value is safe to pass).
#[allow(clippy::too_many_arguments)]
pub fn composite_band_until<S: SliceSource>(
    isa: Isa,
    source: &mut S,
    frame: &Frame,
    tables: &SliceTables<'_>,
    img: &mut Intermediate<'_>,
    rows: &mut [Rgba],
    shadow: Option<(&mut [u16], &mut [u16])>,
    keep_going: &mut dyn FnMut() -> bool,
) -> Result<bool, Error> {
    match isa.effective() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `effective` returns only levels whose features this CPU has.
        Isa::X86V4 => unsafe {
            render::composite_band_until_x86_v4(
                source, frame, tables, img, rows, shadow, keep_going,
            )
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Isa::X86V3 => unsafe {
            render::composite_band_until_x86_v3(
                source, frame, tables, img, rows, shadow, keep_going,
            )
        },
        _ => render::composite_band_until(source, frame, tables, img, rows, shadow, keep_going),
    }
}
