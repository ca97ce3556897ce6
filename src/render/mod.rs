//! Differentiable emission-absorption volume renderer: forward and analytic backward.
//!
//! Per ray, front to back (DESIGN.md "Conventions"): trilinear samples of the normalized
//! scalar (a NaN corner makes a sample empty), the LUT interpolated linearly after the scalar,
//! αₙ = 1 − exp(−σₙ δₙ / L), and
//!
//! ```text
//! I = Σₙ Tₙ αₙ cₙ + T_N B,   Tₙ₊₁ = Tₙ (1 − αₙ).
//! ```
//!
//! **Backward.** With g = ∂L/∂I and g_T = ∂L/∂T_N for one pixel, and Aₙ the colour
//! accumulated up to and including sample n, the colour behind sample n is I − Aₙ, and
//!
//! ```text
//! ∂L/∂cₙ = Tₙ αₙ g,     ∂L/∂σₙ = (δₙ/L) · [ g · (Tₙ₊₁ cₙ − (I − Aₙ)) − g_T T_N ]
//! ```
//!
//! (from ∂I/∂αₙ = Tₙ (cₙ − Rₙ) with Rₙ the colour seen from just behind n, and
//! ∂αₙ/∂σₙ = (δₙ/L)(1 − αₙ); no division by 1 − αₙ, so saturated rays stay finite). The ray
//! is re-marched front to back with the final I and T_N of the forward: memory is O(pixels).
//! σₙ and cₙ are linear in the two LUT entries around the sample, which receive the gradient.
//!
//! **Work done.** Rays are clipped to the box; bricks whose value range the LUT maps to σ = 0
//! (or ≤ [`RenderOptions::empty_sigma`]) are jumped over without moving the sample positions;
//! rays stop once T < [`RenderOptions::early_termination`]; bricks whose points all hold one
//! value are crossed in one step (their samples are identical, so the compositing telescopes:
//! T e^(−kσδ/L), and the k per-sample backward terms are equal); the mip level is chosen so a
//! voxel is half a pixel at the volume's centre. The backward re-marches exactly the samples the
//! forward used (same skips, same stop), so it is the exact gradient of what was rendered —
//! except that LUT entries that are exactly zero (at most `empty_sigma`) get no gradient from
//! skipped bricks: their samples are never visited. Pass `skip_empty: false` where that
//! gradient matters (the TF parameterization's σ = 255·(tanh p + 1)/2 is never exactly 0).
//!
//! **Memory and the inner loop** (BENCHMARKS.md, "Renderer"). Sampling is bound by memory, not
//! arithmetic: rays read the level's bricked copy (`volume::bricked`: 9³ points per brick with
//! aprons, 8 or 16 bits for integer volumes, huge pages), so a 256³ `uint8` volume is 23 MiB
//! instead of 64 MiB of f32. The block walk merges consecutive non-uniform bricks into one
//! sample range, which is interpolated and classified 8 samples at a time (AVX2 gathers where
//! the CPU has them, `simd.rs`, bit-identical to the scalar code) before the serial
//! compositing.
//!
//! Rays run in parallel over 16 × 16 tiles (rayon); LUT gradients are summed per tile and the
//! tiles reduced in a fixed order, so the result does not depend on the thread count.

mod fastmath;
mod march;
mod simd;
mod skip;

use glam::DVec3;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::image::Image;
use crate::tf::{Lut, LutGrad};
use crate::volume::Volume;

use march::{march, BoxFrame, Grid, MarchParams, Ray};
use skip::Blocks;

/// Tile side in pixels (parallel work unit and gradient reduction unit).
const TILE: usize = 16;

