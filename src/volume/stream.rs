//! The streaming build of a volume's statistics and mip pyramid over a [`Source`].
//!
//! [`stream`] builds a volume from a source in **two passes**: the statistics first (the
//! normalization needs the finite range before any value is normalized), then one pass over
//! level 0's z-slices that normalizes each slice ([`Norm`], the formula of
//! `Volume::from_buffer`), adds it to level 0's brick ranges and the histogram, and pushes it
//! through the pyramid's `Reducer`. Memory beyond the levels kept is one slice of level 0 and a
//! few slices per coarser level. Level 0 is never kept by the stream: it is read from the
//! source when asked for (`Level::data`, `Level::read_box`).

use std::sync::Arc;

use super::pyramid::{self, BrickGridBuilder, Level, Narrow, Reducer};
use super::source::Source;
use super::summary::{code_value, small_codes, Stats};
use super::{
    buffer::for_each_value, half_scale, normalize_value, ByteOrder, Geometry, ScalarType,
    VolumeError,
};

/// How a source's values become normalized samples (`normalize` of `Volume::from_buffer`).
#[derive(Debug)]
pub(crate) struct Norm {
    norm_range: [f64; 2],
    scale: f64,
    /// For 8/16-bit codes: the sample of every code (as `small_int`).
    lut: Option<Vec<f32>>,
}

impl Norm {
    fn new(ty: ScalarType, norm_range: [f64; 2]) -> Norm {
        let scale = half_scale(norm_range);
        let lut = small_codes(ty).map(|codes| {
            (0..codes)
                .map(|c| normalize_value(code_value(ty, c), norm_range, scale).0)
                .collect()
        });
        Norm {
            norm_range,
            scale,
            lut,
        }
    }

    /// Normalized samples of values `start..start + out.len()` of `src` into `out`. For wider
    /// types (no table) it also counts each finite value's bin into `histogram` when given;
    /// 8/16-bit sources have their histogram from the first pass's code counts.
    pub(crate) fn read(
        &self,
        src: &Source,
        start: usize,
        out: &mut [f32],
        mut histogram: Option<&mut Vec<u64>>,
    ) -> Result<(), VolumeError> {
        let (ty, order) = (src.ty(), src.order());
        let mut i = 0;
        src.for_bytes(start..start + out.len(), |bytes| {
            if let Some(lut) = &self.lut {
                if ty.size() == 1 {
                    for (o, &b) in out[i..].iter_mut().zip(bytes) {
                        *o = lut[b as usize];
                    }
                } else {
                    for (o, c) in out[i..].iter_mut().zip(bytes.chunks_exact(2)) {
                        let b = [c[0], c[1]];
                        let code = match order {
                            ByteOrder::Little => u16::from_le_bytes(b),
                            ByteOrder::Big => u16::from_be_bytes(b),
                        };
                        *o = lut[code as usize];
                    }
                }
                i += bytes.len() / ty.size();
                return;
            }
            for_each_value(ty, order, bytes, |v| {
                out[i] = if v.is_finite() {
                    let (t, bin) = normalize_value(v, self.norm_range, self.scale);
                    if let Some(h) = histogram.as_deref_mut() {
                        h[bin] += 1;
                    }
                    t
                } else {
                    f32::NAN
                };
                i += 1;
            });
        })
    }
}

/// A source with its normalization and level shapes: what a lazy level is made from.
#[derive(Debug)]
pub(crate) struct Streamed {
    pub(crate) source: Source,
    pub(crate) norm: Norm,
    /// Points per axis and spacing of every level ([`pyramid::level_shapes`]).
    pub(crate) shapes: Vec<([usize; 3], [f64; 3])>,
}

impl Streamed {
    /// The samples of level `level`, made by streaming over the source again (the levels
    /// between it and level 0 are reduced slice by slice and not kept). The memory budget is
    /// checked first.
    pub(crate) fn materialize(&self, level: usize) -> Result<Vec<f32>, VolumeError> {
        let dims = self.shapes[level].0;
        crate::memory::check(
            format!(
                "mip level {level} ({}x{}x{} points, f32)",
                dims[0], dims[1], dims[2]
            ),
            crate::memory::product(&dims),
            4,
            "render at a coarser level (--level) or use a smaller volume",
        )
        .map_err(|e| VolumeError::file(self.source.path(), e.to_string()))?;
        let [nx, ny, nz] = self.shapes[0].0;
        let area = nx * ny;
        if level == 0 {
            let mut out = vec![0.0f32; self.source.len()];
            for (z, slice) in out.chunks_mut(area).enumerate() {
                self.norm.read(&self.source, z * area, slice, None)?;
                self.source.release(z * area..(z + 1) * area);
            }
            return Ok(out);
        }
        let mut reducer = Reducer::new(&self.shapes[..=level], |l| l == level);
        let mut slice = vec![0.0f32; area];
        for z in 0..nz {
            self.norm.read(&self.source, z * area, &mut slice, None)?;
            self.source.release(z * area..(z + 1) * area);
            reducer.push(&slice, |_, _| {});
        }
        Ok(reducer.finish().pop().flatten().unwrap_or_default())
    }
}

