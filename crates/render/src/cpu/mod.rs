//! The CPU backend: each prepared level is a bricked copy (`bricked.rs`) with its brick
//! ranges; a view builds the empty/uniform block tables for its LUT (`skip.rs`) and marches
//! every ray (`march.rs`, sampling in `sample.rs`, 8 samples at a time with AVX2 in
//! `simd.rs`) in parallel 16 × 16 tiles. Shots cast below the output size are upsampled here
//! (and the gradient taken through the upsampling's transpose).
//!
//! Imports run one way: `render::backend` (the [`Backend`] trait) ← `render::cpu` ← the
//! `render` facade; inside, `sample` is used by `march` and `simd`, `simd` by `march`, and
//! none of them imports the others back.
//!
//! **Levels larger than memory.** A level's whole bricked copy is built when it fits the
//! backend's memory budget ([`CpuBackend::new`]), slab by slab from
//! `Level::read_box` (no f32 copy of the level is made for it). Otherwise the level gets a
//! brick cache (`cache.rs`: an LRU arena of at most half the budget and 1 GiB, loaded per
//! batch of tiles); the march reaches bricks through a slot table there, and is compiled
//! separately for the whole copy, whose path is unchanged. Both give bit-identical results.
//!
//! **The backend's backward replays its forward.** [`Backend::forward`] records, per tile,
//! each composited sample's value and run length (8 bytes a step, a few MiB for a 224² view,
//! at most `RECORD_STEPS` per view); [`Backend::backward`] composites them again
//! (`march::replay`) instead of walking blocks and interpolating: the same samples, so the
//! same gradient bit for bit, in about half the time of a second march. The front functions
//! (`render::backward`, `render::backward_from`) and tiles past the budget march again.
//!
//! **Prepared levels are cached** per level allocation (`volume::Level` shares its samples in
//! an `Arc` that never changes): preparing the same level again — every view of an
//! optimization — costs a lookup. An entry is dropped at the next `prepare` after its level's
//! samples are freed, so a dropped volume's copies do not outlive the next render by much.

mod bricked;
mod cache;
mod fastmath;
mod march;
mod sample;
mod simd;
mod skip;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, Weak};

use glam::DVec3;
use rayon::prelude::*;

use super::backend::{validate, Backend, RenderError, RenderOptions, Rendered, Shot};
use crate::camera::Camera;
use t2tf_core::image::{resize_bilinear, resize_bilinear_adjoint, Image};
use t2tf_core::memory::Budget;
use t2tf_tf::{Lut, LutGrad};
use t2tf_volume::{BrickGrid, Level, Volume, BRICK_CELLS};

pub use bricked::BrickValues;
use bricked::{read_box, BrickedData, Encoding, BRICK_POINTS, BRICK_VALUES, PAD};
use cache::BrickCache;
pub use cache::CacheStats;
use march::{bricks_touched, march, replay, BoxFrame, Step};
use sample::{Grid, MarchParams, Ray};
use skip::Blocks;

/// Tile side in pixels (parallel work unit and gradient reduction unit).
const TILE: usize = 16;

/// Most recorded steps a forward keeps for its backward ([`CpuTape`]), over all its tiles: 8
/// bytes each, so 32 MiB. A 224² view of the optimizer needs a few MiB; tiles past the
/// budget (a fine step, a large final render) are marched again by the backward.
const RECORD_STEPS: usize = 1 << 22;

/// The CPU renderer (rayon threads, AVX2 where the CPU has it), with the memory budget its
/// copies of levels are built within and its cache of the levels it prepared.
#[derive(Debug, Default)]
pub struct CpuBackend {
    budget: Budget,
    /// Every level prepared so far whose samples still exist.
    levels: Mutex<Vec<CacheEntry>>,
}

impl CpuBackend {
    /// A renderer whose copies of levels fit `budget`.
    pub fn new(budget: Budget) -> CpuBackend {
        CpuBackend {
            budget,
            levels: Mutex::new(Vec::new()),
        }
    }

    /// The budget its copies of levels are built within.
    pub fn budget(&self) -> Budget {
        self.budget
    }
}

/// Largest brick cache a level gets when its bricked copy does not fit the memory budget: a
/// final render is bound by reading bricks, not by how many stay resident (a view of a level
/// larger than memory touches more bricks than any cache holds, and a batch of tiles needs
/// far less than this), and the rest of the budget is left to the process. 1 GiB keeps a
/// 2048³ `t2tf optimize` (whose preview renders level 0) under 3 GiB (BENCHMARKS.md).
const BRICK_CACHE_MAX: u64 = 1 << 30;

/// Largest whole copy made of a level whose samples the volume holds (`Level::is_materialized`,
/// a coarse level the load kept: a 512³ level 1 of a 1024³ volume is 256 MiB in 16 bits, its
/// whole copy 364 MiB). Above it the level gets a brick cache, which reads bricks from those
/// samples as views sample them: the same images and gradients bit for bit, no second copy of
/// the level, a forward as fast and a backward that replays the forward's record as a whole
/// copy's does (BENCHMARKS.md, "Memory of a default run": the 1 GiB volume).
const HELD_WHOLE_MAX: u64 = 128 << 20;

