//! Fast re-classification for window/level changes.
//!
//! Window/level changes only the opacity transfer function, but the file frontend's
//! `scene::encode` recomputes every gradient and normal too. Without a gradient-opacity
//! function the core's `classify` sets `opacity = table[raw value]` and nothing else
//! depends on the table, so this module classifies once (normals and quantised scalars)
//! and afterwards only rewrites the opacity byte and run-length encodes the three axis
//! copies again with the core's `rle` functions. The result is the same encoding
//! `scene::encode` builds, bit for bit (checked by the tests below), and takes flat
//! voxels the way the CLI does by default (`FlatVoxels::for_volume`, with the tables
//! of them that `Encoded::build_flat_rows` makes).

use shearwarp_core::classify::{self, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::composite::FlatVoxels;
use shearwarp_core::normal::ZERO_GRADIENT;
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::source::RleVolume;
use shearwarp_core::Error;
use shearwarp_file::scene::{self, Classification};
use shearwarp_file::volume::{RawVolume, Voxels};
use std::sync::Arc;
use std::time::Instant;

/// A volume classified once, ready to be encoded under any opacity function.
pub struct Classifier {
    raw: Arc<RawVolume>,
    grid: Grid,
    /// Classified voxels with opacity 0.
    base: Vec<Voxel>,
}

fn scalars(raw: &RawVolume) -> Scalars<'_> {
    match &raw.voxels {
        Voxels::U8(d) => Scalars::U8(d),
        Voxels::U16(d) => Scalars::U16(d),
    }
}

impl Classifier {
    /// Computes normals and quantised scalars of `raw`.
    pub fn new(raw: Arc<RawVolume>) -> Result<Self, Error> {
        let grid = Grid::new(raw.dims, raw.spacing)?;
        let s = scalars(&raw);
        let zero = vec![0u8; s.value_count()];
        let mut base = vec![Voxel::default(); grid.voxel_count()];
        classify::classify(&grid, s, &zero, None, &mut base)?;
        Ok(Classifier { raw, grid, base })
    }

    /// Geometry.
    pub fn grid(&self) -> Grid {
        self.grid
    }

    /// Raw value range the scalars are quantised over.
    pub fn range(&self) -> (u16, u16) {
        scalars(&self.raw).range()
    }

    /// The classified voxels under `class` (which must have no gradient-opacity
    /// function): the stored records with the opacity byte rewritten.
    pub fn relabel(&self, class: &Classification) -> Result<Vec<Voxel>, Error> {
        if class.gradient.is_some() {
            return Err(Error::BadParameter {
                reason: "the fast re-classification has no gradient opacity",
            });
        }
        if !(0.0..1.0).contains(&class.min_opacity) {
            return Err(Error::BadParameter {
                reason: "minimum opacity must be in [0, 1)",
            });
        }
        let s = scalars(&self.raw);
        let pts: Vec<(f64, [f64; 1])> = class.opacity.iter().map(|&(v, a)| (v, [a])).collect();
        let mut table = vec![0u8; s.value_count()];
        OpacityTf::new(&pts)?.build_table(&mut table);
        let mut dense = match &self.raw.voxels {
            Voxels::U8(d) => relabel(&self.base, d, &table),
            Voxels::U16(d) => relabel(&self.base, d, &table),
        };
        class
            .cut
            .apply(&self.grid, 0..self.grid.dims[2], &mut dense)?;
        Ok(dense)
    }

