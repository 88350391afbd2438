//! The steps of the scanline loop an instruction-set build may replace: warming the
//! cache, shading a voxel, compositing a run of pixels and finding the pixels that
//! closed. The portable versions are the reference every vector version is tested
//! against bit for bit.

#[cfg(target_arch = "x86_64")]
use super::Way;
use super::{Rgba, SliceJob};
use crate::classify::Voxel;
use crate::error::Error;
use crate::fixed::{self, ONE};
use crate::normal::ZERO_GRADIENT;
use crate::shade::ShadeEntry;

/// The steps an instruction-set build of the compositor may replace (see
/// [`crate::render::composite_band_until_x86_v3`]): warming the cache for a row, shading
/// a voxel, compositing a run of pixels. Everything else is shared.
pub(crate) trait Kernels {
    /// Warms the cache for a voxel row the compositor reads two rows later.
    fn warm(&self, voxels: &[Voxel]);
    /// Shades colour `c` with `e` and premultiplies it by `alpha` (Q15):
    /// [`premultiply`] or a bit-identical vector version.
    fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba;
    /// Resamples and composites a run of open pixels: [`over_run`] or a bit-identical
    /// vector version. Returns at least the highest opacity of the run's pixels
    /// afterwards: pixels below the early-ray-termination threshold are not looked at
    /// for the opaque mark when it is below it.
    fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16;
    /// Bit `i` set where pixel `px[i]` (at most 64 pixels) reached opacity `thr`
    /// (`thr >= 1`): [`closed_bits`] or a bit-identical vector version.
    fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64;
    /// Bit `i` set for each flat voxel `voxels[i]` of the first `n <= 64`
    /// ([`super::flat`]; the voxels after them may be read, and count for nothing):
    /// [`flat_bits`] or a bit-identical vector version.
    fn flat_bits(&self, voxels: &[Voxel], n: usize) -> u64;
    /// The sums the rule for flat voxels takes of a sample's taps `t`, weights `w` and
    /// flat bits `flat`: [`super::flat::sums`] or a bit-identical vector version.
    fn flat_sums(&self, t: &[Rgba; 4], w: [u32; 4], flat: u32) -> ([u32; 4], u32);
    /// Composites a slice of a perspective view ([`crate::perspective::composite_slice`])
    /// with these kernels, in a function of its own compiled for the build's
    /// instruction set: inlined into the band compositor instead, it made frames slower.
    fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error>;
    /// Composites a slice with flat voxels excluded from samples' colours, shaded
    /// `way` ([`super::composite_rows_excluding`]), with these kernels, in a function
    /// of its own compiled for the build's instruction set: a slice loop of its own, so
    /// that the default one's code stays as it was, which inlines the flat voxels'
    /// marking and compositing. Inlined into the band compositor beside the default
    /// loops, it made those take more instructions (spheres256, callgrind: 1.6 % a
    /// frame).
    #[cfg(target_arch = "x86_64")]
    fn composite_flat(&self, job: SliceJob<'_, '_>, way: Way<'_, '_>) -> Result<(), Error>;
}

/// The portable kernels: [`touch`], [`premultiply`], [`closed_bits`] and [`over_run`],
/// which does not keep the run's highest opacity: as a reduction in its loop it stopped
/// the compiler from vectorising the loop for baseline x86-64 (spheres256: 34 → 43 ms a
/// frame), and on the Cortex-M3 it cost as much as it saved. So every run is looked at.
pub(crate) struct Portable;

