//! One ray through one mip level: box clipping, trilinear sampling, LUT lookup and front-to-back
//! compositing. The forward and backward passes run the *same* march (same samples, same skips,
//! same early stop) and differ only in what they do per sample, so the backward is the exact
//! gradient of what the forward computed.

use glam::DVec3;

use super::fastmath::ceil;
use super::skip::Blocks;
use crate::tf::Lut;
use crate::volume::Level;

/// A level's samples with the index arithmetic precomputed.
pub(crate) struct Grid<'a> {
    data: &'a [f32],
    /// Largest valid coordinate per axis: dims − 1.
    max_coord: [f32; 3],
    /// Largest cell index per axis: max(dims − 2, 0).
    max_cell: [usize; 3],
    /// Index offset of the +1 corner per axis (0 on a 1-point axis, so it reuses the point).
    step: [usize; 3],
    /// Row and slice strides.
    stride: [usize; 2],
    /// [super-blocks, bricks]: checked coarse to fine before sampling.
    blocks: &'a [Blocks; 2],
}

impl<'a> Grid<'a> {
    pub(crate) fn new(level: &'a Level, blocks: &'a [Blocks; 2]) -> Grid<'a> {
        let d = level.dims;
        let stride = [d[0], d[0] * d[1]];
        Grid {
            data: &level.data,
            max_coord: d.map(|n| (n - 1) as f32),
            max_cell: d.map(|n| n.saturating_sub(2)),
            step: [
                usize::from(d[0] > 1),
                if d[1] > 1 { stride[0] } else { 0 },
                if d[2] > 1 { stride[1] } else { 0 },
            ],
            stride,
            blocks,
        }
    }
}

/// A ray in a level's index space, clipped to the box: position `a + s * b` for `s` in
/// [0, length], `s` in world units (so `b` is the world direction divided by the spacing).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ray {
    a: [f32; 3],
    b: [f32; 3],
    /// 1 / (b · δ) per axis (0 where b is 0): block exits in sample units without divisions.
    inv_b_delta: [f32; 3],
    /// Number of segments; segment n is [n δ, min((n + 1) δ, length)].
    segments: u32,
    delta: f32,
    delta_last: f32,
    /// Where in its segment each sample sits, in [0, 1) (0.5 without jitter).
    jitter: f32,
}

/// One view's box in a level's index space, with what every ray's clipping shares.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BoxFrame {
    /// The eye in index coordinates.
    eye: DVec3,
    inv_spacing: DVec3,
    /// dims − 1 per axis: the box is [0, hi].
    hi: DVec3,
    delta: f64,
    inv_delta: f64,
}

impl BoxFrame {
    /// The box of a level with `dims` points at `spacing` from `origin`, seen from `eye`, cut
    /// into segments of world length `delta`.
    pub(crate) fn new(
        eye: DVec3,
        origin: DVec3,
        spacing: DVec3,
        dims: [usize; 3],
        delta: f64,
    ) -> BoxFrame {
        let inv_spacing = spacing.recip();
        BoxFrame {
            eye: (eye - origin) * inv_spacing,
            inv_spacing,
            hi: DVec3::from_array(dims.map(|d| (d - 1) as f64)),
            delta,
            inv_delta: 1.0 / delta,
        }
    }