    /// Encodes `axes` under `class`, reusing `dense` if it was relabelled for `class`.
    pub fn encode_axes(
        &self,
        class: &Classification,
        dense: Option<Arc<Vec<Voxel>>>,
        axes: &[Axis],
    ) -> Result<Encoding, Error> {
        let t = Instant::now();
        let dense = match dense {
            Some(d) => d,
            None => Arc::new(self.relabel(class)?),
        };
        // The file frontend's encoder: it reads the volume in storage order.
        let threshold = (class.min_opacity * 255.0).floor() as u8;
        let (visible, flat) = dense
            .iter()
            .filter(|v| rle::is_visible(v, threshold))
            .fold((0, 0), |(n, f), v| {
                (n + 1, f + (v.normal == ZERO_GRADIENT) as u64)
            });
        let flat_voxels = FlatVoxels::for_volume(flat, visible);
        let axes = axes
            .iter()
            .map(|&a| {
                let (runs, voxels, scans) =
                    scene::encode_axis(&dense, &self.grid, a, threshold, visible as usize)?;
                let mut rle = AxisRle {
                    runs,
                    voxels,
                    scans,
                    flat: Vec::new(),
                };
                if flat_voxels == FlatVoxels::Excluded {
                    rle.flat = scene::flat_rows(&rle.axis(&self.grid, a)?)?;
                }
                Ok((a, rle))
            })
            .collect::<Result<Vec<_>, Error>>()?;
        Ok(Encoding {
            class: class.clone(),
            dense,
            axes,
            flat_voxels,
            ms: t.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// All three copies under `class`.
    pub fn encode(&self, class: &Classification) -> Result<LevelRle, Error> {
        let mut level = LevelRle::new(self.grid, self.range());
        level.install(self.encode_axes(class, None, &Axis::ALL)?);
        Ok(level)
    }
}

fn relabel<T: Copy + Into<usize>>(base: &[Voxel], raw: &[T], table: &[u8]) -> Vec<Voxel> {
    base.iter()
        .zip(raw)
        .map(|(v, &r)| Voxel {
            opacity: table[r.into()],
            ..*v
        })
        .collect()
}

/// One run-length-encoded axis copy, with its table of flat voxels when its
/// classification excludes them (empty otherwise).
pub struct AxisRle {
    runs: Vec<u8>,
    voxels: Vec<Voxel>,
    scans: Vec<ScanIndex>,
    flat: Vec<u64>,
}

impl AxisRle {
    /// The copy as the core reads it, without its table of flat voxels.
    fn axis<'a>(&'a self, grid: &Grid, a: Axis) -> Result<RleAxis<'a>, Error> {
        RleAxis::new(grid, a, &self.runs, &self.voxels, &self.scans)
    }
}

/// Freshly encoded axis copies and the relabelled voxels they came from.
pub struct Encoding {
    /// The classification.
    pub class: Classification,
    /// The voxels under it (kept to encode the other axes later).
    pub dense: Arc<Vec<Voxel>>,
    /// The copies.
    pub axes: Vec<(Axis, AxisRle)>,
    /// How frames take flat voxels under `class` ([`FlatVoxels::for_volume`]).
    pub flat_voxels: FlatVoxels,
    /// Milliseconds it took.
    pub ms: f64,
}

/// A level's three axis copies, each tagged with the classification it was built for.
///
/// A frame reads only the copy of its principal axis, so after a window/level change
/// only that copy has to be rebuilt before the frame can be drawn; the others are
/// brought up to date when a view needs them. Stale copies are still valid encodings,
/// so [`LevelRle::volume`] can always hand all three to the core.
pub struct LevelRle {
    /// Geometry.
    pub grid: Grid,
    /// Raw range the scalars were quantised over.
    pub range: (u16, u16),
    axes: [Option<(Classification, AxisRle)>; 3],
    dense: Option<(Classification, Arc<Vec<Voxel>>)>,
    flat_voxels: FlatVoxels,
}

fn same(a: &Classification, b: &Classification) -> bool {
    a.opacity == b.opacity
        && a.min_opacity == b.min_opacity
        && a.gradient == b.gradient
        && a.cut == b.cut
}

impl LevelRle {
    /// No copies yet.
    pub fn new(grid: Grid, range: (u16, u16)) -> Self {
        LevelRle {
            grid,
            range,
            axes: [None, None, None],
            dense: None,
            flat_voxels: FlatVoxels::Blended,
        }
    }

    /// The copies to build so that `axis` is current for `class` and all three exist.
    pub fn missing(&self, class: &Classification, axis: Axis) -> Vec<Axis> {
        Axis::ALL
            .into_iter()
            .filter(|&a| match &self.axes[a as usize] {
                None => true,
                Some((c, _)) => a == axis && !same(c, class),
            })
            .collect()
    }

    /// The relabelled voxels, if they are for `class`.
    pub fn dense_for(&self, class: &Classification) -> Option<Arc<Vec<Voxel>>> {
        match &self.dense {
            Some((c, d)) if same(c, class) => Some(Arc::clone(d)),
            _ => None,
        }
    }

    /// Takes in freshly encoded copies.
    pub fn install(&mut self, enc: Encoding) {
        for (a, rle) in enc.axes {
            self.axes[a as usize] = Some((enc.class.clone(), rle));
        }
        self.dense = Some((enc.class, enc.dense));
        self.flat_voxels = enc.flat_voxels;
    }

    /// How frames take flat voxels under the latest classification. A stale copy may
    /// lack the tables this asks for, or have some it does not: either way the core
    /// renders it right (without a table it finds the flat voxels in the runs).
    pub fn flat_voxels(&self) -> FlatVoxels {
        self.flat_voxels
    }

