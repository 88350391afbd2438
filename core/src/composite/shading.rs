//! How a slice's voxels become premultiplied colours in a row buffer: lit, depth-cued,
//! shadowed or as MIP's grey, chosen once per slice.

use super::{FlatVoxels, Kernels, Mode, Rgba, SliceTables};
use crate::classify::Voxel;
use crate::fixed::{self, ONE};
use crate::shade::ShadeTable;
use crate::shadow::ShadowLookup;

/// How a slice's voxels are shaded into a row buffer: chosen once per slice from the
/// mode, the shadows and the depth-cue factor, so that an instruction-set build compiles
/// the slice loop for each way apart, without the choice on every run. On Zen 2, with
/// the choice made per run, the x86-64-v3 compositor's code was 39 KB; with the common
/// case alone it was 30 KB, and the MR head's frame (256², one thread) took 4.58 ms
/// instead of 4.92.
pub(crate) trait Shading {
    /// Shades voxels `src` (the first at index `first` of row `j`) into `out`, as many
    /// as `out` holds (`src` may run on past them).
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
    );

    /// [`Self::shade_run`] for volumes made of plateaus, where most voxels repeat the one
    /// before them: ways whose shade depends on the voxel's record alone shade each run
    /// of equal records once ([`shade_repeats`]).
    #[inline(always)]
    fn shade_plateaus(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
    ) {
        self.shade_run(out, src, first, t, j, k)
    }

    /// Where this way's slice loop applies the rule for flat voxels: a constant, so the
    /// loops of ways that never do hold none of it.
    const FLAT: FlatRule = FlatRule::Never;

    /// Whether rows shaded this way under tables `t` keep flat bits and composite by the
    /// rule for flat voxels ([`super::FlatVoxels::Excluded`]): as [`Self::FLAT`] says,
    /// and for [`Way`] as the tables ask.
    #[inline(always)]
    fn excludes_flat(&self, _: &SliceTables<'_>) -> bool {
        Self::FLAT == FlatRule::Always
    }
}

/// Where a way's slice loop applies the rule for flat voxels ([`super::flat`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum FlatRule {
    /// Never: the way blends flat voxels like the others (the ways the x86-64 builds
    /// compile a loop for each, and MIP's).
    Never,
    /// As the slice's tables ask ([`Way`]: one loop for both rules, on targets that
    /// compile one, and in the supersampled compositor). The rows' flat voxels are
    /// marked out of line, so that the loop's common path stays as it was.
    AsAsked,
    /// Always ([`ExcludingFlat`]), with the marking inline.
    Always,
}

/// Way `S` with flat voxels excluded from samples' colours
/// ([`super::FlatVoxels::Excluded`]), as a way of its own: its slice loop
/// ([`super::composite_rows_excluding`]) is compiled apart from the default ones, and
/// inlines the marking of flat voxels and the compositing of the rows that hold them.
#[cfg(target_arch = "x86_64")]
pub(crate) struct ExcludingFlat<S>(pub S);

#[cfg(target_arch = "x86_64")]
impl<S: Shading> Shading for ExcludingFlat<S> {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
    ) {
        self.0.shade_plateaus(out, src, first, t, j, k)
    }

    const FLAT: FlatRule = FlatRule::Always;
}

/// Shades `src` into `out` with `one`, once for each run of equal voxel records: the
/// same record always gives the same colour where the shade depends on nothing else.
/// In the volumes whose flat voxels are excluded (those made of plateaus,
/// [`super::FlatVoxels::for_volume`]) most voxels repeat the one before them.
#[inline(always)]
fn shade_repeats(out: &mut [Rgba], src: &[Voxel], one: impl Fn(&Voxel) -> Rgba) {
    // The record as one word, so that a repeat costs one comparison (compared field by
    // field, the loop took 5 % more of spheres256's frame).
    let word = |v: &Voxel| {
        u32::from_le_bytes([v.opacity, v.scalar, v.normal as u8, (v.normal >> 8) as u8])
    };
    let mut pairs = out.iter_mut().zip(src);
    let Some((o, first)) = pairs.next() else {
        return;
    };
    let (mut last, mut colour) = (word(first), one(first));
    *o = colour;
    for (o, vox) in pairs {
        let w = word(vox);
        if w != last {
            last = w;
            colour = one(vox);
        }
        *o = colour;
    }
}