/// Default step in voxels of the rendered level (see BENCHMARKS.md, "Renderer").
pub const DEFAULT_STEP: f32 = 1.0;
/// Step of pictures for people (`t2tf render`), in voxels of level 0. The optimizer's loop
/// keeps [`DEFAULT_STEP`]; a picture someone looks at is rendered once and can afford 4× the
/// samples. Measured (`examples/bench_render_defaults`, BENCHMARKS.md "Render defaults": every
/// shared volume plus a wide-range 16-bit CT, a ramp TF and a narrow opacity-0.98 peak, 256²
/// px) against level 0 at 1/8 voxel: on the worst case (walnut, peak) step 1 is 23.2 dB, 0.5 is
/// 28.6 dB, 0.375 is 32.1 dB, 0.25 is 37.6 dB (≥ 42 dB on every other case), at 1.5–4× the
/// time of step 1 (≤ 0.26 s for two views on a busy 2-core machine).
pub const FINAL_STEP: f32 = 0.25;
/// Mip level of pictures for people: always full resolution. The automatic level picks a
/// coarser one only for small pictures, and there it loses everything the step gains (96² px,
/// aneurism, ramp TF: 27.0 dB on the automatic level 1 against 74.0 dB on level 0), while
/// level 0 at that size takes 0.02 s.
pub const FINAL_LEVEL: usize = 0;
/// Default early-termination threshold: a ray stops when T < 1e-3, so what it leaves out is at
/// most T·|c − B| ≤ 1e-3 per channel, a quarter of an 8-bit level (≥ 60 dB PSNR).
pub const DEFAULT_EARLY_TERMINATION: f32 = 1e-3;

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("step size {0} voxels is not allowed: it must be finite and at least 1/64")]
    Step(f32),
    #[error("mip level {level} does not exist: this volume has levels 0..={max}")]
    Level { level: usize, max: usize },
    #[error("early-termination threshold {0} must lie in [0, 1)")]
    EarlyTermination(f32),
    #[error("empty-space threshold {0} must be finite and at least 0")]
    EmptySigma(f32),
    #[error("lookup table has {0} entries; 2 to 2^24 are needed")]
    LutSize(usize),
    #[error("lookup table entry {index} is {entry:?}: σ must be finite and ≥ 0, colours finite")]
    LutEntry { index: usize, entry: [f32; 4] },
    #[error("background is {got_w}×{got_h} but must be at least 1×1 (the image size)")]
    EmptyImage { got_w: usize, got_h: usize },
    #[error("{what} has {got} values; {expected} expected for a {w}×{h} image")]
    GradientSize {
        what: &'static str,
        got: usize,
        expected: usize,
        w: usize,
        h: usize,
    },
}

/// How to render. `Default` gives the documented defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Step between samples in voxels of the rendered level (the smallest spacing of that level).
    pub step: f32,
    /// Mip level to render; `None` picks it from the pixel footprint ([`choose_level`]).
    pub level: Option<usize>,
    /// Per-ray jitter of the sample positions within their segments; `None` samples segment
    /// midpoints. The same seed gives the same samples (forward and backward must agree).
    pub jitter_seed: Option<u64>,
    /// Stop a ray once its transmittance is below this; 0 turns early termination off.
    pub early_termination: f32,
    /// Skip bricks where the TF has no density.
    pub skip_empty: bool,
    /// A brick counts as empty when σ ≤ this on its whole value range. 0 (default) is exact;
    /// a positive value trades accuracy (a ray loses at most 1 − exp(−√3·empty_sigma) of
    /// opacity) for speed when the TF is nearly but not exactly zero.
    pub empty_sigma: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            step: DEFAULT_STEP,
            level: None,
            jitter_seed: None,
            early_termination: DEFAULT_EARLY_TERMINATION,
            skip_empty: true,
            empty_sigma: 0.0,
        }
    }
}

impl RenderOptions {
    /// The options for a final picture: [`FINAL_LEVEL`] and [`FINAL_STEP`], no jitter, the
    /// other defaults unchanged (early termination at T < 1e-3 costs ≤ 1/4 of an 8-bit level).
    pub fn final_quality() -> Self {
        RenderOptions {
            step: FINAL_STEP,
            level: Some(FINAL_LEVEL),
            ..RenderOptions::default()
        }
    }
}

/// A rendered view.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// I per pixel (background included).
    pub image: Image,
    /// T_N per pixel, row-major from the top row.
    pub transmittance: Vec<f32>,
    /// The mip level that was rendered.
    pub level: usize,
    /// Scalar samples interpolated (skipped samples not counted).
    pub samples: u64,
}

/// Voxels per pixel (at the focal point) that the automatic level keeps: 2, i.e. a voxel is at
/// most half a pixel. With one voxel per pixel the thin vessels of the aneurism lose 13 dB
/// (31 dB PSNR against the level-0 reference, BENCHMARKS.md), with two they do not.
pub const VOXELS_PER_PIXEL: f64 = 2.0;

/// The coarsest mip level whose voxels are at most 1/[`VOXELS_PER_PIXEL`] of a pixel at the
/// focal point (level 0 when even that is too coarse).
pub fn choose_level(volume: &Volume, camera: &Camera, height: usize) -> usize {
    let footprint = camera.pixel_footprint(height) / VOXELS_PER_PIXEL;
    let mut best = 0;
    for (l, level) in volume.levels.iter().enumerate() {
        let voxel = level.spacing.iter().copied().fold(f64::INFINITY, f64::min);
        if voxel <= footprint * (1.0 + 1e-9) {
            best = l;
        }
    }
    best
}