    /// Builds what [`LevelRle::missing`] names, on this thread; returns the milliseconds
    /// spent (0 if nothing was missing).
    pub fn ensure(
        &mut self,
        classifier: &Classifier,
        class: &Classification,
        axis: Axis,
    ) -> Result<f64, Error> {
        let missing = self.missing(class, axis);
        if missing.is_empty() {
            return Ok(0.0);
        }
        let enc = classifier.encode_axes(class, self.dense_for(class), &missing)?;
        let ms = enc.ms;
        self.install(enc);
        Ok(ms)
    }

    /// Borrows the copies as a renderable source.
    pub fn volume(&self) -> Result<RleVolume<'_>, Error> {
        let axis = |a: Axis| {
            let (_, r) = self.axes[a as usize].as_ref().ok_or(Error::Source {
                reason: "an axis copy has not been encoded yet",
            })?;
            let copy = r.axis(&self.grid, a)?;
            if r.flat.is_empty() {
                Ok(copy)
            } else {
                copy.with_flat_rows(&r.flat)
            }
        };
        RleVolume::new(self.grid, [axis(Axis::X)?, axis(Axis::Y)?, axis(Axis::Z)?])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Compositor, ImageMap};
    use shearwarp_core::composite::Mode;
    use shearwarp_core::shade::Lighting;
    use shearwarp_core::view::Camera;
    use shearwarp_file::scene::{self, Look};

    fn lumpy(voxels: impl Fn(usize) -> Voxels) -> RawVolume {
        RawVolume {
            name: "lumpy".into(),
            dims: [23, 19, 17],
            spacing: [1.0, 0.8, 1.7],
            voxels: voxels(23 * 19 * 17),
        }
    }

    fn value(i: usize) -> u32 {
        let (x, y, z) = (i % 23, (i / 23) % 19, i / (23 * 19));
        let r = ((x as f64 - 11.0).powi(2) + (y as f64 - 8.0).powi(2) + (z as f64 - 9.0).powi(2))
            .sqrt();
        let noise = (i.wrapping_mul(2654435761) >> 7) % 37;
        (200.0 - 18.0 * r).max(0.0) as u32 + noise as u32
    }

    #[test]
    fn equals_scene_encode_bit_for_bit() {
        let u8v = lumpy(|n| Voxels::U8((0..n).map(|i| value(i).min(255) as u8).collect()));
        let u16v = lumpy(|n| Voxels::U16((0..n).map(|i| (value(i) * 13 + 100) as u16).collect()));
        // Plateaus: a ball of one value on a zero background, both flat inside, so that
        // under a constant opacity flat voxels are common enough to be excluded.
        let plateaus =
            lumpy(|n| Voxels::U8((0..n).map(|i| (value(i) > 120) as u8 * 200).collect()));
        let mut excluded = 0;
        for raw in [u8v, u16v, plateaus] {
            let range = crate::preset::data_range(&raw);
            let raw = Arc::new(raw);
            let c = Classifier::new(Arc::clone(&raw)).unwrap();
            let mut comp = Compositor::new(&c.grid(), 2);
            // The last case cuts the volume open (the viewer's C key: lower half in y).
            let cut = crate::state::Cut::Axis { axis: 1, keep: 10 };
            let half = cut.crop(raw.dims);
            for (k, opacity) in [
                vec![(0.0, 0.0), (60.0, 0.0), (150.0, 0.5), (255.0, 0.9)],
                vec![(20.0, 0.0), (3000.0, 1.0)],
                vec![(0.0, 0.3)],
                vec![(0.0, 0.6)],
                vec![(0.0, 0.0), (60.0, 0.0), (150.0, 0.5), (255.0, 0.9)],
            ]
            .into_iter()
            .enumerate()
            {
                let class = Classification {
                    opacity,
                    gradient: None,
                    min_opacity: [0.02, 0.0, 0.5, 0.0, 0.02][k],
                    cut: scene::Cut {
                        crop: if k == 4 { half } else { None },
                        ..scene::Cut::NONE
                    },
                };
                let mine = c.encode(&class).unwrap();
                let mut theirs = scene::encode(&raw, &class).unwrap();
                assert_eq!(mine.range, theirs.range);
                // The CLI's default way with flat voxels, and its tables.
                let way = theirs.auto_flat_voxels();
                assert_eq!(mine.flat_voxels(), way);
                if way == FlatVoxels::Excluded {
                    theirs.build_flat_rows().unwrap();
                    excluded += 1;
                }
                comp.set_flat_voxels(way);
                let axes: Vec<&AxisRle> =
                    mine.axes.iter().map(|a| &a.as_ref().unwrap().1).collect();
                assert_eq!(axes[2].voxels.len(), theirs.visible_voxels());
                let bytes: usize = axes
                    .iter()
                    .map(|a| a.runs.len() + 4 * a.voxels.len() + 8 * a.scans.len())
                    .sum();
                assert_eq!(bytes, theirs.bytes());
                assert_eq!(mine.volume().unwrap().axis(Axis::Z).dims(), raw.dims);
                let look = Look {
                    mode: Mode::Composite,
                    color: scene::color_table(
                        &[(0.0, [255, 128, 0]), (5000.0, [0, 128, 255])],
                        range,
                    )
                    .unwrap(),
                    lighting: Some(Lighting::default()),
                    ert_threshold: 0.95,
                    depth_cue: None,
                    shadows: false,
                };
                for (rx, ry) in [(0.0, 0.0), (-70.0, -35.0), (80.0, 10.0), (20.0, 95.0)] {
                    let cam = Camera {
                        rotate_x: rx,
                        rotate_y: ry,
                        width: 64,
                        height: 48,
                    };
                    let id = ImageMap::identity(&c.grid());
                    let a = comp
                        .render(&mine.volume().unwrap(), &cam, &look, &id)
                        .unwrap();
                    let b = comp
                        .render(&theirs.volume().unwrap(), &cam, &look, &id)
                        .unwrap();
                    assert!(a == b, "class {k} view {rx},{ry}");
                }
            }
        }
        assert!(excluded > 0, "no classification excluded flat voxels");
    }

