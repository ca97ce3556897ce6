//! One ray through one mip level: box clipping, trilinear sampling, LUT lookup and front-to-back
//! compositing. The forward and backward passes run the *same* march (same samples, same skips,
//! same early stop) and differ only in what they do per sample, so the backward is the exact
//! gradient of what the forward computed. A forward may record each composited sample's value
//! ([`Step`]); [`replay`] composites those again, giving the backward the same samples
//! without the block walk and the interpolation.

use std::ops::ControlFlow;

use glam::DVec3;

use super::bricked::BrickValues;
use super::fastmath::ceil;
use super::sample::{
    brick_of_cell, cell, classify, trilinear, Chunk, Classified, Grid, InPlace, MarchParams, Ray,
    Slots, Table, Voxel, CHUNK,
};
use super::simd;
use super::skip::Blocks;
use t2tf_core::math::fast_exp;
use t2tf_volume::BRICK_CELLS;

/// One view's box in a level's index space, with what every ray's clipping shares.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BoxFrame {
    /// The eye in index coordinates.
    eye: DVec3,
    inv_spacing: DVec3,
    /// The box is [lo, hi] per axis: [0, dims − 1], except that an axis with one point is a
    /// slab one spacing thick, [−½, ½] (a 1 × 64 × 64 image would otherwise have no
    /// thickness and show nothing; its samples all read that one point, as the clamped
    /// trilinear lookup gives).
    lo: DVec3,
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
            lo: DVec3::from_array(dims.map(|d| if d == 1 { -0.5 } else { 0.0 })),
            hi: DVec3::from_array(dims.map(|d| if d == 1 { 0.5 } else { (d - 1) as f64 })),
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
                if a[ax] < self.lo[ax] || a[ax] > self.hi[ax] {
                    return None;
                }
                continue;
            }
            let (ta, tb) = (
                (self.lo[ax] - a[ax]) * inv_b[ax],
                (self.hi[ax] - a[ax]) * inv_b[ax],
            );
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
            bd: (b * self.delta).as_vec3().to_array(),
            inv_bd: std::array::from_fn(|ax| {
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

/// What the per-sample visitor sees (only non-empty samples are visited): the compositor's
/// view of a sample, with the transmittance and colour the backward needs beyond what the
/// sampler gives (`sample::Classified`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    /// LUT entry below the sample and the weight of the entry above.
    pub(crate) lut_index: usize,
    pub(crate) lut_weight: f32,
    pub(crate) rgb: [f32; 3],
    /// Segment length in normalized units (δ / L).
    pub(crate) delta_norm: f32,
    /// How many identical consecutive samples this stands for (> 1 across a uniform brick,
    /// where the per-sample terms of the backward are equal and are summed in one go).
    pub(crate) count: f32,
    /// Transmittance before and after the sample.
    pub(crate) t_before: f32,
    pub(crate) t_after: f32,
    /// Colour accumulated up to and including this sample (no background).
    pub(crate) acc: [f32; 3],
    /// The scalar value, and how many samples of it the march asked to composite (before
    /// early termination cut the run): with `delta_norm`, what [`replay`] needs to composite
    /// the sample again.
    pub(crate) value: f32,
    pub(crate) run: u32,
}

/// Result of one march.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Marched {
    pub(crate) acc: [f32; 3],
    pub(crate) transmittance: f32,
    /// Samples whose scalar was interpolated (skipped ones excluded).
    pub(crate) samples: u32,
}

/// Work found by the block walk and not yet composited. Consecutive blocks of one kind are
/// merged first: uniform runs of equal value cost one `exp`, and sample ranges get long enough
/// for [`Compositor::samples`] to keep a chunk full (a brick holds only ~5 samples of a ray).
#[derive(Clone, Copy)]
enum Pending {
    None,
    /// `count` samples from `start` on, all of value `value`.
    Uniform {
        value: f32,
        start: u32,
        count: u32,
    },
    /// Samples `n0..n1`, to be interpolated.
    Samples {
        n0: u32,
        n1: u32,
    },
}