/// A level in the renderer's layout: what the cache holds. `dims` and `grid` are those the
/// bricks were built from, so the march's unchecked indexing always agrees with the data.
struct CpuLevel {
    dims: [usize; 3],
    grid: BrickGrid,
    store: Store,
}

/// Where a prepared level's bricks are.
enum Store {
    /// All of them, in memory (`bricked.rs`).
    Whole(BrickedData),
    /// Loaded on demand into a bounded arena (`cache.rs`).
    Cache(Box<BrickCache>),
}

/// A mip level of a volume, prepared for the CPU backend.
#[derive(Clone)]
pub struct CpuPrepared {
    level: usize,
    spacing: [f64; 3],
    origin: [f64; 3],
    /// 1 / L (L = the box's longest side, docs/DESIGN.md density units).
    inv_l: f32,
    data: Arc<CpuLevel>,
}

impl CpuPrepared {
    /// Which mip level this is.
    pub fn level(&self) -> usize {
        self.level
    }

    /// The stored values (8, 16 or 32 bits per point; `bricked.rs`). A brick cache's bricks
    /// come and go: for it, the kind with no values.
    pub fn values(&self) -> BrickValues<'_> {
        match &self.data.store {
            Store::Whole(b) => b.values(),
            Store::Cache(c) => c.kind(),
        }
    }

    /// Bytes held by the bricked copy, or by the brick cache's arena and tables.
    pub fn memory_bytes(&self) -> usize {
        match &self.data.store {
            Store::Whole(b) => b.memory_bytes(),
            Store::Cache(c) => c.stats().bytes as usize,
        }
    }

    /// What the brick cache holds and has done; `None` for a level held whole in memory.
    pub fn cache_stats(&self) -> Option<CacheStats> {
        match &self.data.store {
            Store::Whole(_) => None,
            Store::Cache(c) => Some(c.stats()),
        }
    }
}

impl std::fmt::Debug for CpuPrepared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let store = match &self.data.store {
            Store::Whole(b) => format!("{b:?}"),
            Store::Cache(c) => format!("{:?}", c.stats()),
        };
        write!(
            f,
            "CpuPrepared(level {}, {:?} points, {store})",
            self.level, self.data.dims
        )
    }
}

/// Bytes of the whole bricked copy of a level with `counts` bricks stored as `encoding`.
fn whole_bytes(counts: [usize; 3], encoding: Encoding) -> u64 {
    let values = counts.iter().product::<usize>() as u64 * BRICK_VALUES as u64 + PAD as u64;
    values.saturating_mul(encoding.bytes() as u64)
}

/// `level` in the renderer's layout: the whole bricked copy when it takes at most `budget`
/// bytes and, for a level whose samples are held, at most `held_max` bytes; else a brick cache
/// of at most `cache_budget` bytes.
fn build(
    level: &Level,
    budget: u64,
    cache_budget: u64,
    held_max: u64,
) -> Result<CpuLevel, RenderError> {
    let dims = level.dims;
    // The level's own ranges when they are those of its dims (always, unless a caller
    // changed the public fields); rebuilt otherwise, since the march trusts them.
    let counts = dims.map(|d| d.saturating_sub(1).max(1).div_ceil(BRICK_CELLS));
    let grid = if level.bricks.counts == counts
        && level.bricks.min.len() == counts.iter().product::<usize>()
    {
        level.bricks.clone()
    } else {
        BrickGrid::build(dims, level.try_data().map_err(RenderError::Source)?)
    };
    let encoding = Encoding::of(level.narrow());
    // The whole copy is built from one f32 slab of a brick layer per thread at a time: that
    // room is needed beside the copy (under an address-space limit nothing else is spare).
    let slabs = rayon::current_num_threads() as u64
        * (BRICK_POINTS * dims[0] * dims[1]) as u64
        * std::mem::size_of::<f32>() as u64;
    let whole = whole_bytes(counts, encoding);
    // A level the volume holds already (a coarse level kept by the load) is read from its
    // samples; a whole copy beside it would hold the level twice.
    let duplicate = level.is_materialized() && whole > held_max;
    let store = if whole.saturating_add(slabs) <= budget && !duplicate {
        // Each read is a slab of bricks; the mapped file's pages it touched are released
        // behind it (`Level::release_source`), so a level read from a memory-mapped file adds
        // its bricked copy to the process's memory, not the file.
        let read = |lo, hi, out: &mut [f32]| {
            let read = read_box(level, lo, hi, out);
            level.release_source();
            read
        };
        Store::Whole(BrickedData::build(dims, &grid, level.narrow(), &read)?)
    } else {
        Store::Cache(Box::new(BrickCache::new(
            level,
            counts,
            encoding,
            cache_budget,
        )?))
    };
    Ok(CpuLevel { dims, grid, store })
}