    /// Clip the ray `eye + t dir` (t ≥ 0, `dir` a unit world vector) to the box. `None` when
    /// it misses the box or only touches it.
    #[inline]
    pub(crate) fn clip(&self, dir: DVec3, jitter: f32) -> Option<Ray> {
        let (a, b) = (self.eye, dir * self.inv_spacing);
        let inv_b = b.recip();
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for ax in 0..3 {
            if b[ax].abs() < 1e-300 {
                // Parallel to this slab: inside it or never.
                if a[ax] < 0.0 || a[ax] > self.hi[ax] {
                    return None;
                }
                continue;
            }
            let (ta, tb) = (-a[ax] * inv_b[ax], (self.hi[ax] - a[ax]) * inv_b[ax]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        let length = t1 - t0;
        if length.is_nan() || length <= 0.0 {
            return None;
        }
        let segments = (length * self.inv_delta).ceil().max(1.0);
        if segments > u32::MAX as f64 {
            return None;
        }
        let segments = segments as u32;
        let entry = a + t0 * b;
        Some(Ray {
            a: entry.as_vec3().to_array(),
            b: b.as_vec3().to_array(),
            inv_b_delta: std::array::from_fn(|ax| {
                if b[ax].abs() < 1e-300 {
                    0.0
                } else {
                    (inv_b[ax] * self.inv_delta) as f32
                }
            }),
            segments,
            delta: self.delta as f32,
            delta_last: (length - (segments - 1) as f64 * self.delta) as f32,
            jitter,
        })
    }
}

/// What the per-sample visitor sees (only non-empty samples are visited).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    /// LUT entry below the sample and the weight of the entry above.
    pub lut_index: usize,
    pub lut_weight: f32,
    pub rgb: [f32; 3],
    /// Segment length in normalized units (δ / L).
    pub delta_norm: f32,
    /// How many identical consecutive samples this stands for (> 1 across a uniform brick,
    /// where the per-sample terms of the backward are equal and are summed in one go).
    pub count: f32,
    /// Transmittance before and after the sample.
    pub t_before: f32,
    pub t_after: f32,
    /// Colour accumulated up to and including this sample (no background).
    pub acc: [f32; 3],
}

/// Result of one march.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Marched {
    pub acc: [f32; 3],
    pub transmittance: f32,
    /// Samples whose scalar was interpolated (skipped ones excluded).
    pub samples: u32,
}

/// Constants of one march shared by every ray of a view.
pub(crate) struct MarchParams<'a> {
    pub grid: Grid<'a>,
    pub lut: &'a Lut,
    /// 1 / L (L = the box's longest side, DESIGN.md density units).
    pub inv_l: f32,
    /// Stop once T falls below this (0 = never).
    pub stop_below: f32,
}

/// Index of the first sample past block `bc` (of `cells` cells per side) along `ray`, as a
/// whole number in f32 (infinite when the ray never leaves it, which cannot happen in a box).
#[inline(always)]
fn next_sample_after_block(g: &Grid, ray: &Ray, bc: [usize; 3], cells: usize) -> f32 {
    let mut exit = f32::INFINITY;
    for (ax, &b) in bc.iter().enumerate() {
        let bnd = if ray.b[ax] > 0.0 {
            ((b + 1) * cells).min(g.max_cell[ax] + 1) as f32
        } else if ray.b[ax] < 0.0 {
            (b * cells) as f32
        } else {
            continue;
        };
        exit = exit.min((bnd - ray.a[ax]) * ray.inv_b_delta[ax]);
    }
    ceil(exit - ray.jitter)
}