/// Where a ray is in its front-to-back compositing.
struct Compositor<'a, 'p, T, S, F> {
    p: &'p MarchParams<'a>,
    /// The grid's values and where each brick is in them.
    data: (&'p [T], S),
    ray: &'p Ray,
    visit: F,
    /// A full segment's length in normalized units (δ / L).
    delta_norm: f32,
    t: f32,
    acc: [f32; 3],
    samples: u32,
    pending: Pending,
}

impl<'a, 'p, T, S, F> Compositor<'a, 'p, T, S, F> {
    /// A ray at its start: nothing composited, full transmittance.
    #[inline]
    fn start(p: &'p MarchParams<'a>, data: (&'p [T], S), ray: &'p Ray, visit: F) -> Self {
        Compositor {
            p,
            data,
            ray,
            visit,
            delta_norm: ray.delta * p.inv_l,
            t: 1.0,
            acc: [0.0; 3],
            samples: 0,
            pending: Pending::None,
        }
    }
}

impl<T: Voxel, S: Slots, F: FnMut(&Sample)> Compositor<'_, '_, T, S, F> {
    /// Composite `count` consecutive samples of value `v` (a NaN value is empty space), each of
    /// normalized length `delta_norm`. Breaks once the ray is saturated.
    #[inline(always)]
    fn shade(&mut self, v: f32, count: u32, delta_norm: f32) -> ControlFlow<()> {
        let k = classify(&self.p.lut.entries, v, delta_norm);
        self.composite(k, v, count, delta_norm)
    }

