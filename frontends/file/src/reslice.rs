//! Run-length encoding without a dense classified copy of the volume.
//!
//! The z copy is encoded straight from the classifier, a few slices at a time. The x and
//! y copies are then built from the copies already made: in the cycle of axes
//! z → x → y, each copy's permuted axes `(i, j, k)` become the next one's `(k, i, j)`, so
//! the next copy is a re-slicing of the visible voxels of this one. The dense route
//! (classify everything, then transpose it slab by slab for x and for y) wrote a 4-byte
//! record for every voxel and read all of them three more times; this route touches the
//! transparent ones only while classifying, and a typical volume is mostly transparent.
//! The result is the same, byte for byte (tested against [`rle::encode`]).

use crate::bigbuf;
use crate::scene::AxisArrays;
use shearwarp_core::classify::{self, Grid, Scalars, Voxel};
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::Error;

/// How a voxel is classified: the arguments of [`classify::classify_slices`] besides
/// the slices.
#[derive(Clone, Copy)]
pub struct Classifier<'a> {
    pub grid: &'a Grid,
    pub scalars: Scalars<'a>,
    pub opacity_table: &'a [u8],
    pub gradient_table: Option<&'a [u16; 256]>,
    /// Voxels at or below this opacity are transparent ([`rle::is_visible`]).
    pub threshold: u8,
}

/// Slices classified at a time, which stay in the cache between the classifier writing
/// them and the encoder reading them (nested spheres 256³, one thread: 1, 2, 4 and 8
/// slices took 115–120, 114–116, 115–116 and 119–124 ms).
const SLAB: usize = 2;

/// The z copy, classified and encoded two slices at a time, on up to `threads`
/// threads (each takes its own range of slices; the parts are joined in order).
pub fn encode_z(c: &Classifier<'_>, threads: usize) -> Result<AxisArrays, Error> {
    let nz = c.grid.dims[2];
    let t = threads.clamp(1, nz);
    let part = |n: usize| encode_z_part(c, nz * n / t..nz * (n + 1) / t);
    if t == 1 {
        return part(0);
    }
    let parts: Vec<Result<AxisArrays, Error>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..t).map(|n| scope.spawn(move || part(n))).collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or(Err(Error::Source {
                    reason: "an encoding thread panicked",
                }))
            })
            .collect()
    });
    let mut all = (Vec::new(), Vec::new(), vec![ScanIndex::default()]);
    for p in parts {
        let p = p?;
        append(&mut all, (&p.0, &p.1, &p.2))?;
    }
    Ok(all)
}

/// Slices `zs` of the z copy, as a copy of their own (offsets from their first
/// scanline).
fn encode_z_part(c: &Classifier<'_>, zs: core::ops::Range<usize>) -> Result<AxisArrays, Error> {
    let [nx, ny, _] = c.grid.dims;
    let plane = nx * ny;
    // Per slab: its classified voxels, and the encoder's worst case for them.
    let mut dense = vec![Voxel::default(); SLAB * plane];
    let mut runs = vec![0u8; SLAB * ny * (nx + 2)];
    let mut voxels = vec![Voxel::default(); SLAB * plane];
    let mut scans = vec![ScanIndex::default(); SLAB * ny + 1];
    let mut all = (
        Vec::new(),
        Vec::new(),
        Vec::with_capacity(ny * zs.len() + 1),
    );
    all.2.push(ScanIndex::default());
    for z0 in zs.clone().step_by(SLAB) {
        let z1 = (z0 + SLAB).min(zs.end);
        let d = &mut dense[..(z1 - z0) * plane];
        let (o, g, t) = (c.opacity_table, c.gradient_table, Some(c.threshold));
        classify::classify_slices(c.grid, c.scalars, o, g, t, z0..z1, d)?;
        // The slab as a volume of its own: the encoder reads only its dimensions.
        let slab = Grid::new([nx, ny, z1 - z0], c.grid.spacing)?;
        let (r, v, s) = (&mut runs[..], &mut voxels[..], &mut scans[..]);
        let mut enc = rle::Encoder::new(&slab, Axis::Z, c.threshold, r, v, s)?;
        for slice in d.chunks_exact(plane) {
            enc.push_slice(slice)?;
        }
        append(&mut all, enc.finish()?.parts())?;
    }
    Ok(all)
}

/// Appends the copy `part` (its own offsets, from its first scanline) to `all`.
fn append(all: &mut AxisArrays, part: (&[u8], &[Voxel], &[ScanIndex])) -> Result<(), Error> {
    let (runs, voxels, scans) = all;
    let base = ScanIndex {
        run: count32(runs.len())?,
        voxel: count32(voxels.len())?,
    };
    runs.extend_from_slice(part.0);
    voxels.extend_from_slice(part.1);
    count32(runs.len())?;
    count32(voxels.len())?;
    scans.extend(part.2.iter().skip(1).map(|e| ScanIndex {
        run: base.run + e.run,
        voxel: base.voxel + e.voxel,
    }));
    Ok(())
}