/// One cached level: its samples' cell (dead once the level is dropped) and the copy, built
/// under the entry's own lock.
struct CacheEntry {
    /// `Level::cell`, type-erased (only its identity matters).
    key: Weak<dyn std::any::Any + Send + Sync>,
    level: Arc<Mutex<Option<Arc<CpuLevel>>>>,
}

impl std::fmt::Debug for CacheEntry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CacheEntry")
            .field("alive", &(self.key.strong_count() > 0))
            .finish()
    }
}

/// The prepared copy of `level`, built on first use (whole, or a brick cache when the whole
/// copy does not fit the backend's budget). The backend's lock is held only to find or add
/// the entry; the build runs under the entry's own lock, so views of one level wait for one
/// build instead of each making a copy.
fn cached(backend: &CpuBackend, level: &Level) -> Result<Arc<CpuLevel>, RenderError> {
    let shared = level.cell();
    let slot = {
        // A panic elsewhere while the lock was held leaves the list itself consistent.
        let mut cache = backend.levels.lock().unwrap_or_else(|e| e.into_inner());
        cache.retain(|e| e.key.strong_count() > 0);
        match cache
            .iter()
            .find(|e| std::ptr::addr_eq(e.key.as_ptr(), Arc::as_ptr(shared)))
        {
            Some(e) => e.level.clone(),
            None => {
                let slot = Arc::new(Mutex::new(None));
                cache.push(CacheEntry {
                    key: Arc::downgrade(shared) as Weak<dyn std::any::Any + Send + Sync>,
                    level: slot.clone(),
                });
                slot
            }
        }
    };
    // A build that panicked left `None`: the next view builds again.
    let mut entry = slot.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(l) = entry.as_ref() {
        return Ok(l.clone());
    }
    let budget = backend.budget.available();
    let cache_budget = (budget / 2).min(BRICK_CACHE_MAX);
    let built = Arc::new(build(level, budget, cache_budget, HELD_WHOLE_MAX)?);
    *entry = Some(built.clone());
    Ok(built)
}

impl CpuBackend {
    /// Prepare level `level` of `volume` within `budget` bytes: its whole bricked copy when
    /// that fits with the f32 slabs it is built from (one per thread), else a brick cache of
    /// at most `budget` bytes (arena and tables). Not shared with [`Backend::prepare`]'s
    /// cache of levels, whose budget is the backend's, and a whole copy even of a large level
    /// the volume holds (which `prepare` reads through a brick cache).
    pub fn prepare_within(
        &self,
        volume: &Volume,
        level: usize,
        budget: u64,
    ) -> Result<CpuPrepared, RenderError> {
        let l = level_of(volume, level)?;
        Ok(prepared(
            volume,
            level,
            Arc::new(build(l, budget, budget, u64::MAX)?),
        ))
    }
}

/// Level `level` of `volume`, or the error naming the levels there are.
fn level_of(volume: &Volume, level: usize) -> Result<&Level, RenderError> {
    volume.levels.get(level).ok_or(RenderError::Level {
        level,
        max: volume.levels.len() - 1,
    })
}

/// A prepared level from its copy.
fn prepared(volume: &Volume, level: usize, data: Arc<CpuLevel>) -> CpuPrepared {
    CpuPrepared {
        level,
        spacing: volume.levels[level].spacing,
        origin: volume.geometry.origin,
        inv_l: (1.0 / volume.geometry.longest_side()) as f32,
        data,
    }
}

impl Backend for CpuBackend {
    type Prepared = CpuPrepared;
    /// The forward's colour and T_N at the cast size (over black when upsampled), and what
    /// each ray composited.
    type Tape = CpuTape;

    fn prepare(&self, volume: &Volume, level: usize) -> Result<CpuPrepared, RenderError> {
        let l = level_of(volume, level)?;
        Ok(prepared(volume, level, cached(self, l)?))
    }

    fn forward(
        &self,
        prepared: &CpuPrepared,
        lut: &Lut,
        shot: &Shot,
    ) -> Result<(Rendered, CpuTape), RenderError> {
        let (camera, bg, opts) = (shot.camera, shot.background, shot.options);
        if !shot.upsampled() {
            let (r, tiles) = forward_recorded(prepared, lut, camera, bg, opts, true)?;
            let tape = CpuTape {
                rendered: r.clone(),
                tiles,
            };
            return Ok((r, tape));
        }
        // Colour over black is the accumulated colour alone: I = up(acc) + up(T) · B.
        let (s, n) = (shot.cast, (bg.width, bg.height));
        if s.0 == 0 || s.1 == 0 {
            return Err(RenderError::EmptyImage {
                got_w: s.0,
                got_h: s.1,
            });
        }
        let (r, tiles) =
            forward_recorded(prepared, lut, camera, &Image::new(s.0, s.1), opts, true)?;
        let acc = resize_bilinear(&r.image.data, s, 3, n);
        let t = resize_bilinear(&r.transmittance, s, 1, n);
        let mut image = Image::new(n.0, n.1);
        for (p, px) in image.data.chunks_exact_mut(3).enumerate() {
            for c in 0..3 {
                px[c] = acc[3 * p + c] + t[p] * bg.data[3 * p + c];
            }
        }
        let full = Rendered {
            image,
            transmittance: t,
            level: r.level,
            samples: r.samples,
        };
        Ok((full, CpuTape { rendered: r, tiles }))
    }