    /// Composite `count` samples of value `v` and class `k` (`None`: empty).
    #[inline(always)]
    fn composite(
        &mut self,
        k: Option<Classified>,
        v: f32,
        count: u32,
        delta_norm: f32,
    ) -> ControlFlow<()> {
        self.samples += 1;
        let Some(k) = k else {
            return ControlFlow::Continue(());
        };
        let t = self.t;
        let stop = self.p.stop_below;
        let run = count;
        let mut count = count;
        let mut t_after = t * k.ext;
        if count > 1 {
            t_after = t * fast_exp(-(count as f32) * k.tau);
            if t_after < stop {
                // Stop where sample-by-sample compositing would have: the first m with
                // T·e^(−m τ) < threshold.
                let m = ((t / stop).ln() / k.tau).floor() + 1.0;
                count = (m.max(1.0) as u32).min(count);
                t_after = t * fast_exp(-(count as f32) * k.tau);
            }
        }
        let weight = t - t_after;
        for c in 0..3 {
            self.acc[c] += weight * k.rgb[c];
        }
        (self.visit)(&Sample {
            lut_index: k.j as usize,
            lut_weight: k.w,
            rgb: k.rgb,
            delta_norm,
            count: count as f32,
            t_before: t,
            t_after,
            acc: self.acc,
            value: v,
            run,
        });
        self.t = t_after;
        if t_after < stop {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }

    /// Samples `n0..n1` all have value `v` (a uniform block).
    #[inline(always)]
    fn uniform(&mut self, v: f32, n0: u32, n1: u32) -> ControlFlow<()> {
        if let Pending::Uniform {
            value,
            start,
            count,
        } = &mut self.pending
        {
            if *value == v && *start + *count == n0 {
                *count += n1 - n0;
                return ControlFlow::Continue(());
            }
        }
        self.flush()?;
        self.pending = Pending::Uniform {
            value: v,
            start: n0,
            count: n1 - n0,
        };
        ControlFlow::Continue(())
    }

    /// Samples `n0..n1` must be interpolated.
    #[inline(always)]
    fn interpolated(&mut self, n0: u32, n1: u32) -> ControlFlow<()> {
        if let Pending::Samples { n1: end, .. } = &mut self.pending {
            if *end == n0 {
                *end = n1;
                return ControlFlow::Continue(());
            }
        }
        self.flush()?;
        self.pending = Pending::Samples { n0, n1 };
        ControlFlow::Continue(())
    }

    /// Composite the pending work, if any.
    #[inline(always)]
    fn flush(&mut self) -> ControlFlow<()> {
        match std::mem::replace(&mut self.pending, Pending::None) {
            Pending::None => ControlFlow::Continue(()),
            Pending::Uniform { value, count, .. } => self.shade(value, count, self.delta_norm),
            Pending::Samples { n0, n1 } => self.samples(n0, n1),
        }
    }

    /// Interpolate and composite samples `n0..n1`. In chunks of [`CHUNK`]: first every sample
    /// of the chunk is interpolated and classified (independent of each other: AVX2 does 8 at
    /// once, and even in scalar code their loads overlap), then the chunk is composited, where
    /// the transmittance is a serial chain. A chunk past `n1` interpolates clamped positions
    /// that are never composited, and a ray that stops mid-chunk has interpolated at most
    /// CHUNK − 1 samples too many.
    #[inline(always)]
    fn samples(&mut self, n0: u32, n1: u32) -> ControlFlow<()> {
        let (p, ray, dn) = (self.p, self.ray, self.delta_norm);
        let mut k = Chunk::default();
        let mut n = n0;
        while n < n1 {
            simd::interpolate_classify(p, self.data, ray, n, dn, &mut k);
            for i in 0..((n1 - n) as usize).min(CHUNK) {
                self.composite(k.get(i), k.v[i], 1, dn)?;
            }
            n += CHUNK as u32;
        }
        ControlFlow::Continue(())
    }
}

/// Walk the blocks of `blocks` that the ray crosses between sample coordinates `u0` and `u1`
/// (u = s / δ: sample n sits at u = n + jitter), front to back, calling `f(block, u_in,
/// u_out)` for each. Block coordinates stay within `lo..=hi` (a parent block's children, or
/// the whole level), which also settles a start exactly on a boundary.
#[inline(always)]
fn walk(
    g: &Grid,
    blocks: &Blocks,
    ray: &Ray,
    (u0, u1): (f32, f32),
    (lo, hi): ([usize; 3], [usize; 3]),
    mut f: impl FnMut(usize, [usize; 3], f32, f32) -> ControlFlow<()>,
) -> ControlFlow<()> {
    let cells = blocks.cells as f32;
    // The block holding the point just inside the interval.
    let um = u0 + (u1 - u0).min(1e-3);
    let block = |ax: usize| {
        let c = cell(g, ray.a[ax] + um * ray.bd[ax], ax) as usize;
        (c >> blocks.shift).max(lo[ax]).min(hi[ax])
    };
    let mut bc = [block(0), block(1), block(2)];
    // Per axis: the index-space boundary the ray leaves the block through, and its u.
    let mut bound = [0.0f32; 3];
    let mut u_exit = [f32::INFINITY; 3];
    for ax in 0..3 {
        if g.max_coord[ax] == 0.0 {
            // One point on this axis: one block, never left through this axis (the slab
            // around the point reaches below coordinate 0).
            continue;
        }
        if ray.bd[ax] > 0.0 {
            bound[ax] = (bc[ax] + 1) as f32 * cells;
        } else if ray.bd[ax] < 0.0 {
            bound[ax] = bc[ax] as f32 * cells;
        } else {
            continue;
        }
        u_exit[ax] = (bound[ax] - ray.a[ax]) * ray.inv_bd[ax];
    }
    let mut u = u0;
    loop {
        let ax = if u_exit[0] <= u_exit[1] {
            if u_exit[0] <= u_exit[2] {
                0
            } else {
                2
            }
        } else if u_exit[1] <= u_exit[2] {
            1
        } else {
            2
        };
        let out = u_exit[ax].max(u).min(u1);
        let i = bc[0] + blocks.counts[0] * (bc[1] + blocks.counts[1] * bc[2]);
        f(i, bc, u, out)?;
        if out >= u1 {
            return ControlFlow::Continue(());
        }
        u = out;
        if ray.bd[ax] > 0.0 {
            if bc[ax] == hi[ax] {
                return ControlFlow::Continue(());
            }
            bc[ax] += 1;
            bound[ax] += cells;
        } else {
            if bc[ax] == lo[ax] {
                return ControlFlow::Continue(());
            }
            bc[ax] -= 1;
            bound[ax] -= cells;
        }
        u_exit[ax] = (bound[ax] - ray.a[ax]) * ray.inv_bd[ax];
    }
}

/// What the block walk finds on a ray's samples 0 … N − 2, front to back.
#[derive(Clone, Copy)]
enum Work {
    /// Samples `n0..n1` all have this value (a uniform block).
    Uniform(f32, u32, u32),
    /// Samples `n0..n1` must be interpolated.
    Samples(u32, u32),
}

/// Walk the blocks `ray` crosses, calling `f` with the [`Work`] of each block that is not
/// empty: a walk over the super-blocks, and inside each one that is neither empty nor uniform
/// a walk over its bricks. Shared by the march and by [`bricks_touched`], so a brick cache
/// loads exactly the blocks the march will sample.
#[inline(always)]
fn walk_blocks(g: &Grid, ray: &Ray, mut f: impl FnMut(Work) -> ControlFlow<()>) -> ControlFlow<()> {
    let [supers, bricks] = g.blocks;
    let last = ray.segments - 1;
    let jit = ray.jitter;
    // Sample n lies in [u_in, u_out) when n ∈ [⌈u_in − jitter⌉, ⌈u_out − jitter⌉).
    let first_at = |u: f32| (ceil(u - jit).max(0.0) as u32).min(last);
    let whole = |ax: usize| supers.counts[ax] - 1;
    let per_super = supers.cells / bricks.cells;
    walk(
        g,
        supers,
        ray,
        (0.0, last as f32 + jit),
        ([0; 3], [whole(0), whole(1), whole(2)]),
        |s, sc, u_in, u_out| {
            let (n0, n1) = (first_at(u_in), first_at(u_out));
            if n0 >= n1 || supers.empty[s] {
                return ControlFlow::Continue(());
            }
            if !supers.value[s].is_nan() {
                return f(Work::Uniform(supers.value[s], n0, n1));
            }
            let lo = [sc[0] * per_super, sc[1] * per_super, sc[2] * per_super];
            let hi_of = |ax: usize| (lo[ax] + per_super - 1).min(bricks.counts[ax] - 1);
            let hi = [hi_of(0), hi_of(1), hi_of(2)];
            walk(
                g,
                bricks,
                ray,
                (u_in, u_out),
                (lo, hi),
                // The super-block step's tests, one level finer.
                |b, _, u_in, u_out| {
                    let (n0, n1) = (first_at(u_in), first_at(u_out));
                    if n0 >= n1 || bricks.empty[b] {
                        return ControlFlow::Continue(());
                    }
                    if !bricks.value[b].is_nan() {
                        return f(Work::Uniform(bricks.value[b], n0, n1));
                    }
                    f(Work::Samples(n0, n1))
                },
            )
        },
    )
}

/// The last segment's sample: its index-space position and its brick. It sits at
/// jitter · δ_last into the segment.
#[inline(always)]
fn last_sample(g: &Grid, ray: &Ray) -> ([f32; 3], usize) {
    let u = (ray.segments - 1) as f32 + ray.jitter * ray.delta_last / ray.delta;
    let (a, bd) = (ray.a, ray.bd);
    let pos = [a[0] + u * bd[0], a[1] + u * bd[1], a[2] + u * bd[2]];
    let c = [cell(g, pos[0], 0), cell(g, pos[1], 1), cell(g, pos[2], 2)];
    (pos, brick_of_cell(g.brick_stride, c))
}

/// Call `f` with every brick whose values the march of `ray` may read (a superset: early
/// termination is not foreseen), possibly more than once. Sample n's cell on each axis comes
/// from a + u·b with u = n + jitter, rounded as the samplers round it; rounding is monotonic,
/// so the cells of samples n0 … n1 − 1 lie between those of the first and the last, and the
/// bricks between theirs hold them all (one brick, or two along an axis when a sample sits on
/// a brick face). Chunks read up to 7 samples past a run's end and discard them: those reads
/// may find bricks not loaded, which a cache maps to its zero slot.
pub(crate) fn bricks_touched(g: &Grid, ray: &Ray, mut f: impl FnMut(usize)) {
    let cells = |n: u32| {
        let u = n as f32 + ray.jitter;
        std::array::from_fn::<u32, 3, _>(|ax| cell(g, ray.a[ax] + u * ray.bd[ax], ax))
    };
    let _ = walk_blocks(g, ray, |w| {
        if let Work::Samples(n0, n1) = w {
            let (c0, c1) = (cells(n0), cells(n1 - 1));
            let lo: [u32; 3] = std::array::from_fn(|ax| c0[ax].min(c1[ax]));
            let hi: [u32; 3] = std::array::from_fn(|ax| c0[ax].max(c1[ax]));
            let step = BRICK_CELLS as u32;
            for z in (lo[2] / step)..=(hi[2] / step) {
                for y in (lo[1] / step)..=(hi[1] / step) {
                    for x in (lo[0] / step)..=(hi[0] / step) {
                        f(brick_of_cell(g.brick_stride, [x, y, z].map(|b| b * step)));
                    }
                }
            }
        }
        ControlFlow::Continue(())
    });
    let (_, b) = last_sample(g, ray);
    let bricks = &g.blocks[1];
    if !bricks.empty[b] && bricks.value[b].is_nan() {
        f(b);
    }
}

/// March `ray` front to back, calling `visit` after each non-empty sample.
///
/// Samples 0 … N − 2 are found block by block ([`walk_blocks`]). An empty block's samples are
/// skipped (sample positions do not move, so this only drops samples that are empty anyway); a
/// uniform block's samples are all its value, exactly (a + w·0), and are composited in one
/// step; the others, merged across consecutive blocks, are interpolated in chunks
/// ([`Compositor::samples`]) without further checks. The last, shorter segment's sample is
/// taken on its own.
///
/// With `p.simd` the whole march is compiled for AVX2 (the scalar parts too: VEX encoding,
/// `roundss` for the block boundaries' ceilings), through a `target_feature` copy. A brick
/// cache's grid (`slots`) is marched by its own copies, with one slot lookup per sample.
#[inline(always)]
pub(crate) fn march<F: FnMut(&Sample)>(p: &MarchParams, ray: &Ray, visit: F) -> Marched {
    match (p.grid.values, p.grid.slots) {
        (BrickValues::U8(d), None) => march_typed(p, (d, InPlace), ray, visit),
        (BrickValues::U16(d), None) => march_typed(p, (d, InPlace), ray, visit),
        (BrickValues::F32(d), None) => march_typed(p, (d, InPlace), ray, visit),
        (BrickValues::U8(d), Some(t)) => march_typed(p, (d, Table(t)), ray, visit),
        (BrickValues::U16(d), Some(t)) => march_typed(p, (d, Table(t)), ray, visit),
        (BrickValues::F32(d), Some(t)) => march_typed(p, (d, Table(t)), ray, visit),
    }
}

#[inline(always)]
fn march_typed<T: Voxel, S: Slots, F: FnMut(&Sample)>(
    p: &MarchParams,
    d: (&[T], S),
    ray: &Ray,
    visit: F,
) -> Marched {
    #[cfg(target_arch = "x86_64")]
    if p.simd {
        // SAFETY: `simd` is set only where `simd::available()` found AVX2 on this CPU.
        return unsafe { march_avx2(p, d, ray, visit) };
    }
    march_body(p, d, ray, visit)
}

/// `march_body` compiled with AVX2 enabled, so the chunk interpolator it inlines uses AVX2
/// gathers.
///
/// # Safety
/// The CPU must support AVX2 (`simd::available()`); calling it elsewhere is undefined
/// behaviour (an illegal instruction at best).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn march_avx2<T: Voxel, S: Slots, F: FnMut(&Sample)>(
    p: &MarchParams,
    d: (&[T], S),
    ray: &Ray,
    visit: F,
) -> Marched {
    march_body(p, d, ray, visit)
}

#[inline(always)]
fn march_body<T: Voxel, S: Slots, F: FnMut(&Sample)>(
    p: &MarchParams,
    d: (&[T], S),
    ray: &Ray,
    visit: F,
) -> Marched {
    let g = &p.grid;
    let mut c = Compositor::start(p, d, ray, visit);
    let done = walk_blocks(g, ray, |w| match w {
        Work::Uniform(v, n0, n1) => c.uniform(v, n0, n1),
        Work::Samples(n0, n1) => c.interpolated(n0, n1),
    });
    if done.is_continue() && c.flush().is_continue() {
        let ([x, y, z], b) = last_sample(g, ray);
        let bricks = &g.blocks[1];
        if !bricks.empty[b] {
            // A uniform brick's value is what interpolation would give, without the load (this
            // sample sits on the box's far face, rarely in cache).
            let v = match bricks.value[b] {
                v if v.is_nan() => trilinear(g, d, x, y, z),
                v => v,
            };
            let _ = c.shade(v, 1, ray.delta_last * p.inv_l);
        }
    }
    Marched {
        acc: c.acc,
        transmittance: c.t,
        samples: c.samples,
    }
}

/// One composited sample of a recorded march (`Sample::value` and `Sample::run`); `run` has
/// [`Step::LAST`] set for the last, shorter segment's sample.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Step {
    pub(crate) value: f32,
    pub(crate) run: u32,
}

impl Step {
    /// The flag of the last segment's sample in `run` (a run never has 2³¹ samples: a ray
    /// has at most `u32::MAX` segments, and a last sample stands for one).
    pub(crate) const LAST: u32 = 1 << 31;