/// A way whose voxel colour depends on the voxel's record alone (not on its place in
/// the volume), shaded one voxel at a time by [`ByRecord::one`]: its runs can shade each
/// run of equal records once ([`Shading::shade_plateaus`]).
pub(crate) trait ByRecord {
    /// One voxel's premultiplied colour under tables `t`.
    fn one(&self, vox: &Voxel, t: &SliceTables<'_>, k: &impl Kernels) -> Rgba;
}

impl<R: ByRecord> Shading for R {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        _: usize,
        t: &SliceTables<'_>,
        _: i64,
        k: &impl Kernels,
    ) {
        for (o, vox) in out.iter_mut().zip(src) {
            *o = self.one(vox, t, k);
        }
    }

    #[inline(always)]
    fn shade_plateaus(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        _: usize,
        t: &SliceTables<'_>,
        _: i64,
        k: &impl Kernels,
    ) {
        shade_repeats(out, src, |vox| self.one(vox, t, k));
    }
}

/// Composite mode, unshadowed, without depth cueing: the premultiplied shaded colour.
pub(crate) struct Lit;

impl ByRecord for Lit {
    #[inline(always)]
    fn one(&self, vox: &Voxel, t: &SliceTables<'_>, k: &impl Kernels) -> Rgba {
        let alpha = t.opacity.get(vox.opacity);
        let c = &t.color[vox.scalar as usize];
        k.premultiply(c, t.shade.entry_ref(vox.normal), alpha)
    }
}

/// Composite mode, unshadowed, with the slice's depth-cue factor (Q15, below one) on
/// the colour but not on the opacity.
pub(crate) struct Cued(pub u32);

impl ByRecord for Cued {
    #[inline(always)]
    fn one(&self, vox: &Voxel, t: &SliceTables<'_>, k: &impl Kernels) -> Rgba {
        let alpha = t.opacity.get(vox.opacity);
        let c = &t.color[vox.scalar as usize];
        let a = fixed::mul(alpha, self.0);
        let [r, g, b, _] = k.premultiply(c, t.shade.entry_ref(vox.normal), a);
        [r, g, b, alpha as u16]
    }
}

/// Composite mode with shadows: the first light's table `lit` weighted by the shadow
/// buffer's transmittance, the other lights' from the slice tables, and the depth-cue
/// factor `scale` (Q15).
pub(crate) struct Shadowed<'a, 'b> {
    pub shadow: &'a ShadowLookup<'b>,
    pub lit: &'a ShadeTable,
    pub scale: u32,
}

impl Shading for Shadowed<'_, '_> {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        _: &impl Kernels,
    ) {
        for (idx, (o, vox)) in out.iter_mut().zip(src).enumerate() {
            let alpha = t.opacity.get(vox.opacity);
            let [r, g, b, _] = t.color[vox.scalar as usize];
            let base = [r, g, b];
            let rest = t.shade.shade_raw(vox.normal, base);
            let lit = self.lit.shade_raw(vox.normal, base);
            let tr = self.shadow.transmittance(first + idx, j);
            let am = fixed::mul(alpha, self.scale);
            let mut px = [0u16; 4];
            for c in 0..3 {
                let v = (rest[c] + fixed::mul(lit[c].min(2 * ONE), tr)).min(ONE);
                px[c] = fixed::mul(v, am) as u16;
            }
            px[3] = alpha as u16;
            *o = px;
        }
    }
}

/// Maximum intensity projection: the voxel's scalar in every channel.
pub(crate) struct Mip;

impl ByRecord for Mip {
    #[inline(always)]
    fn one(&self, vox: &Voxel, _: &SliceTables<'_>, _: &impl Kernels) -> Rgba {
        [fixed::from_u8(vox.scalar) as u16; 4]
    }
}