    fn backward(
        &self,
        prepared: &CpuPrepared,
        lut: &Lut,
        shot: &Shot,
        tape: &CpuTape,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<LutGrad, RenderError> {
        let (camera, bg, opts) = (shot.camera, shot.background, shot.options);
        let recorded = Some(&tape.tiles[..]);
        if !shot.upsampled() {
            let fin = Final::Rendered(&tape.rendered);
            fin.check(d_image, d_transmittance)?;
            let grads = (d_image, d_transmittance);
            return backward_recorded(prepared, lut, camera, fin, opts, grads, recorded);
        }
        // Through I = up(acc) + up(T) · B: ∂/∂up(acc) = ∂/∂I, ∂/∂up(T) = ∂/∂T + Σ_c ∂/∂I_c B_c,
        // then the upsampling's transpose.
        let (s, n) = (shot.cast, (bg.width, bg.height));
        Final::Background(bg).check(d_image, d_transmittance)?;
        let d_t: Vec<f32> = (0..n.0 * n.1)
            .map(|p| {
                let from_image: f32 = (0..3)
                    .map(|c| d_image[3 * p + c] * bg.data[3 * p + c])
                    .sum();
                d_transmittance.get(p).copied().unwrap_or(0.0) + from_image
            })
            .collect();
        let d_acc_s = resize_bilinear_adjoint(d_image, n, 3, s);
        let d_t_s = resize_bilinear_adjoint(&d_t, n, 1, s);
        let fin = Final::Rendered(&tape.rendered);
        fin.check(&d_acc_s, &d_t_s)?;
        backward_recorded(
            prepared,
            lut,
            camera,
            fin,
            opts,
            (&d_acc_s, &d_t_s),
            recorded,
        )
    }
}

/// Everything one view's rays share, validated.
struct View<'a> {
    params: MarchParams<'a>,
    rays: crate::camera::RayFrame,
    frame: BoxFrame,
    jitter_seed: Option<u64>,
    width: usize,
    height: usize,
}

impl<'a> View<'a> {
    fn ray(&self, px: usize, py: usize) -> Option<Ray> {
        let jitter = match self.jitter_seed {
            None => 0.5,
            Some(seed) => unit_hash(seed, (py * self.width + px) as u64),
        };
        self.frame.clip(self.rays.dir(px, py), jitter)
    }

    /// Set up a view of `prepared` sampling `grid` (its bricks with the view's block tables).
    fn new(
        prepared: &CpuPrepared,
        lut: &'a Lut,
        camera: &Camera,
        (width, height): (usize, usize),
        opts: &RenderOptions,
        grid: Grid<'a>,
    ) -> View<'a> {
        let level = &prepared.data;
        let voxel = prepared
            .spacing
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let simd = simd::available() && grid.gathers_fit();
        View {
            params: MarchParams {
                grid,
                lut,
                inv_l: prepared.inv_l,
                stop_below: opts.early_termination,
                simd,
            },
            rays: camera.rays(width, height),
            frame: BoxFrame::new(
                camera.position,
                DVec3::from_array(prepared.origin),
                DVec3::from_array(prepared.spacing),
                level.dims,
                opts.step as f64 * voxel,
            ),
            jitter_seed: opts.jitter_seed,
            width,
            height,
        }
    }

    fn tile_pixels(&self, (tx, ty): (usize, usize)) -> impl Iterator<Item = (usize, usize)> + '_ {
        let (x1, y1) = ((tx + TILE).min(self.width), (ty + TILE).min(self.height));
        (ty..y1).flat_map(move |py| (tx..x1).map(move |px| (px, py)))
    }
}

/// splitmix64 of (seed, index) mapped to [0, 1).
fn unit_hash(seed: u64, index: u64) -> f32 {
    let mut z = seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    // 24 random bits: exactly representable, strictly below 1.
    (z >> 40) as f32 / (1u64 << 24) as f32
}

/// The view's block tables: `prepared`'s bricks against `lut`.
fn view_blocks(prepared: &CpuPrepared, lut: &Lut, opts: &RenderOptions) -> [Blocks; 2] {
    skip::blocks(
        &prepared.data.grid,
        lut,
        opts.skip_empty,
        opts.empty_sigma,
        true,
    )
}

/// The tiles of a `width` × `height` view, by their top-left pixel, row by row.
fn tiles((width, height): (usize, usize)) -> Vec<(usize, usize)> {
    let mut t = Vec::new();
    for ty in (0..height).step_by(TILE) {
        for tx in (0..width).step_by(TILE) {
            t.push((tx, ty));
        }
    }
    t
}