/// The copy along the next axis of the cycle z → x → y → z, built from `src`: voxel
/// `(i, j, k)` of `src` is voxel `(j, k, i)` of the result, which lies on the result's
/// scanline `i·nk + k` at position `j`.
///
/// Three passes over `src`'s visible voxels: count each new scanline's voxels, place
/// every voxel (and its position) at its scanline's next free slot, then write each new
/// scanline's runs from its positions. Walking `src` in storage order, the placing pass
/// writes to `ni` scanlines at a time (one per column of the source slice), each slot
/// right after the last one written there, so its writes mostly stay in the cache. The
/// counters are kept by source slice for the same reason: in the new copy's scanline
/// order a source slice's counters lay a whole new slice apart (nested spheres 256³:
/// 156–169 → 115–119 ms for the encoding).
pub fn next_axis(src: &RleAxis<'_>) -> Result<AxisArrays, Error> {
    let [ni, nj, nk] = src.axis().permuted_dims(src.dims());
    let (_, src_voxels, _) = src.parts();
    let lines = ni * nk;
    // The positions are j < nj ≤ MAX_DIM, which fits 16 bits.
    if nj > u16::MAX as usize + 1 {
        return Err(Error::BadDimensions {
            reason: "volume side too long to re-slice",
        });
    }
    // Pass 1: voxels per new scanline. Counters are kept source slice by source slice
    // (`k·ni + i`), so a source slice's counters lie together.
    let mut count = vec![0u32; lines];
    visit(src, |i, _, k, run| {
        for c in &mut count[k * ni + i..][..run.len()] {
            *c += 1;
        }
    });
    // Each new scanline's first slot, in the new copy's order (`i·nk + k`).
    let mut start = vec![0u32; lines + 1];
    for i in 0..ni {
        for k in 0..nk {
            let s = i * nk + k;
            start[s + 1] = start[s] + count[k * ni + i];
        }
    }
    // Pass 2: every voxel and its position into its scanline's next slot.
    let total = src_voxels.len();
    let mut voxels = bigbuf::filled(total, Voxel::default());
    let mut pos = bigbuf::filled(total, 0u16);
    let mut next = count;
    for i in 0..ni {
        for k in 0..nk {
            next[k * ni + i] = start[i * nk + k];
        }
    }
    visit(src, |i, j, k, run| {
        for (s, v) in next[k * ni + i..][..run.len()].iter_mut().zip(run) {
            let at = *s as usize;
            voxels[at] = *v;
            pos[at] = j as u16;
            *s += 1;
        }
    });
    // Pass 3: runs, scanline by scanline.
    let mut runs = Vec::with_capacity(2 * lines);
    let mut scans = Vec::with_capacity(lines + 1);
    for s in 0..lines {
        scans.push(ScanIndex {
            run: count32(runs.len())?,
            voxel: start[s],
        });
        scanline_runs(
            &pos[start[s] as usize..start[s + 1] as usize],
            nj,
            &mut runs,
        );
    }
    scans.push(ScanIndex {
        run: count32(runs.len())?,
        voxel: start[lines],
    });
    Ok((runs, voxels, scans))
}

/// Calls `f(i, j, k, voxels)` for every visible run of `src`, in storage order: the run
/// `voxels` starts at `(i, j, k)` and runs along `i`.
fn visit(src: &RleAxis<'_>, mut f: impl FnMut(usize, usize, usize, &[Voxel])) {
    let [_, nj, nk] = src.axis().permuted_dims(src.dims());
    for (k, slice) in (0..nk).map_while(|k| src.slice(k)).enumerate() {
        for j in 0..nj {
            slice.for_each_run(j, |i, run| f(i, j, k, run));
        }
    }
}

/// Appends the runs of a scanline `width` voxels long whose visible voxels lie at the
/// ascending positions `pos`, by the format's rule ([`rle::scanline_runs`]).
fn scanline_runs(pos: &[u16], width: usize, runs: &mut Vec<u8>) {
    let mut rest = pos;
    let spans = core::iter::from_fn(|| {
        let first = *rest.first()? as usize;
        // The visible run: positions that follow one another.
        let len = 1 + rest.windows(2).take_while(|w| w[1] == w[0] + 1).count();
        rest = &rest[len..];
        Some((first, len))
    });
    rle::scanline_runs(spans, width, |b| runs.push(b));
}

/// `n` as a run or voxel offset, which the format holds in 32 bits.
fn count32(n: usize) -> Result<u32, Error> {
    u32::try_from(n).map_err(|_| Error::BadDimensions {
        reason: "encoded volume exceeds 2^32 runs or voxels",
    })
}