/// March `ray` front to back, calling `visit` after each non-empty sample.
#[inline(always)]
pub(crate) fn march<F: FnMut(&Sample)>(p: &MarchParams, ray: &Ray, mut visit: F) -> Marched {
    let g = &p.grid;
    let lut = &p.lut.entries;
    let lut_max = (lut.len() - 1) as f32;
    let lut_last_cell = lut.len() - 2;
    let mut t = 1.0f32;
    let mut acc = [0.0f32; 3];
    let mut samples = 0u32;
    let mut n = 0u32;
    let last = ray.segments - 1;
    while n < ray.segments {
        let (s, dn) = if n < last {
            ((n as f32 + ray.jitter) * ray.delta, ray.delta)
        } else {
            (
                last as f32 * ray.delta + ray.jitter * ray.delta_last,
                ray.delta_last,
            )
        };
        let pos: [f32; 3] =
            std::array::from_fn(|ax| (ray.a[ax] + s * ray.b[ax]).clamp(0.0, g.max_coord[ax]));
        // Through i32: f32 → usize saturation costs about 12 instructions on x86-64, f32 → i32
        // about 4 (measured with callgrind); positions are clamped to [0, dims − 1] already.
        let cell: [usize; 3] =
            std::array::from_fn(|ax| (pos[ax] as i32 as usize).min(g.max_cell[ax]));
        let lerp = |a: f32, b: f32, w: f32| a + w * (b - a);
        // Coarse to fine: an empty block is jumped over (sample positions do not move, so this
        // only drops samples that are empty anyway); a uniform block is crossed in one step
        // (every trilinear sample in it is its value, exactly: a + w·0).
        let mut found = None;
        let mut jumped = false;
        for b in g.blocks {
            let bc = cell.map(|c| c >> b.shift);
            let i = bc[0] + b.counts[0] * (bc[1] + b.counts[1] * bc[2]);
            if b.empty[i] {
                let next = next_sample_after_block(g, ray, bc, b.cells);
                n = if next > n as f32 {
                    next.min(ray.segments as f32) as u32
                } else {
                    n + 1
                };
                jumped = true;
                break;
            }
            let value = b.value[i];
            if !value.is_nan() {
                // Samples n..n+run all lie in this block or in the blocks right behind it that
                // hold the same value (the last, shorter segment is always taken on its own).
                let mut next = next_sample_after_block(g, ray, bc, b.cells);
                while next > n as f32 && next < last as f32 {
                    let m = next as u32;
                    let s = (m as f32 + ray.jitter) * ray.delta;
                    let cell: [usize; 3] = std::array::from_fn(|ax| {
                        let p = (ray.a[ax] + s * ray.b[ax]).clamp(0.0, g.max_coord[ax]);
                        (p as i32 as usize).min(g.max_cell[ax])
                    });
                    let same = g.blocks.iter().find_map(|b| {
                        let bc = cell.map(|c| c >> b.shift);
                        let i = bc[0] + b.counts[0] * (bc[1] + b.counts[1] * bc[2]);
                        (b.value[i] == value).then(|| next_sample_after_block(g, ray, bc, b.cells))
                    });
                    match same {
                        Some(after) if after > next => next = after,
                        _ => break,
                    }
                }
                let next = next.min(last as f32);
                let run = if n + 1 < last && next > (n + 1) as f32 {
                    next as u32 - n
                } else {
                    1
                };
                found = Some((run, value));
                break;
            }
        }
        if jumped {
            continue;
        }
        let (run, v) = found.unwrap_or_else(|| {
            let f: [f32; 3] = std::array::from_fn(|ax| pos[ax] - cell[ax] as f32);
            let base = cell[0] + g.stride[0] * cell[1] + g.stride[1] * cell[2];
            let (sx, sy, sz) = (g.step[0], g.step[1], g.step[2]);
            let d = g.data;
            let c00 = lerp(d[base], d[base + sx], f[0]);
            let c10 = lerp(d[base + sy], d[base + sy + sx], f[0]);
            let c01 = lerp(d[base + sz], d[base + sz + sx], f[0]);
            let c11 = lerp(d[base + sz + sy], d[base + sz + sy + sx], f[0]);
            (1, lerp(lerp(c00, c10, f[1]), lerp(c01, c11, f[1]), f[2]))
        });
        samples += 1;
        // Any NaN corner makes the sample NaN (0 · NaN is NaN): empty space.
        if v.is_nan() {
            n += 1;
            continue;
        }
        let x = v.clamp(0.0, 1.0) * lut_max;
        let j = (x as i32 as usize).min(lut_last_cell);
        let w = x - j as f32;
        let (e0, e1) = (lut[j], lut[j + 1]);
        let sigma = lerp(e0[0], e1[0], w);
        let delta_norm = dn * p.inv_l;
        let x = sigma * delta_norm;
        let mut count = run;
        let mut t_after = t * (-(run as f32) * x).exp();
        if run > 1 && t_after < p.stop_below {
            // Stop where sample-by-sample compositing would have: the first m with
            // T·e^(−m x) < threshold.
            let m = ((t / p.stop_below).ln() / x).floor() + 1.0;
            count = (m.max(1.0) as u32).min(run);
            t_after = t * (-(count as f32) * x).exp();
        }
        n += count;
        let weight = t - t_after;
        let rgb = [
            lerp(e0[1], e1[1], w),
            lerp(e0[2], e1[2], w),
            lerp(e0[3], e1[3], w),
        ];
        for c in 0..3 {
            acc[c] += weight * rgb[c];
        }
        visit(&Sample {
            lut_index: j,
            lut_weight: w,
            rgb,
            delta_norm,
            count: count as f32,
            t_before: t,
            t_after,
            acc,
        });
        t = t_after;
        if t < p.stop_below {
            break;
        }
    }
    Marched {
        acc,
        transmittance: t,
        samples,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::{Geometry, TypedBuffer, Volume};
    use std::path::Path;

    /// Stepping across a uniform brick in one go gives what sample-by-sample compositing gives,
    /// with and without early termination.
    #[test]
    fn uniform_bricks_match_sample_by_sample() {
        // 33³ points: 4³ bricks; values constant per 16-point octant, so most bricks are uniform.
        let dims = [33usize; 3];
        let vals = (0..33 * 33 * 33)
            .map(|i| {
                let (x, y, z) = (i % 33, (i / 33) % 33, i / (33 * 33));
                ((x / 17) + 2 * (y / 17) + 3 * (z / 17)) as f64 / 6.0
            })
            .collect();
        let g = Geometry {
            dims,
            spacing: [1.0; 3],
            origin: [0.0; 3],
        };
        let v = Volume::from_buffer(Path::new("t"), g, &TypedBuffer::from_f64(vals)).unwrap();
        let level = &v.levels[0];
        assert!(level.bricks.uniform.iter().filter(|&&u| u).count() >= 8);
        let lut = Lut {
            entries: (0..7)
                .map(|j| {
                    [
                        3.0 + 4.0 * j as f32,
                        0.1 * j as f32,
                        0.5,
                        1.0 - 0.1 * j as f32,
                    ]
                })
                .collect(),
        };
        let with = super::super::skip::blocks(level, &lut, false, 0.0, true);
        let without = super::super::skip::blocks(level, &lut, false, 0.0, false);
        for stop in [0.0, 0.05] {
            let params = |uniform: bool| MarchParams {
                grid: Grid::new(level, if uniform { &with } else { &without }),
                lut: &lut,
                inv_l: 1.0 / 32.0,
                stop_below: stop,
            };
            let (fast, slow) = (params(true), params(false));
            let mut saved = 0;
            for k in 0..50 {
                let a = k as f64 * 0.37;
                let dir = DVec3::new(a.cos(), a.sin(), 0.3 * (1.3 * a).cos()).normalize();
                let eye = DVec3::new(15.3, 13.7, 14.1) - 60.0 * dir;
                let frame = BoxFrame::new(eye, DVec3::ZERO, DVec3::ONE, dims, 0.5);
                let ray = frame.clip(dir, 0.3).unwrap();
                let (mut count_fast, mut count_slow) = (0.0, 0.0);
                let m1 = march(&fast, &ray, |s| count_fast += s.count);
                let m2 = march(&slow, &ray, |s| count_slow += s.count);
                saved += m2.samples - m1.samples;
                assert!(
                    (m1.transmittance - m2.transmittance).abs() < 1e-5,
                    "ray {k}"
                );
                for c in 0..3 {
                    assert!((m1.acc[c] - m2.acc[c]).abs() < 1e-5, "ray {k}");
                }
                assert_eq!(count_fast, count_slow, "ray {k} stop {stop}");
            }
            assert!(saved > 500, "uniform runs saved only {saved} samples");
        }
    }
}
