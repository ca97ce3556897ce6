//! The backend boundary: what every renderer shares (options, errors, results, the choice of
//! mip level, validation) and the [`Backend`] trait a renderer implements. Imports run one
//! way: `volume` → this module → `render::cpu` (a backend) → `render` (the facade that picks
//! the CPU backend for the free functions).

use crate::camera::Camera;
use t2tf_core::error::{ErrorKind, Hint};
use t2tf_core::image::Image;
use t2tf_tf::{Lut, LutGrad};
use t2tf_volume::Volume;

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
/// Mip level of pictures for people (`t2tf render`, the benchmarks' held-out views): full
/// resolution. The automatic level picks a coarser one only for small pictures, and there it
/// loses everything the step gains (96² px, aneurism, ramp TF: 27.0 dB on the automatic level 1
/// against 74.0 dB on level 0), while level 0 at that size takes 0.02 s. preview.png takes the
/// automatic level instead ([`choose_level`] at its 256² px): level 0 for volumes up to about
/// 256³, a coarser level for larger ones, whose level 0 would cost its whole copy (or the
/// brick cache's traffic) for detail the picture cannot show.
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
    /// The brick cache of a level too large for memory cannot hold what one tile needs.
    #[error(
        "the brick cache holds {slots} bricks of the level in {} but one 16x16-pixel tile's rays need {needed}; raise the memory `budget` or render a coarser `level`",
        t2tf_core::units::human_bytes(*.budget as u128)
    )]
    BrickBudget {
        /// Bricks one tile needs.
        needed: usize,
        /// Bricks the cache holds.
        slots: usize,
        /// Bytes the cache may use.
        budget: u64,
    },
    /// The level's values could not be read (its source file, or memory to make them).
    #[error("{0}")]
    Source(t2tf_volume::VolumeError),
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

impl RenderError {
    /// What a front end needs to word its advice.
    pub fn hint(&self) -> Hint {
        match self {
            RenderError::Step(_) => Hint::invalid("step_size"),
            RenderError::Level { .. } => Hint::invalid("level"),
            RenderError::BrickBudget {
                needed,
                slots,
                budget,
            } => {
                // Bricks of a level are alike in size: what `needed` of them take.
                let per_brick = *budget as u128 / (*slots).max(1) as u128;
                let needed = (per_brick * *needed as u128).min(u64::MAX as u128) as u64;
                Hint::new(ErrorKind::Memory {
                    needed,
                    available: *budget,
                })
                .about("level")
            }
            RenderError::Source(v) => match v {
                t2tf_volume::VolumeError::Io { .. } => Hint::new(ErrorKind::Io),
                _ => Hint::new(ErrorKind::Volume),
            },
            _ => Hint::other(),
        }
    }
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

/// Where a renderer plugs in (ARCHITECTURE.md, "Seams"). A backend first *prepares* one mip
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
    // `optimize::adapters` implements `optimize::Renderer::backward` with this.
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