/// The way a slice's voxels are shaded, from its mode, its shadows and its depth-cue
/// factor `scale` ([`Way::of`], the one place that chooses). As a [`Shading`] it asks
/// which way on every run: one copy of the slice loop for all of them, as bare-metal
/// targets keep it (for flash), and as the slices that are rarely hot (supersampled
/// ones) use it. The x86-64 builds compile the slice loop for each way instead.
pub(crate) enum Way<'a, 'b> {
    Lit,
    Cued(u32),
    Shadowed(Shadowed<'a, 'b>),
    Mip,
}

impl<'a, 'b> Way<'a, 'b> {
    /// The way for tables `t`, the shadow lookup of the slice if any and its depth-cue
    /// factor (Q15).
    pub(crate) fn of(
        t: &SliceTables<'a>,
        shadow: Option<&'a ShadowLookup<'b>>,
        scale: u32,
    ) -> Self {
        match (t.mode, shadow, t.shade0) {
            (Mode::Composite, Some(shadow), Some(lit)) => {
                Way::Shadowed(Shadowed { shadow, lit, scale })
            }
            (Mode::Composite, _, _) if scale < ONE => Way::Cued(scale),
            (Mode::Composite, _, _) => Way::Lit,
            (Mode::Mip, _, _) => Way::Mip,
        }
    }
}

impl Shading for Way<'_, '_> {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
    ) {
        // Tables that exclude flat voxels are those of volumes made of plateaus. Not on
        // bare-metal targets: the second copy of the shading took 8 KB more flash on the
        // Cortex-M3.
        let plateaus = cfg!(target_arch = "x86_64") && t.flat_voxels == FlatVoxels::Excluded;
        match self {
            Way::Lit if plateaus => Lit.shade_plateaus(out, src, first, t, j, k),
            Way::Lit => Lit.shade_run(out, src, first, t, j, k),
            Way::Cued(scale) if plateaus => Cued(*scale).shade_plateaus(out, src, first, t, j, k),
            Way::Cued(scale) => Cued(*scale).shade_run(out, src, first, t, j, k),
            Way::Shadowed(s) => s.shade_run(out, src, first, t, j, k),
            Way::Mip => Mip.shade_run(out, src, first, t, j, k),
        }
    }

    const FLAT: FlatRule = FlatRule::AsAsked;

    /// As the tables ask, but never in MIP: its grey is not shaded, so flat voxels do
    /// not matter to it.
    #[inline(always)]
    fn excludes_flat(&self, t: &SliceTables<'_>) -> bool {
        t.flat_voxels == FlatVoxels::Excluded && !matches!(self, Way::Mip)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A colour that tells every field of the record apart.
    fn record(v: &Voxel) -> Rgba {
        [
            v.opacity as u16,
            v.scalar as u16,
            v.normal,
            v.normal ^ 0x5a5a,
        ]
    }

    #[test]
    fn runs_of_equal_records_shade_as_each_voxel_would() {
        let mut rng = crate::xorshift(0x9e9e);
        for _ in 0..500 {
            let n = (rng() % 40) as usize;
            let mut src: heapless::Vec<Voxel, 40> = heapless::Vec::new();
            for _ in 0..n {
                // Mostly repeats of the previous record, else one field changed.
                let mut v = src.last().copied().unwrap_or_default();
                match rng() % 6 {
                    0 => v.opacity = rng() as u8,
                    1 => v.scalar = rng() as u8,
                    2 => v.normal ^= 1 << (rng() % 16),
                    _ => {}
                }
                src.push(v).unwrap();
            }
            // The output may be shorter than the voxels: as many as it holds.
            let len = n - (rng() % (n as u64 + 1)) as usize;
            let mut out = [[0xffffu16; 4]; 41];
            shade_repeats(&mut out[..len], &src, record);
            for i in 0..41 {
                let want = if i < len {
                    record(&src[i])
                } else {
                    [0xffff; 4]
                };
                assert_eq!(out[i], want, "voxel {i} of {len}");
            }
        }
    }
}