    /// What a march's visitor records of `s` on `ray`.
    #[inline(always)]
    pub(crate) fn of(s: &Sample, full_delta_norm: f32) -> Step {
        let last = if s.delta_norm == full_delta_norm {
            0
        } else {
            Step::LAST
        };
        Step {
            value: s.value,
            run: s.run | last,
        }
    }
}

/// Composite `steps` (recorded by a march with the same parameters of a ray whose segments
/// are `delta` long, the last `delta_last`) again, calling `visit` after each, as that march
/// did: the same classification and compositing, hence the same [`Sample`]s bit for bit (the
/// AVX2 classifier gives the scalar one's bits), without the ray, the block walk or the
/// interpolation.
#[inline(always)]
pub(crate) fn replay<F: FnMut(&Sample)>(
    p: &MarchParams,
    (delta, delta_last): (f32, f32),
    steps: &[Step],
    visit: F,
) -> Marched {
    let none: &[u8] = &[];
    // Only the segment lengths are read: steps are never interpolated.
    let ray = &Ray {
        a: [0.0; 3],
        bd: [0.0; 3],
        inv_bd: [0.0; 3],
        segments: 1,
        delta,
        delta_last,
        jitter: 0.5,
    };
    let mut c = Compositor::start(p, (none, InPlace), ray, visit);
    let last_dn = ray.delta_last * p.inv_l;
    for s in steps {
        let (dn, run) = if s.run & Step::LAST != 0 {
            (last_dn, s.run & !Step::LAST)
        } else {
            (c.delta_norm, s.run)
        };
        if c.shade(s.value, run, dn).is_break() {
            break;
        }
    }
    Marched {
        acc: c.acc,
        transmittance: c.t,
        samples: c.samples,
    }
}

#[cfg(test)]
mod tests {
    use super::super::CpuBackend;
    use super::*;
    use crate::backend::Backend;
    use std::path::Path;
    use t2tf_tf::Lut;
    use t2tf_volume::{Geometry, TypedBuffer, Volume};

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
        let prepared = CpuBackend::default().prepare(&v, 0).unwrap();
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
        let with = super::super::skip::blocks(&level.bricks, &lut, false, 0.0, true);
        let without = super::super::skip::blocks(&level.bricks, &lut, false, 0.0, false);
        for stop in [0.0, 0.05] {
            // Built like simd.rs's test parameters: both tests vary one field of the same struct.
            let params = |uniform: bool| MarchParams {
                grid: Grid::new(
                    dims,
                    super::super::tests::whole(&prepared),
                    None,
                    if uniform { &with } else { &without },
                ),
                lut: &lut,
                inv_l: 1.0 / 32.0,
                stop_below: stop,
                simd: false,
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