/// Everything one view's rays share, validated.
struct View<'a> {
    params: MarchParams<'a>,
    rays: crate::camera::RayFrame,
    frame: BoxFrame,
    jitter_seed: Option<u64>,
    width: usize,
    height: usize,
    level: usize,
}

impl<'a> View<'a> {
    fn ray(&self, px: usize, py: usize) -> Option<Ray> {
        let jitter = match self.jitter_seed {
            None => 0.5,
            Some(seed) => unit_hash(seed, (py * self.width + px) as u64),
        };
        self.frame.clip(self.rays.dir(px, py), jitter)
    }

    fn tiles(&self) -> Vec<(usize, usize)> {
        let mut t = Vec::new();
        for ty in (0..self.height).step_by(TILE) {
            for tx in (0..self.width).step_by(TILE) {
                t.push((tx, ty));
            }
        }
        t
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

fn validate(lut: &Lut, opts: &RenderOptions) -> Result<(), RenderError> {
    if !(opts.step.is_finite() && opts.step >= 1.0 / 64.0) {
        return Err(RenderError::Step(opts.step));
    }
    if !(0.0..1.0).contains(&opts.early_termination) {
        return Err(RenderError::EarlyTermination(opts.early_termination));
    }
    if !(opts.empty_sigma.is_finite() && opts.empty_sigma >= 0.0) {
        return Err(RenderError::EmptySigma(opts.empty_sigma));
    }
    if lut.entries.len() < 2 || lut.entries.len() > 1 << 24 {
        return Err(RenderError::LutSize(lut.entries.len()));
    }
    for (index, e) in lut.entries.iter().enumerate() {
        if !(e.iter().all(|v| v.is_finite()) && e[0] >= 0.0) {
            return Err(RenderError::LutEntry { index, entry: *e });
        }
    }
    Ok(())
}

/// Validate, choose the level and build its block tables.
fn prepare(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    width: usize,
    height: usize,
    opts: &RenderOptions,
) -> Result<(usize, [Blocks; 2]), RenderError> {
    validate(lut, opts)?;
    if width == 0 || height == 0 {
        return Err(RenderError::EmptyImage {
            got_w: width,
            got_h: height,
        });
    }
    let level = match opts.level {
        Some(l) if l >= volume.levels.len() => {
            return Err(RenderError::Level {
                level: l,
                max: volume.levels.len() - 1,
            })
        }
        Some(l) => l,
        None => choose_level(volume, camera, height),
    };
    let blocks = skip::blocks(
        &volume.levels[level],
        lut,
        opts.skip_empty,
        opts.empty_sigma,
        true,
    );
    Ok((level, blocks))
}

/// Set up a view on `level` with its `blocks` (from [`prepare`]).
fn view<'a>(
    volume: &'a Volume,
    lut: &'a Lut,
    camera: &Camera,
    (width, height): (usize, usize),
    opts: &RenderOptions,
    (level_index, blocks): &'a (usize, [Blocks; 2]),
) -> View<'a> {
    let level = &volume.levels[*level_index];
    let voxel = level.spacing.iter().copied().fold(f64::INFINITY, f64::min);
    View {
        params: MarchParams {
            grid: Grid::new(level, blocks),
            lut,
            inv_l: (1.0 / volume.geometry.longest_side()) as f32,
            stop_below: opts.early_termination,
            simd: simd::available(),
        },
        rays: camera.rays(width, height),
        frame: BoxFrame::new(
            camera.position,
            DVec3::from_array(volume.geometry.origin),
            DVec3::from_array(level.spacing),
            level.dims,
            opts.step as f64 * voxel,
        ),
        jitter_seed: opts.jitter_seed,
        width,
        height,
        level: *level_index,
    }
}