/// `per_tile` of every tile of a `size` view of `prepared`, in tile order (tiles run in
/// parallel; through a brick cache, batch by batch, `cache.rs`).
// The view's arguments, whether `per_tile` samples the level, and `per_tile`.
#[allow(clippy::too_many_arguments)]
fn each_tile<R: Send>(
    prepared: &CpuPrepared,
    lut: &Lut,
    camera: &Camera,
    size: (usize, usize),
    opts: &RenderOptions,
    samples: bool,
    per_tile: impl Fn(&View, (usize, usize)) -> R + Sync,
) -> Result<Vec<R>, RenderError> {
    let blocks = view_blocks(prepared, lut, opts);
    let tiles = tiles(size);
    let dims = prepared.data.dims;
    let cache = match &prepared.data.store {
        Store::Cache(cache) if samples => cache,
        store => {
            let values = match store {
                Store::Whole(b) => (b.values(), b.scale()),
                // No brick is read: a grid without values, and no brick loaded for it.
                Store::Cache(_) => (BrickValues::F32(&[]), 1.0),
            };
            let grid = Grid::new(dims, values, None, &blocks);
            let v = View::new(prepared, lut, camera, size, opts, grid);
            return Ok(tiles.par_iter().map(|&t| per_tile(&v, t)).collect());
        }
    };
    cache.run(
        |r| {
            let v = resident_view(prepared, lut, camera, size, opts, (r, &blocks));
            tiles
                .par_iter()
                .map(|&t| {
                    let mut bricks = Vec::new();
                    for (px, py) in v.tile_pixels(t) {
                        if let Some(ray) = v.ray(px, py) {
                            bricks_touched(&v.params.grid, &ray, |b| bricks.push(b as u32));
                        }
                    }
                    bricks.sort_unstable();
                    bricks.dedup();
                    bricks
                })
                .collect()
        },
        |r, range| {
            let v = resident_view(prepared, lut, camera, size, opts, (r, &blocks));
            tiles[range].par_iter().map(|&t| per_tile(&v, t)).collect()
        },
    )
}

/// A view of `prepared` sampling a brick cache's resident bricks `r`, with block tables
/// `blocks`.
fn resident_view<'a>(
    prepared: &CpuPrepared,
    lut: &'a Lut,
    camera: &Camera,
    size: (usize, usize),
    opts: &RenderOptions,
    (r, blocks): (cache::Resident<'a>, &'a [Blocks; 2]),
) -> View<'a> {
    let grid = Grid::new(
        prepared.data.dims,
        (r.values, r.scale),
        Some(r.slots),
        blocks,
    );
    View::new(prepared, lut, camera, size, opts, grid)
}

/// What a [`Backend::forward`] keeps for its backward: the result, and per tile (in tile
/// order) what each ray composited, so the backward replays the compositing instead of
/// walking blocks and interpolating again (`march::replay`). A tile past `RECORD_STEPS`
/// has none and is marched again.
#[derive(Clone, Debug)]
pub struct CpuTape {
    rendered: Rendered,
    tiles: Vec<Option<TileRecord>>,
}

/// The steps of one tile's rays, pixel by pixel in tile order: pixel i's are
/// `steps[ends[i − 1]..ends[i]]`, on a ray whose segments are `delta` long and whose last
/// segment is `last[i]` long.
#[derive(Clone, Debug, Default)]
struct TileRecord {
    ends: Vec<u32>,
    last: Vec<f32>,
    delta: f32,
    steps: Vec<Step>,
}

/// Render `prepared` with `lut` from `camera` over `background` (whose size is the image size).
pub(super) fn forward(
    prepared: &CpuPrepared,
    lut: &Lut,
    camera: &Camera,
    background: &Image,
    opts: &RenderOptions,
) -> Result<Rendered, RenderError> {
    Ok(forward_recorded(prepared, lut, camera, background, opts, false)?.0)
}

