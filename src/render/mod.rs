//! Differentiable emission-absorption volume renderer: forward and analytic backward.
//!
//! Per ray, front to back (docs/DESIGN.md "Conventions"): trilinear samples of the normalized
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
//! arithmetic: rays read the level's bricked copy (`cpu::bricked`, made when the [`Backend`]
//! prepares the level: 9³ points per brick with aprons, 8 or 16 bits for integer volumes, huge
//! pages), so a 256³ `uint8` volume is 23 MiB
//! instead of 64 MiB of f32. The block walk merges consecutive non-uniform bricks into one
//! sample range, which is interpolated and classified 8 samples at a time (AVX2 gathers where
//! the CPU has them, `cpu/simd.rs`, bit-identical to the scalar code) before the serial
//! compositing.
//!
//! Rays run in parallel over 16 × 16 tiles (rayon); LUT gradients are summed per tile and the
//! tiles reduced in a fixed order, so the result does not depend on the thread count.

pub mod cpu;

use crate::camera::Camera;
use crate::image::Image;
use crate::tf::{Lut, LutGrad};
use crate::volume::Volume;

pub use cpu::CpuBackend;

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

/// Why a view could not be rendered or differentiated.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// `step` is not finite or below 1/64 voxel.
    #[error("step size {0} voxels is not allowed: it must be finite and at least 1/64")]
    Step(f32),
    /// The level asked for is past the volume's coarsest.
    #[error("mip level {level} does not exist: this volume has levels 0..={max}")]
    Level {
        /// The level asked for.
        level: usize,
        /// The coarsest level there is.
        max: usize,
    },
    /// `early_termination` is outside [0, 1).
    #[error("early-termination threshold {0} must lie in [0, 1)")]
    EarlyTermination(f32),
    /// `empty_sigma` is negative or not finite.
    #[error("empty-space threshold {0} must be finite and at least 0")]
    EmptySigma(f32),
    /// The LUT has fewer than 2 or more than 2²⁴ entries.
    #[error("lookup table has {0} entries; 2 to 2^24 are needed")]
    LutSize(usize),
    /// A LUT entry is not finite, or its σ is negative.
    #[error("lookup table entry {index} is {entry:?}: σ must be finite and ≥ 0, colours finite")]
    LutEntry {
        /// Which entry.
        index: usize,
        /// Its (σ, r, g, b).
        entry: [f32; 4],
    },
    /// The image has no pixel.
    #[error("background is {got_w}×{got_h} but must be at least 1×1 (the image size)")]
    EmptyImage {
        /// Width found.
        got_w: usize,
        /// Height found.
        got_h: usize,
    },
    /// A gradient (or the forward's result) does not have the image's size.
    #[error("{what} has {got} values; {expected} expected for a {w}×{h} image")]
    GradientSize {
        /// Which input.
        what: &'static str,
        /// Values found.
        got: usize,
        /// Values expected.
        expected: usize,
        /// Image width.
        w: usize,
        /// Image height.
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

/// Check the LUT and the options every backend relies on.
pub(crate) fn validate(lut: &Lut, opts: &RenderOptions) -> Result<(), RenderError> {
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

/// Validate a view of `width` × `height` rays and pick its mip level: `opts.level`, or
/// [`choose_level`] when that is `None`. What a caller of a [`Backend`] asks it to prepare.
pub fn level_for(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    (width, height): (usize, usize),
    opts: &RenderOptions,
) -> Result<usize, RenderError> {
    validate(lut, opts)?;
    if width == 0 || height == 0 {
        return Err(RenderError::EmptyImage {
            got_w: width,
            got_h: height,
        });
    }
    match opts.level {
        Some(l) if l >= volume.levels.len() => Err(RenderError::Level {
            level: l,
            max: volume.levels.len() - 1,
        }),
        Some(l) => Ok(l),
        None => Ok(choose_level(volume, camera, height)),
    }
}

/// One view for a [`Backend`]: where from, over what, how, and at what size the rays are cast.
#[derive(Clone, Copy, Debug)]
pub struct Shot<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// What the volume is composited over; its size is the output's size.
    pub background: &'a Image,
    /// Step, jitter, early termination, skipping (`level` is the prepared level's).
    pub options: &'a RenderOptions,
    /// Rays per side, (width, height). Below the background's size the volume's colour and
    /// transmittance are cast at this size, upsampled bilinearly and composited over the
    /// full-size background there (so sharp backgrounds stay sharp): the work shrinks with the
    /// square of the ratio. At or above it, rays are cast at the background's size.
    pub cast: (usize, usize),
}

impl Shot<'_> {
    /// Whether the rays are cast below the output size (and the result upsampled).
    pub fn upsampled(&self) -> bool {
        let (w, h) = (self.background.width, self.background.height);
        self.cast.0 < w || self.cast.1 < h
    }
}

/// Where a renderer plugs in (ARCHITECTURE.md, "Backends"). A backend first *prepares* one mip
/// level of a volume — copies it into the layout and memory it samples from (the CPU backend:
/// bricks with aprons in 8/16/32 bits; a GPU backend would upload a 3D texture and the brick
/// ranges) — and then renders views of the prepared level and differentiates them. The
/// optimizer only uses this trait; which level to prepare comes from [`level_for`].
///
/// Contract: `forward` returns the image at the background's size and T_N per pixel;
/// `backward` returns ∂L/∂LUT for the same shot and LUT given ∂L/∂image and ∂L/∂T_N at that
/// size, using the `Tape` its `forward` returned. Results may not depend on the thread count.
pub trait Backend: Send + Sync {
    /// A level ready to render.
    type Prepared: Send + Sync;
    /// What `backward` needs from the `forward` of the same shot.
    type Tape: Send + Sync;

    /// Make level `level` of `volume` ready to render (may be cached by the backend).
    fn prepare(&self, volume: &Volume, level: usize) -> Result<Self::Prepared, RenderError>;

    /// Render one shot of a prepared level.
    fn forward(
        &self,
        prepared: &Self::Prepared,
        lut: &Lut,
        shot: &Shot,
    ) -> Result<(Rendered, Self::Tape), RenderError>;

    /// ∂L/∂LUT of a shot rendered by `forward` (which returned `tape`), given ∂L/∂image
    /// (H·W·3, row-major from the top) and ∂L/∂T_N (H·W, or empty for zero) at the
    /// background's size.
    fn backward(
        &self,
        prepared: &Self::Prepared,
        lut: &Lut,
        shot: &Shot,
        tape: &Self::Tape,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<LutGrad, RenderError>;
}

/// Render `volume` with `lut` from `camera` over `background` (whose size is the image size),
/// on the CPU backend.
pub fn forward(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    background: &Image,
    opts: &RenderOptions,
) -> Result<Rendered, RenderError> {
    let size = (background.width, background.height);
    let level = level_for(volume, lut, camera, size, opts)?;
    let prepared = CpuBackend.prepare(volume, level)?;
    cpu::forward(&prepared, lut, camera, background, opts)
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
    let fin = cpu::Final::Background(background);
    fin.check(d_image, d_transmittance)?;
    let level = level_for(volume, lut, camera, fin.size(), opts)?;
    let prepared = CpuBackend.prepare(volume, level)?;
    cpu::backward(&prepared, lut, camera, fin, opts, d_image, d_transmittance)
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
    let fin = cpu::Final::Rendered(rendered);
    fin.check(d_image, d_transmittance)?;
    let level = level_for(volume, lut, camera, fin.size(), opts)?;
    let prepared = CpuBackend.prepare(volume, level)?;
    cpu::backward(&prepared, lut, camera, fin, opts, d_image, d_transmittance)
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