impl Streamed {
    /// Samples of level `level` in the box [`lo`, `hi`) (x fastest) without holding the
    /// level: level 0's rows are read from the source, a coarser level is reduced from the box
    /// of the finer one that its filter reads (`pyramid::reduce_box`: the streamed level's
    /// values bit for bit). 64-bit index math: level 0 may hold more than 2³² points.
    pub(crate) fn read_box(
        &self,
        level: usize,
        lo: [usize; 3],
        hi: [usize; 3],
        out: &mut [f32],
    ) -> Result<(), VolumeError> {
        if level == 0 {
            let w = hi[0] - lo[0];
            let rows = pyramid::box_rows(self.shapes[0].0, lo, hi);
            for (row, at) in out.chunks_exact_mut(w.max(1)).zip(rows) {
                // A usize index: the values lie in this process's memory (a map or a buffer).
                self.norm.read(&self.source, at as usize, row, None)?;
            }
            return Ok(());
        }
        let (input, output) = (self.shapes[level - 1].0, self.shapes[level].0);
        pyramid::reduce_box(input, output, lo, hi, out, |l, h, buf| {
            self.read_box(level - 1, l, h, buf)
        })
    }
}

/// The statistics and levels of a volume streamed from a source.
pub(crate) struct Streaming {
    pub(crate) stats: Stats,
    pub(crate) levels: Vec<Level>,
}

/// Build a volume's statistics and levels from `source` (module docs: two passes). Levels 1..
/// whose f32 samples [`keep`] accepts are held; the others, and level 0, are made when asked
/// for. `None` when no value is finite.
pub(crate) fn stream(
    geometry: Geometry,
    declared: ScalarType,
    source: Source,
) -> Result<Option<Streaming>, VolumeError> {
    let Some((stats, _counts)) = source.stats()? else {
        return Ok(None);
    };
    let shapes = pyramid::level_shapes(geometry);
    let kept = keep(&shapes, crate::memory::budget());
    stream_keeping(geometry, declared, source, stats, shapes, &kept)
}

/// [`stream`] after the statistics pass, holding the levels `kept` says.
fn stream_keeping(
    geometry: Geometry,
    declared: ScalarType,
    source: Source,
    mut stats: Stats,
    shapes: Vec<([usize; 3], [f64; 3])>,
    kept: &[bool],
) -> Result<Option<Streaming>, VolumeError> {
    // Held whatever is kept: every level's brick ranges (`level_bytes` less the samples, plus
    // the builder's NaN flag per brick of about 512 points), and a slice of level 0 as f32
    // with the reducer's few.
    let held: u64 = shapes
        .iter()
        .map(|(d, _)| {
            let samples = 4 * d.iter().product::<usize>() as u64;
            pyramid::level_bytes(*d) as u64 - samples + samples.div_ceil(4 * 512)
        })
        .sum::<u64>()
        + 16 * (geometry.dims[0] * geometry.dims[1]) as u64
        + kept
            .iter()
            .zip(&shapes)
            .filter(|(k, _)| **k)
            .map(|(_, s)| pyramid::level_bytes(s.0) as u64)
            .sum::<u64>();
    crate::memory::check(
        "the volume's brick ranges and coarse mip levels",
        Some(held),
        1,
        "use a smaller volume",
    )
    .map_err(|e| VolumeError::file(source.path(), e.to_string()))?;

    let norm = Norm::new(source.ty(), stats.norm_range);
    let [nx, ny, nz] = geometry.dims;
    let area = nx * ny;
    let mut grids: Vec<BrickGridBuilder> =
        shapes.iter().map(|s| BrickGridBuilder::new(s.0)).collect();
    let mut reducer = Reducer::new(&shapes, |l| kept[l]);
    // The generic path counts the histogram while normalizing (the code path has it).
    let mut histogram = stats
        .histogram
        .is_empty()
        .then(|| vec![0u64; super::HISTOGRAM_BINS]);
    let mut slice = vec![0.0f32; area];
    for z in 0..nz {
        norm.read(&source, z * area, &mut slice, histogram.as_mut())?;
        source.release(z * area..(z + 1) * area);
        let (first, rest) = grids.split_first_mut().expect("level 0 exists");
        first.push(&slice);
        reducer.push(&slice, |l, s| rest[l - 1].push(s));
    }
    if let Some(h) = histogram {
        stats.histogram = h;
    }
    let narrow = narrow_for(declared, stats.norm_range);
    let streamed = Arc::new(Streamed {
        source,
        norm,
        shapes: shapes.clone(),
    });
    let mut data = reducer.finish();
    let levels = shapes
        .iter()
        .zip(grids)
        .enumerate()
        .map(|(l, ((dims, spacing), grid))| {
            let narrow = if l == 0 { narrow } else { Narrow::Round16 };
            let data = if l == 0 { None } else { data[l - 1].take() };
            Level::lazy(*dims, *spacing, grid.finish(), narrow, data, &streamed, l)
        })
        .collect();
    Ok(Some(Streaming { stats, levels }))
}

