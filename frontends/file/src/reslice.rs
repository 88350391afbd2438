//! Run-length encoding without a dense classified copy of the volume.
//!
//! The z copy is encoded straight from the classifier, a few slices at a time. The x copy
//! is then re-sliced from the visible voxels of the z copy, whose scanlines or rows run
//! along x, and the y copy likewise from the x copy ([`reslice`]), each in whichever
//! layout the grid has ([`shearwarp_core::rle::Layout`]). The dense route
//! (classify everything, then transpose it slab by slab for x and for y) wrote a 4-byte
//! record for every voxel and read all of them three more times; this route touches the
//! transparent ones only while classifying, and a typical volume is mostly transparent.
//! The result is the same, byte for byte (tested against [`rle::encode`]).

use crate::bigbuf;
use crate::scene::{transpose, AxisArrays, Cut, Strided};
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
    /// What is cut away of the voxels as they are classified.
    pub cut: Cut,
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
    let mut runs = vec![0u8; SLAB * (nx * ny + 2 * nx.max(ny))];
    let mut voxels = vec![Voxel::default(); SLAB * plane];
    let mut scans = vec![ScanIndex::default(); SLAB * nx.max(ny) + 1];
    // The z copy's scanlines run along y when the layout says so.
    let across = c.grid.permutation(Axis::Z)[0] == 1;
    let mut flipped = vec![Voxel::default(); if across { plane } else { 0 }];
    let mut all = (
        Vec::new(),
        Vec::new(),
        Vec::with_capacity(nx.max(ny) * zs.len() + 1),
    );
    all.2.push(ScanIndex::default());
    for z0 in zs.clone().step_by(SLAB) {
        let z1 = (z0 + SLAB).min(zs.end);
        let d = &mut dense[..(z1 - z0) * plane];
        let (o, g, t) = (c.opacity_table, c.gradient_table, Some(c.threshold));
        classify::classify_slices(c.grid, c.scalars, o, g, t, z0..z1, d)?;
        c.cut.apply(c.grid, z0..z1, d)?;
        // The slab as a volume of its own: the encoder reads only its dimensions and
        // layout.
        let slab = Grid::new([nx, ny, z1 - z0], c.grid.spacing)?.with_layout(c.grid.layout());
        let (r, v, s) = (&mut runs[..], &mut voxels[..], &mut scans[..]);
        let mut enc = rle::Encoder::new(&slab, Axis::Z, c.threshold, r, v, s)?;
        for slice in d.chunks_exact(plane) {
            if across {
                // Scanlines along y: the slice transposed, y fastest.
                let (src, dst) = (
                    Strided {
                        offset: 0,
                        stride: nx,
                    },
                    Strided {
                        offset: 0,
                        stride: ny,
                    },
                );
                transpose(slice, src, &mut flipped, dst, [ny, nx]);
                enc.push_slice(&flipped)?;
            } else {
                enc.push_slice(slice)?;
            }
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

/// `axis`'s copy of the volume, laid out as `grid` says, built from another copy `src`
/// whose scanlines or rows run along `axis` (any copy for another principal axis does).
/// A voxel at `(i, j, k)` of `src` lies, in the result, on the scanline and at the
/// position that are linear in `(i, j, k)`: each of the result's `(i, j, k)` is one of
/// `src`'s.
///
/// Three passes over `src`'s visible voxels: count each new scanline's voxels, place
/// every voxel (and its position) at its scanline's next free slot, then write each new
/// scanline's runs from its positions. `src` is walked in storage order (`k`, then `j`,
/// then `i`), so with any two of its coordinates fixed the third only grows: each new
/// scanline receives its voxels in the order of their positions.
pub fn reslice(src: &RleAxis<'_>, grid: &Grid, axis: Axis) -> Result<AxisArrays, Error> {
    let (ps, pt) = (src.permutation(), grid.permutation(axis));
    let [ni, nj, nk] = grid.permuted_dims(axis);
    if src.dims() != grid.dims || ps[2] == pt[2] {
        return Err(Error::BadParameter {
            reason: "a copy is re-sliced from another axis's copy of the same volume",
        });
    }
    // The positions are < ni ≤ MAX_DIM, which fits 16 bits.
    if ni > u16::MAX as usize + 1 {
        return Err(Error::BadDimensions {
            reason: "volume side too long to re-slice",
        });
    }
    // `src`'s coordinate (0 = i, 1 = j, 2 = k) that becomes the result's i, j and k.
    let role = pt.map(|a| ps.iter().position(|&b| b == a).unwrap_or(0));
    let n = src.permuted_dims();
    // The counters of the new scanlines are kept in `src`'s order (the two coordinates
    // that name a new scanline, the later of them in `src`'s storage order first), so
    // that walking `src` in storage order touches them in order, and a source slice's
    // counters lie together (nested spheres 256³: 115–119 ms for the encoding, 156–169
    // with the counters in the new copy's order).
    let (hi, lo) = (role[1].max(role[2]), role[1].min(role[2]));
    let mut counter_step = [0; 3];
    counter_step[hi] = n[lo];
    counter_step[lo] = 1;
    let mut pos_step = [0; 3];
    pos_step[role[0]] = 1;
    let at = |c: [usize; 3], step: [usize; 3]| c[0] * step[0] + c[1] * step[1] + c[2] * step[2];
    let (_, src_voxels, _) = src.parts();
    let lines = nj * nk;
    // Pass 1: voxels per new scanline.
    let mut count = vec![0u32; lines];
    // `i` is never the later of the two coordinates, so a run's voxels either all go to
    // one new scanline (`i` is the new position) or to consecutive counters.
    let along = counter_step[0] == 0;
    visit(src, |i, j, k, run| {
        let first = at([i, j, k], counter_step);
        if along {
            count[first] += run.len() as u32;
        } else {
            for c in &mut count[first..][..run.len()] {
                *c += 1;
            }
        }
    });
    // Each new scanline's first slot, in the new copy's order (`k'·nj + j'`); the
    // counters become the next free slot of their scanline.
    let mut start = vec![0u32; lines + 1];
    let mut next = count;
    for kk in 0..nk {
        for jj in 0..nj {
            let s = kk * nj + jj;
            let mut c = [0; 3];
            (c[role[2]], c[role[1]]) = (kk, jj);
            let counter = &mut next[at(c, counter_step)];
            start[s + 1] = start[s] + *counter;
            *counter = start[s];
        }
    }
    // Pass 2: every voxel and its position into its scanline's next slot.
    let total = src_voxels.len();
    let mut voxels = bigbuf::filled(total, Voxel::default());
    let mut pos = bigbuf::filled(total, 0u16);
    visit(src, |i, j, k, run| {
        let (first, p0) = (at([i, j, k], counter_step), at([i, j, k], pos_step));
        if along {
            // The run, whole, at positions p0...
            let slot = next[first] as usize;
            voxels[slot..slot + run.len()].copy_from_slice(run);
            for (t, p) in pos[slot..slot + run.len()].iter_mut().enumerate() {
                *p = (p0 + t) as u16;
            }
            next[first] += run.len() as u32;
        } else {
            // Each voxel at position p0 of its own new scanline.
            for (s, v) in next[first..][..run.len()].iter_mut().zip(run) {
                let slot = *s as usize;
                voxels[slot] = *v;
                pos[slot] = p0 as u16;
                *s += 1;
            }
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
            ni,
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
    let [_, nj, nk] = src.permuted_dims();
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
    let x = reslice(
        &RleAxis::new(c.grid, Axis::Z, &z.0, &z.1, &z.2)?,
        c.grid,
        Axis::X,
    )?;
    let y = reslice(
        &RleAxis::new(c.grid, Axis::X, &x.0, &x.1, &x.2)?,
        c.grid,
        Axis::Y,
    )?;
    Ok([x, y, z])
}

#[cfg(test)]
mod tests {
    use super::*;
    use shearwarp_core::clip::Clip;
    use shearwarp_core::crop::Crop;
    use shearwarp_core::rle::Layout;

    /// The copies `rle::encode` makes of the dense classified volume.
    fn dense_route(c: &Classifier<'_>) -> [AxisArrays; 3] {
        let mut dense = vec![Voxel::default(); c.grid.voxel_count()];
        let (o, g, t) = (c.opacity_table, c.gradient_table, Some(c.threshold));
        classify::classify_above(c.grid, c.scalars, o, g, t, &mut dense).unwrap();
        c.cut.apply(c.grid, 0..c.grid.dims[2], &mut dense).unwrap();
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
            // The middle half of every side, cropped.
            let middle = Crop::new(
                dims.map(|n| n / 4),
                dims.map(|n| (3 * n / 4).min(n - 1)),
                dims,
            );
            // An oblique plane through the centre, and one more with the box.
            let oblique = Clip::NONE.with_plane(&grid, [1.0, -2.0, 0.5], 0.0).unwrap();
            let slab = oblique.with_plane(&grid, [0.0, 0.3, -1.0], 1.0).unwrap();
            let cases = [
                (None, 0, None, Clip::NONE),
                (None, 30, None, Clip::NONE),
                (Some(&grad), 12, None, Clip::NONE),
                (None, 0, Some(middle.unwrap()), Clip::NONE),
                (None, 0, None, oblique),
                (Some(&grad), 12, Some(middle.unwrap()), slab),
            ];
            for (gradient_table, threshold, crop, clip) in cases {
                let c = Classifier {
                    grid: &grid,
                    scalars: Scalars::U8(&data),
                    opacity_table: &ramp,
                    gradient_table,
                    threshold,
                    cut: Cut { crop, clip },
                };
                for bits in 0..8 {
                    let g = grid.with_layout(Layout::from_bits(bits).unwrap());
                    let c = Classifier { grid: &g, ..c };
                    let want = dense_route(&c);
                    for threads in [1, 2, 3] {
                        let got = encode_all(&c, threads).unwrap();
                        for a in 0..3 {
                            assert!(
                                got[a] == want[a],
                                "{dims:?} axis {a} layout {bits} threads {threads}"
                            );
                        }
                    }
                }
                // Every copy from every other one, in any layout of either.
                for (from, to) in [(1, 2), (0, 2), (1, 0), (2, 1)] {
                    let (f, t) = (Axis::ALL[from], Axis::ALL[to]);
                    for bits in 0..8 {
                        let g = grid.with_layout(Layout::from_bits(bits).unwrap());
                        let c = Classifier { grid: &g, ..c };
                        let want = dense_route(&c);
                        let a = &want[from];
                        let src = RleAxis::new(&g, f, &a.0, &a.1, &a.2).unwrap();
                        let got = reslice(&src, &g, t).unwrap();
                        assert!(got == want[to], "{dims:?} {f:?} to {t:?}, layout {bits}");
                    }
                }
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
