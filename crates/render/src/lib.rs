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
//! is walked front to back again with the final I and T_N of the forward: the front functions
//! here march it again (memory O(pixels)); the backend's forward records each composited step
//! (value and run length) and its backward replays that record (`cpu/march.rs`), which gives
//! the same bits for less time (BENCHMARKS.md, "Renderer").
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
//! instead of 64 MiB of f32. A level whose copy does not fit the memory budget is rendered
//! through an LRU brick cache instead (`cpu/cache.rs`), with the same results. The block walk merges consecutive non-uniform bricks into one
//! sample range, which is interpolated and classified 8 samples at a time (AVX2 gathers where
//! the CPU has them, `cpu/simd.rs`, bit-identical to the scalar code) before the serial
//! compositing.
//!
//! Rays run in parallel over 16 × 16 tiles (rayon); LUT gradients are summed per tile and the
//! tiles reduced in a fixed order, so the result does not depend on the thread count.

#![warn(missing_docs)]

pub mod background;
pub mod camera;

mod backend;
pub mod cpu;

use crate::camera::Camera;
use t2tf_core::image::Image;
use t2tf_tf::{Lut, LutGrad};
use t2tf_volume::Volume;

pub use backend::{
    choose_level, level_for, Backend, RenderError, RenderOptions, Rendered, Shot,
    DEFAULT_EARLY_TERMINATION, DEFAULT_STEP, FINAL_LEVEL, FINAL_STEP, VOXELS_PER_PIXEL,
};
pub use cpu::CpuBackend;

/// The backend the functions below render with: one per process, with the system's memory
/// budget ([`t2tf_core::memory::Budget::system`]), so that its copies of levels are shared by
/// every call. A program that wants another budget makes its own [`CpuBackend`].
pub fn shared_backend() -> &'static CpuBackend {
    static SHARED: std::sync::OnceLock<CpuBackend> = std::sync::OnceLock::new();
    SHARED.get_or_init(CpuBackend::default)
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
    shared_backend().render(volume, lut, camera, background, opts)
}

impl CpuBackend {
    /// [`forward`] on this backend (its budget, its copies of levels).
    pub fn render(
        &self,
        volume: &Volume,
        lut: &Lut,
        camera: &Camera,
        background: &Image,
        opts: &RenderOptions,
    ) -> Result<Rendered, RenderError> {
        let size = (background.width, background.height);
        let level = level_for(volume, lut, camera, size, opts)?;
        let prepared = self.prepare(volume, level)?;
        cpu::forward(&prepared, lut, camera, background, opts)
    }

    /// [`orbit_sheet`] on this backend.
    pub fn orbit_sheet(
        &self,
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
            views.push(self.render(volume, lut, cam, background, opts)?.image);
        }
        views.resize(cols * n.div_ceil(cols), background.clone());
        Ok(Image::grid(&views, cols))
    }
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
    backward_to(volume, lut, camera, fin, opts, (d_image, d_transmittance))
}

/// Like [`backward`], with the image and transmittance of the forward of the same view,
/// LUT and options (its background is already in `rendered.image`).
// The same parameters as `backward` but one: both are public API and share `backward_to`.
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
    backward_to(volume, lut, camera, fin, opts, (d_image, d_transmittance))
}

/// [`backward`] and [`backward_from`], given where the final colour comes from.
fn backward_to(
    volume: &Volume,
    lut: &Lut,
    camera: &Camera,
    fin: cpu::Final,
    opts: &RenderOptions,
    (d_image, d_transmittance): (&[f32], &[f32]),
) -> Result<LutGrad, RenderError> {
    fin.check(d_image, d_transmittance)?;
    let level = level_for(volume, lut, camera, fin.size(), opts)?;
    let prepared = shared_backend().prepare(volume, level)?;
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
    shared_backend().orbit_sheet(volume, lut, cameras, background, opts)
}