/// [`forward`], and with `record` each tile's [`TileRecord`] (else none).
fn forward_recorded(
    prepared: &CpuPrepared,
    lut: &Lut,
    camera: &Camera,
    background: &Image,
    opts: &RenderOptions,
    record: bool,
) -> Result<(Rendered, Vec<Option<TileRecord>>), RenderError> {
    validate(lut, opts)?;
    let size = (background.width, background.height);
    if size.0 == 0 || size.1 == 0 {
        return Err(RenderError::EmptyImage {
            got_w: size.0,
            got_h: size.1,
        });
    }
    // Steps recorded by the tiles done so far (relaxed: which tiles keep their record may
    // depend on the schedule, the results do not).
    let recorded = AtomicUsize::new(0);
    // Per tile: (pixel, rgb, T) triples, the sample count and the record.
    let done = each_tile(prepared, lut, camera, size, opts, true, |v, tile| {
        let mut out: Vec<(usize, [f32; 3], f32)> = Vec::with_capacity(TILE * TILE);
        let mut samples = 0u64;
        let mut rec = record.then(|| TileRecord {
            ends: Vec::with_capacity(TILE * TILE),
            last: Vec::with_capacity(TILE * TILE),
            delta: 0.0,
            steps: Vec::new(),
        });
        for (px, py) in v.tile_pixels(tile) {
            let p = py * v.width + px;
            let bg = background.pixel(px, py);
            let mut last = 0.0;
            let (acc, t) = match v.ray(px, py) {
                Some(ray) => {
                    let m = match &mut rec {
                        Some(r) => {
                            (r.delta, last) = (ray.delta, ray.delta_last);
                            let full = ray.delta * v.params.inv_l;
                            march(&v.params, &ray, |s| r.steps.push(Step::of(s, full)))
                        }
                        None => march(&v.params, &ray, |_| {}),
                    };
                    samples += m.samples as u64;
                    (m.acc, m.transmittance)
                }
                None => ([0.0; 3], 1.0),
            };
            if let Some(r) = &mut rec {
                if r.steps.len() + recorded.load(Ordering::Relaxed) > RECORD_STEPS {
                    rec = None;
                } else {
                    r.ends.push(r.steps.len() as u32);
                    r.last.push(last);
                }
            }
            out.push((p, std::array::from_fn(|c| acc[c] + t * bg[c]), t));
        }
        if let Some(r) = &rec {
            if recorded.fetch_add(r.steps.len(), Ordering::Relaxed) + r.steps.len() > RECORD_STEPS {
                rec = None;
            }
        }
        (out, samples, rec)
    })?;
    let mut image = Image::new(size.0, size.1);
    let mut transmittance = vec![1.0; size.0 * size.1];
    let mut samples = 0;
    let mut records = Vec::with_capacity(if record { done.len() } else { 0 });
    for (pixels, s, rec) in done {
        samples += s;
        for (p, rgb, t) in pixels {
            image.data[3 * p..3 * p + 3].copy_from_slice(&rgb);
            transmittance[p] = t;
        }
        if record {
            records.push(rec);
        }
    }
    let rendered = Rendered {
        image,
        transmittance,
        level: prepared.level,
        samples,
    };
    Ok((rendered, records))
}