/// Which levels a stream keeps in f32: the coarse ones that fit half of `budget` bytes,
/// coarsest first, none above [`KEEP_POINTS`] points (finer than 512³); level 0 never. The
/// others are made when asked for.
pub(crate) fn keep(shapes: &[([usize; 3], [f64; 3])], budget: u64) -> Vec<bool> {
    let mut kept = vec![false; shapes.len()];
    let mut used = 0u64;
    for l in (1..shapes.len()).rev() {
        let dims = shapes[l].0;
        used = used.saturating_add(pyramid::level_bytes(dims) as u64);
        if dims.iter().product::<usize>() > KEEP_POINTS || used > budget / 2 {
            break;
        }
        kept[l] = true;
    }
    kept
}

/// Points of the finest level a stream keeps: 512³ (512 MiB of f32).
const KEEP_POINTS: usize = 1 << 27;

/// How level 0's samples may be narrowed: integer data spanning at most 65535 steps
/// normalizes to k / span exactly, so the renderer's bricked copy can store k in 8 or 16 bits
/// (render::cpu::bricked).
pub(super) fn narrow_for(scalar_type: ScalarType, norm_range: [f64; 2]) -> Narrow {
    let span = norm_range[1] - norm_range[0];
    let integer = !matches!(scalar_type, ScalarType::F32 | ScalarType::F64);
    if integer && span.fract() == 0.0 && (1.0..=65535.0).contains(&span) {
        Narrow::Exact(span as u32)
    } else {
        Narrow::No
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::TypedBuffer;
    use std::path::Path;

    #[test]
    fn keeps_the_coarse_levels_that_fit() {
        let geometry = Geometry {
            dims: [2048, 2048, 2048],
            spacing: [1.0; 3],
            origin: [0.0; 3],
        };
        let shapes = pyramid::level_shapes(geometry);
        assert_eq!(shapes[2].0, [512; 3]);
        // 512³ and coarser: levels 2..; not 1024³ nor level 0.
        let kept = keep(&shapes, 8 << 30);
        assert!(
            !kept[0] && !kept[1] && kept[2..].iter().all(|&k| k),
            "{kept:?}"
        );
        // A small budget keeps only what fits in half of it, coarsest first.
        let kept = keep(&shapes, 200 << 20);
        assert!(!kept[2] && kept[3..].iter().all(|&k| k), "{kept:?}");
        assert_eq!(keep(&shapes, 0), vec![false; shapes.len()]);
    }

    /// Levels that are not held: `read_box` (reduced from level 0's box on the source) and
    /// `try_data` (a second stream) equal the in-memory pyramid bit for bit, on odd boxes.
    #[test]
    fn levels_not_held_read_like_held_ones() {
        let dims = [37, 29, 23];
        let n: usize = dims.iter().product();
        let mut values: Vec<f64> = (0..n).map(|i| ((i * 7919) % 1013) as f64 - 3.5).collect();
        for i in (0..n).step_by(89) {
            values[i] = f64::NAN;
        }
        let geometry = Geometry {
            dims,
            spacing: [1.0, 0.5, 2.0],
            origin: [0.0; 3],
        };
        let path = Path::new("t");
        let buffer = TypedBuffer::from_f64(values);
        let reference = super::super::Volume::from_buffer(path, geometry, &buffer).unwrap();
        let source = Source::memory(path, buffer);
        let (stats, _) = source.stats().unwrap().unwrap();
        let shapes = pyramid::level_shapes(geometry);
        let none = vec![false; shapes.len()];
        let s = stream_keeping(geometry, ScalarType::F64, source, stats, shapes, &none)
            .unwrap()
            .unwrap();
        assert_eq!(s.stats.histogram, reference.histogram);
        assert!(s.levels.len() >= 3);
        let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for (l, (level, want)) in s.levels.iter().zip(&reference.levels).enumerate() {
            assert!(!level.is_materialized(), "level {l}");
            let d = level.dims;
            let boxes = [
                ([0, 0, 0], d),
                ([1, 2, 3], [d[0] - 1, d[1], d[2] - 2]),
                (
                    [d[0] / 2, d[1] / 3, d[2] / 2],
                    [d[0] / 2 + 1, d[1] / 3 + 2, d[2]],
                ),
                ([d[0] - 1, d[1] - 1, d[2] - 1], d),
            ];
            for (lo, hi) in boxes {
                let lo: [usize; 3] = std::array::from_fn(|a| lo[a].min(hi[a]));
                let len = (0..3).map(|a| hi[a] - lo[a]).product();
                let mut out = vec![0.0; len];
                level.read_box(lo, hi, &mut out).unwrap();
                let mut expect = Vec::new();
                for at in pyramid::box_rows(d, lo, hi) {
                    expect.extend_from_slice(&want.data()[at as usize..][..hi[0] - lo[0]]);
                }
                assert_eq!(bits(&out), bits(&expect), "level {l} {lo:?}..{hi:?}");
            }
            assert!(!level.is_materialized(), "read_box made level {l}");
            assert_eq!(
                bits(level.try_data().unwrap()),
                bits(want.data()),
                "level {l}"
            );
            assert_eq!(level.bricks.min, want.bricks.min, "level {l}");
        }
    }
}