impl Kernels for Portable {
    #[inline(always)]
    fn warm(&self, voxels: &[Voxel]) {
        touch(voxels)
    }
    #[inline(always)]
    fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
        premultiply(c, e, alpha)
    }
    #[inline(always)]
    fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
        over_run_unranked(px, top, bot, w)
    }
    #[inline(always)]
    fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64 {
        closed_bits(px, thr)
    }
    #[inline(always)]
    fn flat_bits(&self, voxels: &[Voxel], n: usize) -> u64 {
        flat_bits(voxels, n)
    }
    #[inline(always)]
    fn flat_sums(&self, t: &[Rgba; 4], w: [u32; 4], flat: u32) -> ([u32; 4], u32) {
        super::flat::sums(t, w, flat)
    }
    #[inline(always)]
    fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error> {
        crate::perspective::composite_slice(job, self)
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn composite_flat(&self, job: SliceJob<'_, '_>, way: Way<'_, '_>) -> Result<(), Error> {
        super::composite_flat_portable(job, way)
    }
}

/// Kernels given as closures: an instruction-set build writes them inside its
/// `target_feature` function, so they are compiled with its features (and may call the
/// vector intrinsics those features make safe). Only the x86-64 builds have such
/// functions.
#[cfg(target_arch = "x86_64")]
pub(crate) struct With<W, P, O, C, B, U, S, F>(
    pub W,
    pub P,
    pub O,
    pub C,
    pub B,
    pub U,
    pub S,
    pub F,
);

#[cfg(target_arch = "x86_64")]
impl<W, P, O, C, B, U, S, F> Kernels for With<W, P, O, C, B, U, S, F>
where
    W: Fn(&[Voxel]),
    P: Fn(&[u16; 4], &ShadeEntry, u32) -> Rgba,
    O: Fn(&mut [Rgba], &[Rgba], &[Rgba], [u32; 4]) -> u16,
    C: Fn(&[Rgba], u32) -> u64,
    B: Fn(&[Voxel], usize) -> u64,
    U: Fn(&[Rgba; 4], [u32; 4], u32) -> ([u32; 4], u32),
    S: Fn(SliceJob<'_, '_>) -> Result<(), Error>,
    F: Fn(SliceJob<'_, '_>, Way<'_, '_>) -> Result<(), Error>,
{
    #[inline(always)]
    fn warm(&self, voxels: &[Voxel]) {
        (self.0)(voxels)
    }
    #[inline(always)]
    fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
        (self.1)(c, e, alpha)
    }
    #[inline(always)]
    fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
        (self.2)(px, top, bot, w)
    }
    #[inline(always)]
    fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64 {
        (self.3)(px, thr)
    }
    #[inline(always)]
    fn flat_bits(&self, voxels: &[Voxel], n: usize) -> u64 {
        (self.4)(voxels, n)
    }
    #[inline(always)]
    fn flat_sums(&self, t: &[Rgba; 4], w: [u32; 4], flat: u32) -> ([u32; 4], u32) {
        (self.5)(t, w, flat)
    }
    #[inline(always)]
    fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error> {
        (self.6)(job)
    }
    #[inline(always)]
    fn composite_flat(&self, job: SliceJob<'_, '_>, way: Way<'_, '_>) -> Result<(), Error> {
        (self.7)(job, way)
    }
}

/// A voxel's premultiplied colour, Q15: `min(1, c·D + S)·α` for red, green and blue from
/// its colour and shading entry, and `α` after them. The fourth lanes of `c` and `e`
/// are padding ([`crate::classify::ColorLanes`], [`ShadeEntry`]) and are not used.
#[inline(always)]
pub(crate) fn premultiply(c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
    let mut out = [0, 0, 0, alpha as u16];
    for ch in 0..3 {
        let x = fixed::mul(c[ch] as u32, e.diffuse[ch] as u32) + e.specular[ch] as u32;
        out[ch] = fixed::mul(x.min(ONE), alpha) as u16;
    }
    out
}