/// Render `volume` with `lut` from `camera` over `background` (whose size is the image size).
pub fn forward(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    background: &Image,
    opts: &RenderOptions,
) -> Result<Rendered, RenderError> {
    let size = (background.width, background.height);
    let prepared = prepare(volume, lut, camera, size.0, size.1, opts)?;
    let v = view(volume, lut, camera, size, opts, &prepared);
    let tiles = v.tiles();
    // Per tile: (pixel, rgb, T) triples and the sample count.
    type TileOut = (Vec<(usize, [f32; 3], f32)>, u64);
    let done: Vec<TileOut> = tiles
        .par_iter()
        .map(|&tile| {
            let mut out = Vec::with_capacity(TILE * TILE);
            let mut samples = 0u64;
            for (px, py) in v.tile_pixels(tile) {
                let p = py * v.width + px;
                let bg = background.pixel(px, py);
                let (acc, t) = match v.ray(px, py) {
                    Some(ray) => {
                        let m = march(&v.params, &ray, |_| {});
                        samples += m.samples as u64;
                        (m.acc, m.transmittance)
                    }
                    None => ([0.0; 3], 1.0),
                };
                out.push((p, std::array::from_fn(|c| acc[c] + t * bg[c]), t));
            }
            (out, samples)
        })
        .collect();
    let mut image = Image::new(v.width, v.height);
    let mut transmittance = vec![1.0; v.width * v.height];
    let mut samples = 0;
    for (pixels, s) in done {
        samples += s;
        for (p, rgb, t) in pixels {
            image.data[3 * p..3 * p + 3].copy_from_slice(&rgb);
            transmittance[p] = t;
        }
    }
    Ok(Rendered {
        image,
        transmittance,
        level: v.level,
        samples,
    })
}

/// ∂L/∂LUT given ∂L/∂I (`d_image`, H·W·3, row-major from the top) and ∂L/∂T_N
/// (`d_transmittance`, H·W; may be empty for zero). Re-renders the forward per ray first; use
/// [`backward_from`] when the forward's [`Rendered`] is at hand (one march per ray less).
pub fn backward(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    background: &Image,
    opts: &RenderOptions,
    d_image: &[f32],
    d_transmittance: &[f32],
) -> Result<LutGrad, RenderError> {
    backward_impl(
        volume,
        lut,
        camera,
        Final::Background(background),
        opts,
        d_image,
        d_transmittance,
    )
}

/// Like [`backward`], with the image and transmittance of the forward of the same view,
/// LUT and options (its background is already in `rendered.image`).
pub fn backward_from(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    rendered: &Rendered,
    opts: &RenderOptions,
    d_image: &[f32],
    d_transmittance: &[f32],
) -> Result<LutGrad, RenderError> {
    backward_impl(
        volume,
        lut,
        camera,
        Final::Rendered(rendered),
        opts,
        d_image,
        d_transmittance,
    )
}

/// Where the backward gets each pixel's final colour and transmittance.
#[derive(Clone, Copy)]
enum Final<'a> {
    Background(&'a Image),
    Rendered(&'a Rendered),
}

impl Final<'_> {
    fn size(&self) -> (usize, usize) {
        match self {
            Final::Background(b) => (b.width, b.height),
            Final::Rendered(r) => (r.image.width, r.image.height),
        }
    }
}

fn backward_impl(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    fin: Final,
    opts: &RenderOptions,
    d_image: &[f32],
    d_transmittance: &[f32],
) -> Result<LutGrad, RenderError> {
    let (w, h) = fin.size();
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
    if let Final::Rendered(r) = fin {
        if r.transmittance.len() != w * h || r.image.data.len() != w * h * 3 {
            return Err(size_err(
                "rendered transmittance",
                r.transmittance.len(),
                w * h,
            ));
        }
    }
    let prepared = prepare(volume, lut, camera, w, h, opts)?;
    let v = view(volume, lut, camera, (w, h), opts, &prepared);
    let n = lut.entries.len();
    let tiles = v.tiles();
    let grads: Vec<Vec<[f64; 4]>> = tiles
        .par_iter()
        .map(|&tile| {
            let mut grad = vec![[0.0f64; 4]; n];
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
        })
        .collect();
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

/// Render one view per camera and tile them into a sheet of ⌈√n⌉ columns; cells without a
/// view show `background`. Every view uses `background` and `opts`.
pub fn orbit_sheet(
    volume: &Volume,
    lut: &Lut,
    cameras: &[Camera],
    background: &Image,
    opts: &RenderOptions,
) -> Result<Image, RenderError> {
    let n = cameras.len().max(1);
    let cols = (n as f64).sqrt().ceil() as usize;
    let mut views = Vec::with_capacity(cols * n.div_ceil(cols));
    for cam in cameras {
        views.push(forward(volume, lut, cam, background, opts)?.image);
    }
    views.resize(cols * n.div_ceil(cols), background.clone());
    Ok(Image::grid(&views, cols))
}
