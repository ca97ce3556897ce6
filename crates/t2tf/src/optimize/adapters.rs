//! The optimizer's traits on the real components: the renderer (through the
//! `crate::render::Backend` trait), CLIP (`crate::clip`) and the paper's TF parameterization
//! (`crate::tf::TfParams`).

use crate::camera::{Camera, Orbit, UpAxis};
use crate::clip::{Clip, ImageCache};
use crate::image::Image;
// The renderer the optimizer uses: the only backend (ARCHITECTURE.md, "Seams", render
// backends). Everything below goes through the `render::Backend` trait.
use crate::render::{self, Backend, CpuBackend, RenderOptions, Shot};
use crate::tf::{ControlPoints, Lut, LutGrad, TfParams};
use crate::volume::Volume;

use super::driver::TextEncoder;
use super::series::SeriesSteps;
use super::{BoxError, ImageEncoder, Parameterization, PointGrad, Renderer, View};

/// Side of each view in preview.png when CLIP's input is smaller.
pub const PREVIEW_SIZE: usize = 256;

/// The differentiable renderer on one volume, at CLIP's image size.
pub struct VolumeRenderer<'a> {
    /// The backend that renders (with its memory budget and its copies of levels).
    pub backend: &'a CpuBackend,
    /// The volume rendered; for a series, the one that stands for it
    /// (`SeriesSteps::representative`: geometry, data range).
    pub volume: &'a Volume,
    /// The time series whose steps `View::time` picks; `None`: `volume` at every time.
    pub series: Option<&'a SeriesSteps>,
    /// Render options of the loop (step, level, skipping).
    pub options: RenderOptions,
    /// Which world axis is up in the views.
    pub up: UpAxis,
    /// Square image side (CLIP's `image_size()`).
    pub size: usize,
    /// Side the rays are cast at. Below `size`, the volume's colour and transmittance are
    /// rendered at this size, upsampled bilinearly, and composited over the full-size
    /// background there (so CLIP still sees sharp checkerboards and noise): the renderer's
    /// work shrinks with the square of the ratio (`render::Shot::cast`).
    pub render_size: usize,
    /// Jitter sample positions per view (seeded by `View::seed`).
    pub jitter: bool,
}

/// The forward's tape: the camera, the background, the prepared level, and the backend's own
/// tape.
type Tape<B> = (
    Camera,
    Image,
    <B as Backend>::Prepared,
    <B as Backend>::Tape,
);

impl VolumeRenderer<'_> {
    /// A picture for people of `view` (preview.png's views): final quality (BENCHMARKS.md, render
    /// defaults), not the loop's cheaper settings, at least `PREVIEW_SIZE` pixels wide, on
    /// `level`, or by default the level [`render::choose_level`] picks for its pixel footprint
    /// as the loop's views do (level 0 unless the volume has more than 2 voxels per pixel
    /// there: a large volume is then neither copied nor paged through the brick cache at full
    /// resolution for a picture that cannot show it).
    pub fn render_picture(
        &self,
        lut: &Lut,
        view: &View,
        level: Option<usize>,
    ) -> Result<Image, BoxError> {
        let size = self.size.max(PREVIEW_SIZE);
        let camera = self.camera(view)?;
        let volume = self.at(view)?;
        let bg = view.background.draw(size, size);
        let opts = RenderOptions {
            level: Some(level.unwrap_or_else(|| render::choose_level(&volume, &camera, size))),
            ..RenderOptions::final_quality()
        };
        // A picture has no backward: render without recording the rays' steps.
        Ok(self
            .backend
            .render(&volume, lut, &camera, &bg, &opts)?
            .image)
    }

    /// The volume `view` renders: its time step of the series, else the volume.
    fn at(&self, view: &View) -> Result<Frame<'_>, BoxError> {
        match self.series {
            Some(s) => Ok(Frame::Step(s.step(view.time)?)),
            None => Ok(Frame::One(self.volume)),
        }
    }

    fn camera(&self, view: &View) -> Result<Camera, BoxError> {
        let orbit = Orbit {
            yaw: view.yaw,
            pitch: view.pitch,
            distance: view.distance,
            up: self.up,
        };
        Ok(Camera::orbit(&self.volume.geometry, orbit)?)
    }

    fn options(&self, view: &View) -> RenderOptions {
        RenderOptions {
            jitter_seed: self.jitter.then_some(view.seed),
            ..self.options
        }
    }

    /// Rays per side: `render_size` below CLIP's size, else CLIP's size.
    fn cast(&self) -> (usize, usize) {
        let s = self.render_size.min(self.size);
        (s, s)
    }

    /// The view's camera and background, and the prepared level it is rendered from.
    fn setup<B: Backend>(
        &self,
        backend: &B,
        lut: &Lut,
        view: &View,
        opts: &RenderOptions,
    ) -> Result<(Camera, Image, B::Prepared), BoxError> {
        let camera = self.camera(view)?;
        let bg = view.background.draw(self.size, self.size);
        let volume = self.at(view)?;
        let level = render::level_for(&volume, lut, &camera, self.cast(), opts)?;
        let prepared = backend.prepare(&volume, level)?;
        Ok((camera, bg, prepared))
    }
}