/// Where the backward gets each pixel's final colour and transmittance.
#[derive(Clone, Copy)]
pub(super) enum Final<'a> {
    /// Re-march each ray over this background.
    Background(&'a Image),
    /// The forward's result.
    Rendered(&'a Rendered),
}

impl Final<'_> {
    /// The image size.
    pub(super) fn size(&self) -> (usize, usize) {
        match self {
            Final::Background(b) => (b.width, b.height),
            Final::Rendered(r) => (r.image.width, r.image.height),
        }
    }

    /// The gradients (and the forward's result) have the image's size.
    pub(super) fn check(
        &self,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<(), RenderError> {
        let (w, h) = self.size();
        let size_err = |what, got, expected| RenderError::GradientSize {
            what,
            got,
            expected,
            w,
            h,
        };
        if d_image.len() != w * h * 3 {
            return Err(size_err("d_image", d_image.len(), w * h * 3));
        }
        if !(d_transmittance.is_empty() || d_transmittance.len() == w * h) {
            return Err(size_err("d_transmittance", d_transmittance.len(), w * h));
        }
        if let Final::Rendered(r) = self {
            if r.transmittance.len() != w * h || r.image.data.len() != w * h * 3 {
                return Err(size_err(
                    "rendered transmittance",
                    r.transmittance.len(),
                    w * h,
                ));
            }
        }
        Ok(())
    }
}

/// ∂L/∂LUT of one view of `prepared` (sizes checked by [`Final::check`]).
pub(super) fn backward(
    prepared: &CpuPrepared,
    lut: &Lut,
    camera: &Camera,
    fin: Final,
    opts: &RenderOptions,
    d_image: &[f32],
    d_transmittance: &[f32],
) -> Result<LutGrad, RenderError> {
    let grads = (d_image, d_transmittance);
    backward_recorded(prepared, lut, camera, fin, opts, grads, None)
}

/// [`backward`], replaying the tiles `recorded` by the forward of the same view, LUT and
/// options where it kept them (`None`, or a tile without a record: marched again).
fn backward_recorded(
    prepared: &CpuPrepared,
    lut: &Lut,
    camera: &Camera,
    fin: Final,
    opts: &RenderOptions,
    (d_image, d_transmittance): (&[f32], &[f32]),
    recorded: Option<&[Option<TileRecord>]>,
) -> Result<LutGrad, RenderError> {
    fin.check(d_image, d_transmittance)?;
    validate(lut, opts)?;
    let (w, h) = fin.size();
    if w == 0 || h == 0 {
        return Err(RenderError::EmptyImage { got_w: w, got_h: h });
    }
    let n = lut.entries.len();
    let tiles_x = w.div_ceil(TILE);
    if let Some(r) = recorded {
        if r.len() != tiles_x * h.div_ceil(TILE) {
            return Err(RenderError::GradientSize {
                what: "recorded tiles",
                got: r.len(),
                expected: tiles_x * h.div_ceil(TILE),
                w,
                h,
            });
        }
    }
    // Replayed tiles read the record, not the level: a brick cache then loads nothing.
    let replayed = matches!(fin, Final::Rendered(_))
        && recorded.is_some_and(|r| r.iter().all(Option::is_some));
    let grads = each_tile(prepared, lut, camera, (w, h), opts, !replayed, |v, tile| {
        let mut grad = vec![[0.0f64; 4]; n];
        let rec = recorded.and_then(|r| r[tile.1 / TILE * tiles_x + tile.0 / TILE].as_ref());
        if let (Some(rec), Final::Rendered(r)) = (rec, fin) {
            let mut start = 0;
            for (i, (px, py)) in v.tile_pixels(tile).enumerate() {
                let end = rec.ends[i] as usize;
                let steps = &rec.steps[start..end];
                start = end;
                let p = py * w + px;
                let g = [d_image[3 * p], d_image[3 * p + 1], d_image[3 * p + 2]];
                let g_t = d_transmittance.get(p).copied().unwrap_or(0.0);
                // A pixel without steps (no ray, or nothing composited) adds nothing.
                if (g == [0.0; 3] && g_t == 0.0) || steps.is_empty() {
                    continue;
                }
                let (image, t_final) = (r.image.pixel(px, py), r.transmittance[p]);
                let tail = g_t * t_final;
                let deltas = (rec.delta, rec.last[i]);
                replay(&v.params, deltas, steps, |s| {
                    accumulate(&mut grad, s, g, image, tail)
                });
            }
            return grad;
        }
        for (px, py) in v.tile_pixels(tile) {
            let p = py * w + px;
            let g = [d_image[3 * p], d_image[3 * p + 1], d_image[3 * p + 2]];
            let g_t = d_transmittance.get(p).copied().unwrap_or(0.0);
            if g == [0.0; 3] && g_t == 0.0 {
                continue;
            }
            let Some(ray) = v.ray(px, py) else { continue };
            let (image, t_final) = match fin {
                Final::Rendered(r) => (r.image.pixel(px, py), r.transmittance[p]),
                Final::Background(bg) => {
                    let m = march(&v.params, &ray, |_| {});
                    let b = bg.pixel(px, py);
                    let rgb = std::array::from_fn(|c| m.acc[c] + m.transmittance * b[c]);
                    (rgb, m.transmittance)
                }
            };
            let tail = g_t * t_final;
            march(&v.params, &ray, |s| {
                accumulate(&mut grad, s, g, image, tail)
            });
        }
        grad
    })?;
    // Fixed-order reduction: independent of how rayon scheduled the tiles.
    let mut total = LutGrad::zeros(n);
    for g in grads {
        for (a, b) in total.entries.iter_mut().zip(&g) {
            for c in 0..4 {
                a[c] += b[c];
            }
        }
    }
    Ok(total)
}

/// One sample's part of ∂L/∂LUT (module docs: "Backward"), for a pixel with ∂L/∂I = `g`,
/// final colour `image` and `tail` = ∂L/∂T_N · T_N. A function of its own, always inlined:
/// as a closure body LLVM called it once per sample.
#[inline(always)]
fn accumulate(grad: &mut [[f64; 4]], s: &march::Sample, g: [f32; 3], image: [f32; 3], tail: f32) {
    let weight = s.t_before - s.t_after;
    let mut d_sigma = -tail;
    let mut d_rgb = [0.0f32; 3];
    for c in 0..3 {
        d_sigma += g[c] * (s.t_after * s.rgb[c] - (image[c] - s.acc[c]));
        d_rgb[c] = weight * g[c];
    }
    let d_sigma = (d_sigma * s.delta_norm * s.count) as f64;
    let (w1, w0) = (s.lut_weight as f64, 1.0 - s.lut_weight as f64);
    let (e0, e1) = grad.split_at_mut(s.lut_index + 1);
    let (e0, e1) = (&mut e0[s.lut_index], &mut e1[0]);
    e0[0] += w0 * d_sigma;
    e1[0] += w1 * d_sigma;
    for c in 0..3 {
        e0[c + 1] += w0 * d_rgb[c] as f64;
        e1[c + 1] += w1 * d_rgb[c] as f64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;
    use t2tf_volume::{Geometry, TypedBuffer};

    /// The values and scale of a level prepared whole.
    pub(super) fn whole(p: &CpuPrepared) -> (BrickValues<'_>, f32) {
        match &p.data.store {
            Store::Whole(b) => (b.values(), b.scale()),
            Store::Cache(_) => panic!("a whole level expected"),
        }
    }

    /// A float volume of `dims` points at unit spacing with value `f(i, j, k)` at (i, j, k).
    pub(super) fn volume_of(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> f64) -> Volume {
        let mut vals = Vec::with_capacity(dims.iter().product());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    vals.push(f(i, j, k));
                }
            }
        }
        let g = Geometry {
            dims,
            spacing: [1.0; 3],
            origin: [0.0; 3],
        };
        Volume::from_buffer(Path::new("t"), g, &TypedBuffer::from_f64(vals)).unwrap()
    }

    fn volume(seed: usize) -> Volume {
        volume_of([12, 10, 9], |i, j, k| {
            (((i + 12 * (j + 10 * k)) * 31 + seed) % 17) as f64
        })
    }

    /// A level is bricked once (clones of the volume share it), and the copy goes once the
    /// volume is gone and something else is prepared.
    #[test]
    fn prepared_levels_are_cached_and_released() {
        let v = volume(1);
        let backend = CpuBackend::default();
        let a = backend.prepare(&v, 0).unwrap();
        let b = backend.prepare(&v.clone(), 0).unwrap();
        assert!(Arc::ptr_eq(&a.data, &b.data));
        // Another backend keeps its own copies.
        let c = CpuBackend::default().prepare(&v, 0).unwrap();
        assert!(!Arc::ptr_eq(&a.data, &c.data));
        drop(c);
        let other = backend.prepare(&v, 1).unwrap();
        assert!(!Arc::ptr_eq(&a.data, &other.data));
        assert_eq!(other.level(), 1);
        let weak = Arc::downgrade(&a.data);
        drop((a, b, other, v));
        let w = volume(2);
        backend.prepare(&w, 0).unwrap();
        assert!(
            weak.upgrade().is_none(),
            "a dropped volume's copy is still held"
        );
        assert!(matches!(
            backend.prepare(&w, 99),
            Err(RenderError::Level { level: 99, .. })
        ));
    }

    /// A level the volume holds, above the size of whole copy made of such a level, is read
    /// through a brick cache: the same images and gradients as a whole copy, bit for bit, and
    /// a backward that replays the forward's record loads no brick.
    #[test]
    fn held_levels_above_the_limit_are_read_through_a_cache() {
        let v = volume_of([80, 72, 66], |i, j, k| {
            ((i as f64 * 0.15).sin() * (j as f64 * 0.1).cos() + k as f64 / 66.0).abs()
        });
        let level = &v.levels[1];
        assert!(
            level.is_materialized(),
            "from_buffer holds the coarse levels"
        );
        let whole = prepared(
            &v,
            1,
            Arc::new(build(level, u64::MAX, 1 << 30, u64::MAX).unwrap()),
        );
        // A cache of about 3/4 of the level's bricks: the forward evicts, so a backward that
        // walked the bricks would load some again.
        let part = whole.memory_bytes() as u64 * 3 / 4;
        let cached = prepared(&v, 1, Arc::new(build(level, u64::MAX, part, 0).unwrap()));
        assert!(whole.cache_stats().is_none());
        assert!(cached.cache_stats().is_some());
        // Level 0 is not held: a whole copy whatever the limit.
        let l0 = build(&v.levels[0], u64::MAX, 1 << 30, 0).unwrap();
        assert!(matches!(l0.store, Store::Whole(_)));

        let lut = Lut {
            entries: (0..32)
                .map(|i| {
                    let x = i as f32 / 31.0;
                    [20.0 * x * x, x, 1.0 - x, 0.5]
                })
                .collect(),
        };
        let bg = Image::new(64, 56);
        let (d_image, d_t) = (vec![0.25f32; 3 * 64 * 56], vec![-0.5f32; 64 * 56]);
        let backend = CpuBackend::default();
        let mut bits = Vec::new();
        for p in [&whole, &cached] {
            let mut got = Vec::new();
            for yaw in [0.3f64, 2.0, 4.1] {
                let orbit = crate::camera::Orbit {
                    yaw,
                    pitch: 0.4,
                    distance: 2.4,
                    up: crate::camera::UpAxis::Z,
                };
                let camera = Camera::orbit(&v.geometry, orbit).unwrap();
                let opts = RenderOptions::default();
                let shot = Shot {
                    camera: &camera,
                    background: &bg,
                    options: &opts,
                    cast: (64, 56),
                };
                let (r, tape) = backend.forward(p, &lut, &shot).unwrap();
                let loads = p.cache_stats().map(|s| s.loads);
                let g = backend
                    .backward(p, &lut, &shot, &tape, &d_image, &d_t)
                    .unwrap();
                assert_eq!(
                    p.cache_stats().map(|s| s.loads),
                    loads,
                    "the backward loaded"
                );
                got.extend(r.image.data.iter().map(|x| u64::from(x.to_bits())));
                got.extend(g.entries.iter().flatten().map(|x| x.to_bits()));
            }
            bits.push(got);
        }
        assert!(cached.cache_stats().unwrap().evictions > 0);
        assert_eq!(bits[0], bits[1]);
    }
}