/// [`premultiply`] in SSE4.1 vectors: the voxel's four lanes in one 128-bit register,
/// the padding lane computed along and then replaced by `α` (the compiler kept the
/// channels in scalar registers: 44 instructions a voxel in the x86-64-v4 build against
/// 27 here). A macro expanding to a closure, because the intrinsics are safe to call
/// only where SSE4.1 is enabled: it is written inside the x86-64-v3 and v4 compositors.
#[cfg(target_arch = "x86_64")]
macro_rules! premultiply_sse41 {
    () => {
        |c: &[u16; 4], e: &$crate::shade::ShadeEntry, alpha: u32| -> $crate::composite::Rgba {
            use core::arch::x86_64::*;
            let lanes = |x: &[u16; 4]| _mm_cvtepu16_epi32(_mm_cvtsi64_si128(bytemuck::cast(*x)));
            let half = _mm_set1_epi32(1 << 14);
            let d = _mm_mullo_epi32(lanes(c), lanes(&e.diffuse));
            let x = _mm_add_epi32(
                _mm_srli_epi32::<15>(_mm_add_epi32(d, half)),
                lanes(&e.specular),
            );
            let a = _mm_set1_epi32(alpha as i32);
            let x = _mm_min_epu32(x, _mm_set1_epi32($crate::fixed::ONE as i32));
            let x = _mm_mullo_epi32(x, a);
            let x = _mm_srli_epi32::<15>(_mm_add_epi32(x, half));
            // The padding lane becomes α, from the vector it was broadcast into.
            let x = _mm_blend_epi16::<0xC0>(x, a);
            let p = _mm_packus_epi32(x, x);
            bytemuck::cast(_mm_cvtsi128_si64(p))
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(crate) use premultiply_sse41;

/// [`over_run`] by `N` pixels at a time with `step`, which composites `N` pixels
/// (given by value) from `N + 1` entries of each row and returns them with their lanes
/// as a vector; runs shorter than `N` go to `short`. The run's highest opacity is kept
/// lane by lane in a vector (`most`, one maximum a step) and read out once at the end
/// (`opacity_of`): per step, pulling the two opacities out of the vector and comparing
/// them in scalar registers cost 7 of the AVX2 step's 35 instructions. The step at the
/// end overlaps the one before it rather than running past the run: it is computed
/// first, from the pixels as they were, and stored last, so the pixels both cover get
/// the same value twice.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn by_steps<const N: usize, M: Copy>(
    px: &mut [Rgba],
    top: &[Rgba],
    bot: &[Rgba],
    step: impl Fn([Rgba; N], &[Rgba], &[Rgba]) -> ([Rgba; N], M),
    most: impl Fn(M, M) -> M,
    opacity_of: impl FnOnce(M) -> u16,
    short: impl FnOnce(&mut [Rgba], &[Rgba], &[Rgba]) -> u16,
) -> u16 {
    let n = px.len();
    let Some(end) = n.checked_sub(N) else {
        return short(px, top, bot);
    };
    let (top, bot) = (&top[..n + 1], &bot[..n + 1]);
    let at = |px: &[Rgba], u: usize| -> [Rgba; N] { core::array::from_fn(|k| px[u + k]) };
    let (last, mut hi) = step(at(px, end), &top[end..], &bot[end..]);
    let mut u = 0;
    while u < end {
        let (out, m) = step(at(px, u), &top[u..], &bot[u..]);
        hi = most(hi, m);
        px[u..u + N].copy_from_slice(&out);
        u += N;
    }
    px[end..].copy_from_slice(&last);
    opacity_of(hi)
}

/// [`over_run`] in AVX2 or AVX-512 vectors, 2 or 4 pixels a step ([`by_steps`]): each
/// pixel's four channels are four 32-bit lanes of one 128-bit part of a register, so the
/// bilinear taps are plain loads of neighbouring buffer entries and the pixel's own
/// opacity is a shuffle. The compiler's version keeps one channel of eight pixels a
/// register and spends most of its instructions regrouping channels (callgrind,
/// spheres256, x86-64-v3: about 39 instructions a pixel). AVX-512 hands runs shorter
/// than four pixels to the AVX2 version, which hands single pixels to [`over_run`].
///
/// Bit-identical to [`over_run`] for any `u16` taps: every intermediate fits its 32-bit
/// lane (a tap sum is at most `ONE·65535`, a product with `1 − α` at most
/// `65535·ONE`), and the results, at most [`ONE`], narrow to `u16` unchanged. A macro
/// expanding to a closure, written inside the x86-64-v3 and v4 compositors (see
/// [`premultiply_sse41`]).
#[cfg(target_arch = "x86_64")]
macro_rules! over_run_simd {
    (avx2) => {
        |px: &mut [$crate::composite::Rgba],
         top: &[$crate::composite::Rgba],
         bot: &[$crate::composite::Rgba],
         w: [u32; 4]| {
            use core::arch::x86_64::*;
            type Rgba = $crate::composite::Rgba;
            let step = $crate::composite::over_run_simd!(
                step 2, w,
                _mm256_set1_epi32, _mm256_add_epi32, _mm256_sub_epi32, _mm256_mullo_epi32,
                _mm256_srli_epi32, _mm256_min_epu32, _mm256_shuffle_epi32,
                |q: [Rgba; 2]| _mm256_cvtepu16_epi32(bytemuck::cast(q)),
                |r| -> [Rgba; 2] {
                    // Pack each 128-bit half to u16 and bring the two pixels together.
                    let packed = _mm256_permute4x64_epi64::<0b1000>(_mm256_packus_epi32(r, r));
                    bytemuck::cast(_mm256_castsi256_si128(packed))
                }
            );
            // The opacities are lanes 3 and 7, each at most `ONE`.
            let opacity = |m: __m256i| {
                (_mm256_extract_epi32::<3>(m) as u32).max(_mm256_extract_epi32::<7>(m) as u32)
                    as u16
            };
            $crate::composite::by_steps::<2, __m256i>(
                px,
                top,
                bot,
                step,
                |a, b| _mm256_max_epu32(a, b),
                opacity,
                |p, t, b| {
                    $crate::composite::over_run(p, t, b, w);
                    $crate::composite::highest(p)
                },
            )
        }
    };
    (avx512) => {
        |px: &mut [$crate::composite::Rgba],
         top: &[$crate::composite::Rgba],
         bot: &[$crate::composite::Rgba],
         w: [u32; 4]| {
            use core::arch::x86_64::*;
            type Rgba = $crate::composite::Rgba;
            let step = $crate::composite::over_run_simd!(
                step 4, w,
                _mm512_set1_epi32, _mm512_add_epi32, _mm512_sub_epi32, _mm512_mullo_epi32,
                _mm512_srli_epi32, _mm512_min_epu32, _mm512_shuffle_epi32,
                |q: [Rgba; 4]| _mm512_cvtepu16_epi32(bytemuck::cast(q)),
                |r| -> [Rgba; 4] { bytemuck::cast(_mm512_cvtepi32_epi16(r)) }
            );
            let short = $crate::composite::over_run_simd!(avx2);
            // The opacities are lanes 3, 7, 11 and 15.
            $crate::composite::by_steps::<4, __m512i>(
                px,
                top,
                bot,
                step,
                |a, b| _mm512_max_epu32(a, b),
                |m| _mm512_mask_reduce_max_epu32(0x8888, m) as u16,
                |p, t, b| short(p, t, b, w),
            )
        }
    };
    // One step of N pixels.
    (step $n:literal, $w:expr, $set1:ident, $add:ident, $sub:ident, $mul:ident, $srli:ident,
     $min:ident, $shuffle:ident, $wide:expr, $narrow:expr) => {{
        const N: usize = $n;
        let one = $set1($crate::fixed::ONE as i32);
        let half = $set1(1 << 14);
        let wv = $w.map(|x: u32| $set1(x as u16 as i32));
        let wide = $wide;
        let narrow = $narrow;
        move |p: [Rgba; N], t: &[Rgba], b: &[Rgba]| {
            let (t, b) = (&t[..N + 1], &b[..N + 1]);
            let at = |r: &[Rgba], o: usize| {
                let q: [Rgba; N] = bytemuck::pod_read_unaligned(bytemuck::cast_slice(&r[o..o + N]));
                wide(q)
            };
            let sum = $add(
                $add($mul(wv[0], at(t, 0)), $mul(wv[1], at(t, 1))),
                $add($mul(wv[2], at(b, 0)), $mul(wv[3], at(b, 1))),
            );
            let s = $srli::<15>($add(sum, half));
            let cur = wide(p);
            // 1 − α of each pixel in all four of its lanes.
            let tr = $sub(one, $shuffle::<0xff>(cur));
            let over = $srli::<15>($add($mul(s, tr), half));
            let r = $min($add(cur, over), one);
            (narrow(r), r)
        }
    }};
}
#[cfg(target_arch = "x86_64")]
pub(crate) use over_run_simd;

/// Reads one byte per 64-byte line of `voxels`, a row the compositor reaches two rows
/// later: the compositor's default way to warm the cache (see
/// [`super::composite_slice_in`]'s `warm`). Lazy shading reads a few scattered voxels
/// per row, which the hardware does not prefetch; walking the row ahead streams the
/// slice into the cache instead (about 10 % of a frame on the MR head, which otherwise
/// waits on those reads). The loads make the core wait for memory when the row is not
/// cached, which a prefetch instruction does not (every x86-64 build uses one, see
/// [`crate::render::composite_band_until_x86_64`]). Bare-metal targets have no data
/// cache to fill, so there it does nothing.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
pub(crate) fn touch(voxels: &[Voxel]) {
    if cfg!(target_os = "none") {
        return;
    }
    let mut acc = 0u8;
    for v in voxels.iter().step_by(16) {
        acc ^= v.opacity;
    }
    core::hint::black_box(acc);
}

/// Bit `i` set where `px[i]` (at most 64 pixels) reached opacity `thr`.
#[inline(always)]
pub(crate) fn closed_bits(px: &[Rgba], thr: u32) -> u64 {
    let mut m = 0u64;
    for (i, p) in px.iter().take(64).enumerate() {
        m |= ((p[3] as u32 >= thr) as u64) << i;
    }
    m
}

/// [`closed_bits`] four pixels a step in AVX2: a pixel is one 64-bit lane, its opacity
/// the lane's top 16 bits, so a shift, a 64-bit compare and a sign-bit mask give four
/// bits. The compiler's version of the plain loop sets up vector code that short runs
/// hardly enter: on the MR head, 19 K runs a frame of 7.6 pixels on average are looked
/// at, and this kernel takes 1.5 % off the frame's instructions (callgrind). Runs
/// shorter than four pixels go pixel by pixel; the last step of a longer run overlaps
/// the one before it. A macro expanding to a closure, written inside the x86-64-v3 and
/// v4 compositors (see [`premultiply_sse41`]).
#[cfg(target_arch = "x86_64")]
macro_rules! closed_bits_avx2 {
    () => {
        |px: &[$crate::composite::Rgba], thr: u32| -> u64 {
            use core::arch::x86_64::*;
            type Rgba = $crate::composite::Rgba;
            let px = &px[..px.len().min(64)];
            let n = px.len();
            if n < 4 {
                return $crate::composite::closed_bits(px, thr);
            }
            // Opacity above thr − 1, as signed 64-bit lanes (both are below 2^16).
            let below = _mm256_set1_epi64x(thr as i64 - 1);
            let four = |q: &[Rgba]| -> u64 {
                let q: [Rgba; 4] = core::array::from_fn(|k| q[k]);
                let alpha = _mm256_srli_epi64::<48>(bytemuck::cast(q));
                let ge = _mm256_cmpgt_epi64(alpha, below);
                _mm256_movemask_pd(_mm256_castsi256_pd(ge)) as u64
            };
            let mut m = four(&px[n - 4..]) << (n - 4);
            let mut i = 0;
            while i + 4 < n {
                m |= four(&px[i..i + 4]) << i;
                i += 4;
            }
            m
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(crate) use closed_bits_avx2;

/// Bit `i` set for each flat voxel `voxels[i]` of the first `n` (at most 64; a zero
/// gradient, [`crate::normal::ZERO_GRADIENT`]), voxel by voxel: last voxel first, each
/// shifting the ones before it up (a shift by one a voxel rather than one by the
/// voxel's index).
#[inline(always)]
pub(crate) fn flat_bits(voxels: &[Voxel], n: usize) -> u64 {
    voxels
        .iter()
        .take(n.min(64))
        .rev()
        .fold(0u64, |m, v| m << 1 | (v.normal == ZERO_GRADIENT) as u64)
}

/// [`flat_bits`] in AVX2, 32 voxels at a time: a byte a voxel, all ones for a flat one,
/// in a loop the compiler vectorises, then the bytes' mask. A block reads on past the
/// `n` voxels when the slice's voxels do (a shaded run is mostly followed by the next
/// runs' voxels), and the bits past `n` are dropped; only a block at the end of the
/// slice's voxels goes voxel by voxel. A loop over the bytes of any count left its last
/// voxels to a scalar loop, and the vector load of bytes just stored one at a time
/// waited for them (the x86-64-v4 build: 5 % of spheres256's frame on that load's
/// test). A macro expanding to a closure, written inside the x86-64-v3 and v4
/// compositors (see [`premultiply_sse41`]).
#[cfg(target_arch = "x86_64")]
macro_rules! flat_bits_avx2 {
    () => {
        |voxels: &[$crate::classify::Voxel], n: usize| -> u64 {
            use core::arch::x86_64::*;
            let n = n.min(64).min(voxels.len());
            let mut m = 0u64;
            let mut from = 0;
            while from < n {
                let Some(block) = voxels.get(from..from + 32) else {
                    let rest = voxels.get(from..).unwrap_or_default();
                    m |= $crate::composite::flat_bits(rest, n - from) << from;
                    break;
                };
                let mut flags = [0u8; 32];
                for (f, v) in flags.iter_mut().zip(block) {
                    *f = 0u8.wrapping_sub((v.normal == $crate::normal::ZERO_GRADIENT) as u8);
                }
                m |= (_mm256_movemask_epi8(bytemuck::cast(flags)) as u32 as u64) << from;
                from += 32;
            }
            match n {
                64.. => m,
                _ => m & ((1u64 << n) - 1),
            }
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(crate) use flat_bits_avx2;

/// [`super::flat::sums`] in AVX2 vectors: the four taps' channels as 32-bit lanes of
/// two registers (the top taps, the bottom ones), multiplied by their weights, the flat
/// taps' lanes masked off from the non-flat sums, and the two taps of each register
/// added across its halves. The portable version packs two channels to a 64-bit word
/// and takes 8 scalar multiplies and about 40 instructions a sample; here a few vector
/// steps do it. Bit-identical: every product and sum is below `2^31` (see
/// [`super::flat::sums`]), so no 32-bit lane wraps. A macro expanding to a closure,
/// written inside the x86-64-v3 and v4 compositors (see [`premultiply_sse41`]).
#[cfg(target_arch = "x86_64")]
macro_rules! flat_sums_avx2 {
    () => {
        |t: &[$crate::composite::Rgba; 4], w: [u32; 4], flat: u32| -> ([u32; 4], u32) {
            use core::arch::x86_64::*;
            let taps = |a: $crate::composite::Rgba, b: $crate::composite::Rgba| {
                _mm256_cvtepu16_epi32(bytemuck::cast::<_, __m128i>([a, b]))
            };
            let weights = |a: u32, b: u32| {
                let (a, b) = (a as i32, b as i32);
                _mm256_setr_epi32(a, a, a, a, b, b, b, b)
            };
            let top = _mm256_mullo_epi32(taps(t[0], t[1]), weights(w[0], w[1]));
            let bot = _mm256_mullo_epi32(taps(t[2], t[3]), weights(w[2], w[3]));
            // All ones in the lanes of the taps that are not flat.
            let bits = _mm256_set1_epi32(flat as i32);
            let not_flat = |a: i32, b: i32| {
                let tap = _mm256_setr_epi32(a, a, a, a, b, b, b, b);
                _mm256_cmpeq_epi32(_mm256_and_si256(bits, tap), _mm256_setzero_si256())
            };
            let kept = _mm256_add_epi32(
                _mm256_and_si256(top, not_flat(1, 2)),
                _mm256_and_si256(bot, not_flat(4, 8)),
            );
            let all = _mm256_add_epi32(top, bot);
            let halves = |x: __m256i| {
                _mm_add_epi32(_mm256_castsi256_si128(x), _mm256_extracti128_si256::<1>(x))
            };
            let kept: [u32; 4] = bytemuck::cast(halves(kept));
            let all: [u32; 4] = bytemuck::cast(halves(all));
            (kept, all[3])
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(crate) use flat_sums_avx2;

/// Resamples `top`/`bot` (one entry longer than `px`) with weights `w` and composites
/// the result under `px`. A zero sample leaves a pixel unchanged (`p + 0·(1 − α) = p`),
/// so no pixel needs a test and the loop has no branches.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
pub(crate) fn over_run(px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) {
    const H: u32 = 1 << 14;
    let w = w.map(|x| x as u16 as u32);
    for ((p, t), b) in px.iter_mut().zip(top.windows(2)).zip(bot.windows(2)) {
        let mut s = [0u32; 4];
        for c in 0..4 {
            let sum = w[0] * t[0][c] as u32
                + w[1] * t[1][c] as u32
                + w[2] * b[0][c] as u32
                + w[3] * b[1][c] as u32;
            // At most ONE: the weights sum to ONE and the channels are at most ONE.
            s[c] = ((sum + H) >> 15) as u16 as u32;
        }
        let tr = (ONE - p[3] as u32) as u16 as u32;
        for c in 0..4 {
            p[c] = (p[c] as u32 + ((s[c] * tr + H) >> 15)).min(ONE) as u16;
        }
    }
}

/// [`over_run`] as [`Kernels::over_run`] of the portable kernels: returns `u16::MAX`, so
/// every run is looked at for the opaque mark (see [`Portable`]).
#[inline(always)]
pub(crate) fn over_run_unranked(px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
    over_run(px, top, bot, w);
    u16::MAX
}

/// The highest opacity of `px`.
#[cfg(any(test, target_arch = "x86_64"))]
#[inline(always)]
pub(crate) fn highest(px: &[Rgba]) -> u16 {
    px.iter().fold(0, |h, p| h.max(p[3]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::composite::rng;
    use crate::normal;
    use crate::shade::ShadeTable;

    #[test]
    fn premultiply_gives_the_shaded_colour_and_the_opacity_after_it() {
        // With real tables (a lit table, colours and opacities within one) and anything
        // in the padding lane, the step must give what shading three channels and
        // appending the opacity gives.
        let mut shade = ShadeTable::UNSHADED;
        let mut lights = heapless::Vec::new();
        let _ = lights.push(crate::shade::Light {
            direction: [0.3, -0.5, 1.0],
            color: [1.0, 0.8, 0.6],
        });
        let l = crate::shade::Lighting {
            ka: 0.2,
            kd: 1.4,
            ks: 0.5,
            shininess: 12.0,
            lights,
        };
        let rot = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(shade.fill(&l, &rot).is_ok());
        let mut next = rng(0x51f1_5ee5_d00d_f00d);
        for _ in 0..20_000 {
            let c = [next(ONE), next(ONE), next(ONE)].map(|x| x as u16);
            let code = next(normal::CODES as u32 + 40) as u16;
            let alpha = next(ONE);
            let lanes = [c[0], c[1], c[2], next(u16::MAX as u32) as u16];
            let got = premultiply(&lanes, shade.entry_ref(code), alpha);
            let s = shade.shade(code, c);
            let want = [0, 1, 2].map(|i| fixed::mul(s[i], alpha) as u16);
            assert_eq!(
                got,
                [want[0], want[1], want[2], alpha as u16],
                "{c:?} {code} {alpha}"
            );
        }
    }
}