/// A volume the renderer draws: borrowed, or a step of a series shared with its cache.
enum Frame<'a> {
    One(&'a Volume),
    Step(std::sync::Arc<Volume>),
}

impl std::ops::Deref for Frame<'_> {
    type Target = Volume;

    fn deref(&self) -> &Volume {
        match self {
            Frame::One(v) => v,
            Frame::Step(v) => v,
        }
    }
}

impl Renderer for VolumeRenderer<'_> {
    /// The camera, the background, the prepared level and what the backend's backward needs.
    type Tape = Tape<CpuBackend>;

    fn render(&self, lut: &Lut, view: &View) -> Result<(Image, Vec<f32>, Self::Tape), BoxError> {
        let opts = self.options(view);
        let (camera, bg, prepared) = self.setup(self.backend, lut, view, &opts)?;
        let shot = Shot {
            camera: &camera,
            background: &bg,
            options: &opts,
            cast: self.cast(),
        };
        let (r, tape) = self.backend.forward(&prepared, lut, &shot)?;
        Ok((r.image, r.transmittance, (camera, bg, prepared, tape)))
    }

    /// preview.png views at least `PREVIEW_SIZE` pixels wide, whatever CLIP's input size.
    fn render_preview(&self, lut: &Lut, view: &View) -> Result<Image, BoxError> {
        self.render_picture(lut, view, None)
    }

    fn time_steps(&self) -> usize {
        self.series.map_or(1, SeriesSteps::len)
    }

    // The signature of `Renderer::backward` in optimize/mod.rs, which this implements.
    fn backward(
        &self,
        lut: &Lut,
        view: &View,
        tape: &Self::Tape,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<LutGrad, BoxError> {
        let (camera, bg, prepared, tape) = tape;
        let opts = self.options(view);
        let shot = Shot {
            camera,
            background: bg,
            options: &opts,
            cast: self.cast(),
        };
        Ok(self
            .backend
            .backward(prepared, lut, &shot, tape, d_image, d_transmittance)?)
    }
}

/// CLIP's towers.
pub struct ClipModel<'a>(pub &'a Clip);

impl ImageEncoder for ClipModel<'_> {
    type Cache = ImageCache;

    fn encode(&self, images: &[Image]) -> Result<(Vec<Vec<f32>>, ImageCache), BoxError> {
        Ok(self.0.encode_images(images)?)
    }

    fn backward(&self, cache: &ImageCache, d: &[Vec<f32>]) -> Result<Vec<Image>, BoxError> {
        Ok(self.0.image_backward(cache, d)?)
    }

    fn prepare(&self, picture: &Image) -> Image {
        self.0.preprocess(picture)
    }
}

impl TextEncoder for ClipModel<'_> {
    fn encode_text(&self, texts: &[&str]) -> Result<Vec<Vec<f32>>, BoxError> {
        Ok(self.0.encode_text(texts)?)
    }

    fn texts_done(&self) {
        self.0.release_text();
    }
}

/// The paper's parameterization (`TfParams`) with `k` control points, LUT of `lut_size`.
pub struct PaperTf {
    /// Control points.
    pub k: usize,
    /// Entries of the LUT the control points are sampled into.
    pub lut_size: usize,
}

impl PaperTf {
    fn params(&self, flat: &[f64]) -> Result<TfParams, BoxError> {
        tf_params(self.k, flat)
    }
}

/// `flat` as the parameters of a TF of `k` points, or why not.
pub(crate) fn tf_params(k: usize, flat: &[f64]) -> Result<TfParams, BoxError> {
    TfParams::from_flat(k, flat).ok_or_else(|| {
        format!(
            "{} parameters do not describe a TF of {k} control points",
            flat.len()
        )
        .into()
    })
}

/// d loss / d control points: the LUT gradient through `to_lut(lut_size)` plus the terms that
/// act on the points directly. Every parameterization's backward starts here.
pub(crate) fn point_gradient(
    cp: &ControlPoints,
    lut_size: usize,
    lut: &LutGrad,
    direct: &PointGrad,
) -> crate::tf::ControlPointsGrad {
    let mut g = cp.lut_backward(lut_size, lut);
    for (a, b) in g.sigma.iter_mut().zip(&direct.sigma) {
        *a += b;
    }
    for (a, b) in g.rgb.iter_mut().zip(&direct.rgb) {
        for c in 0..3 {
            a[c] += b[c];
        }
    }
    g
}

impl Parameterization for PaperTf {
    fn control_points(&self, flat: &[f64]) -> Result<ControlPoints, BoxError> {
        Ok(self.params(flat)?.control_points())
    }

    fn lut_size(&self) -> usize {
        self.lut_size
    }

    fn params_for(&self, cp: &ControlPoints) -> Result<Vec<f64>, BoxError> {
        Ok(TfParams::from_control_points(cp).to_flat())
    }

    fn backward(
        &self,
        flat: &[f64],
        lut: &LutGrad,
        direct: &PointGrad,
    ) -> Result<Vec<f64>, BoxError> {
        let p = self.params(flat)?;
        let g = point_gradient(&p.control_points(), self.lut_size, lut, direct);
        Ok(p.backward(&g).to_flat())
    }
}