/// The three axis copies, as [`crate::scene::encode_threads`] returns them (indexed by
/// [`Axis`]).
pub fn encode_all(c: &Classifier<'_>, threads: usize) -> Result<[AxisArrays; 3], Error> {
    let z = encode_z(c, threads)?;
    let dims = c.grid.dims;
    let x = next_axis(&RleAxis::new(dims, Axis::Z, &z.0, &z.1, &z.2)?)?;
    let y = next_axis(&RleAxis::new(dims, Axis::X, &x.0, &x.1, &x.2)?)?;
    Ok([x, y, z])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The copies `rle::encode` makes of the dense classified volume.
    fn dense_route(c: &Classifier<'_>) -> [AxisArrays; 3] {
        let mut dense = vec![Voxel::default(); c.grid.voxel_count()];
        let (o, g, t) = (c.opacity_table, c.gradient_table, Some(c.threshold));
        classify::classify_above(c.grid, c.scalars, o, g, t, &mut dense).unwrap();
        Axis::ALL.map(|axis| {
            let sz = rle::measure(&dense, c.grid, axis, c.threshold).unwrap();
            let mut a = (
                vec![0u8; sz.runs],
                vec![Voxel::default(); sz.voxels],
                vec![ScanIndex::default(); sz.scans],
            );
            rle::encode(
                &dense,
                c.grid,
                axis,
                c.threshold,
                &mut a.0,
                &mut a.1,
                &mut a.2,
            )
            .unwrap();
            a
        })
    }

    /// Values with runs of every length along every axis: long visible and transparent
    /// runs (split at 255), single voxels, and noise.
    fn scalars(dims: [usize; 3]) -> Vec<u8> {
        let [nx, ny, _] = dims;
        (0..dims.iter().product::<usize>())
            .map(|n| {
                let (x, y, z) = (n % nx, n / nx % ny, n / (nx * ny));
                let h = (n as u32).wrapping_mul(2_654_435_761) >> 24;
                match (x, z % 5) {
                    // Whole lines along y and z, whole slices across x and y.
                    (0, _) | (_, 0) => 200,
                    (1, _) | (_, 1) => 0,
                    _ => match (x / 7 + y / 3 + z) % 4 {
                        0 => 200,
                        1 => 0,
                        2 => h as u8,
                        _ => ((x * y + z) % 3 * 90) as u8,
                    },
                }
            })
            .collect()
    }

    #[test]
    fn copies_equal_the_dense_route() {
        let mut ramp = [0u8; 256];
        for (v, a) in ramp.iter_mut().enumerate() {
            *a = (v as u8).saturating_sub(40);
        }
        let mut grad = [0u16; 256];
        for (m, f) in grad.iter_mut().enumerate() {
            *f = (m as u16 * 600).min(1 << 15);
        }
        // Sides past 255 (split runs), sides of one, and ones that are not multiples of
        // the slab.
        for dims in [
            [300, 7, 9],
            [5, 280, 3],
            [9, 4, 270],
            [1, 1, 1],
            [1, 6, 2],
            [17, 1, 5],
        ] {
            let data = scalars(dims);
            let grid = Grid::new(dims, [1.0, 2.0, 0.5]).unwrap();
            for (gradient_table, threshold) in [(None, 0), (None, 30), (Some(&grad), 12)] {
                let c = Classifier {
                    grid: &grid,
                    scalars: Scalars::U8(&data),
                    opacity_table: &ramp,
                    gradient_table,
                    threshold,
                };
                let want = dense_route(&c);
                for threads in [1, 2, 3] {
                    let got = encode_all(&c, threads).unwrap();
                    for a in 0..3 {
                        assert!(got[a] == want[a], "{dims:?} axis {a} threads {threads}");
                    }
                }
                // The cycle closes: the z copy re-sliced from the y copy.
                let y = &want[Axis::Y as usize];
                let from_y = next_axis(&RleAxis::new(dims, Axis::Y, &y.0, &y.1, &y.2).unwrap());
                assert!(from_y.unwrap() == want[Axis::Z as usize], "{dims:?} y to z");
            }
        }
    }

    #[test]
    fn scanline_runs_split_and_close_as_the_encoder_does() {
        let runs = |pos: &[u16], width| {
            let mut r = Vec::new();
            scanline_runs(pos, width, &mut r);
            r
        };
        assert_eq!(runs(&[], 0), [0, 0]);
        assert_eq!(runs(&[], 300), [255, 0, 45, 0]);
        assert_eq!(runs(&[0, 1, 2], 3), [0, 3]);
        assert_eq!(runs(&[1, 3], 5), [1, 1, 1, 1, 1, 0]);
        let all: Vec<u16> = (0..300).collect();
        assert_eq!(runs(&all, 300), [0, 255, 0, 45]);
    }
}