    #[test]
    fn lazy_axes_render_like_a_full_encode() {
        let raw = Arc::new(lumpy(|n| {
            Voxels::U8((0..n).map(|i| value(i).min(255) as u8).collect())
        }));
        let c = Classifier::new(Arc::clone(&raw)).unwrap();
        let class = |lo: f64| Classification {
            opacity: vec![(lo, 0.0), (lo + 60.0, 0.7)],
            gradient: None,
            min_opacity: 0.02,
            cut: scene::Cut::NONE,
        };
        let (a, b) = (class(40.0), class(90.0));
        let mut level = c.encode(&a).unwrap();
        assert_eq!(level.missing(&b, Axis::Z), vec![Axis::Z]);
        assert!(level.ensure(&c, &b, Axis::Z).unwrap() > 0.0);
        assert!(level.missing(&b, Axis::Z).is_empty());
        assert_eq!(level.missing(&b, Axis::X), vec![Axis::X]);
        let look = Look {
            mode: Mode::Composite,
            color: scene::color_table(&[(0.0, [255, 255, 255])], (0, 255)).unwrap(),
            lighting: Some(Lighting::default()),
            ert_threshold: 0.95,
            depth_cue: None,
            shadows: false,
        };
        let want = scene::encode(&raw, &b).unwrap();
        let mut comp = Compositor::new(&c.grid(), 2);
        let id = ImageMap::identity(&c.grid());
        let cam = |rx: f64, ry: f64| Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: 40,
            height: 40,
        };
        // Principal axis Z: only the Z copy was rebuilt, and it is all the frame reads.
        let z = cam(10.0, 5.0);
        assert_eq!(
            shearwarp_core::view::Factorization::new(&c.grid(), &z)
                .unwrap()
                .axis,
            Axis::Z
        );
        let got = comp
            .render(&level.volume().unwrap(), &z, &look, &id)
            .unwrap();
        let exp = comp
            .render(&want.volume().unwrap(), &z, &look, &id)
            .unwrap();
        assert!(got == exp);
        // Turning to X: that copy is brought up to date from the kept voxels.
        assert!(level.ensure(&c, &b, Axis::X).unwrap() > 0.0);
        assert!(level.missing(&b, Axis::X).is_empty());
        let x = cam(0.0, 80.0);
        let got = comp
            .render(&level.volume().unwrap(), &x, &look, &id)
            .unwrap();
        let exp = comp
            .render(&want.volume().unwrap(), &x, &look, &id)
            .unwrap();
        assert!(got == exp);
    }

    #[test]
    fn rejects_what_it_cannot_do() {
        let raw = Arc::new(lumpy(|n| Voxels::U8(vec![7; n])));
        let c = Classifier::new(raw).unwrap();
        let mut class = Classification {
            opacity: vec![(0.0, 1.0)],
            gradient: Some(vec![(0.0, 1.0)]),
            min_opacity: 0.0,
            cut: scene::Cut::NONE,
        };
        assert!(c.encode(&class).is_err());
        class.gradient = None;
        class.min_opacity = 1.0;
        assert!(c.encode(&class).is_err());
        class.min_opacity = 0.0;
        class.opacity = vec![(5.0, 0.1), (5.0, 0.2)];
        assert!(c.encode(&class).is_err());
    }
}
