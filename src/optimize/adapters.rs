//! The optimizer's traits on the real components: the renderer (`crate::render`), CLIP
//! (`crate::clip`) and the paper's TF parameterization (`crate::tf::TfParams`).

use crate::background::{self, BackgroundKind};
use crate::camera::{Camera, Orbit, UpAxis};
use crate::clip::{Clip, ImageCache};
use crate::image::Image;
use crate::render::{self, RenderOptions, Rendered};
use crate::tf::{ControlPoints, Lut, LutGrad, TfParams};
use crate::volume::Volume;

use super::driver::TextEncoder;
use super::{Background, BoxError, ImageEncoder, Parameterization, PointGrad, Renderer, View};

/// Side of each view in preview.png when CLIP's input is smaller.
pub const PREVIEW_SIZE: usize = 256;

/// The differentiable renderer on one volume, at CLIP's image size.
pub struct VolumeRenderer<'a> {
    pub volume: &'a Volume,
    pub options: RenderOptions,
    pub up: UpAxis,
    /// Square image side (CLIP's `image_size()`).
    pub size: usize,
    /// Jitter sample positions per view (seeded by `View::seed`).
    pub jitter: bool,
}

impl VolumeRenderer<'_> {
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

    fn background(&self, view: &View) -> Image {
        self.background_sized(view, self.size)
    }

    fn background_sized(&self, view: &View, size: usize) -> Image {
        let (kind, seed) = match view.background {
            Background::Gray { level } => (BackgroundKind::Gray(Some(level as f32)), 0),
            Background::Checkerboard { seed } => (BackgroundKind::Checkerboard, seed),
            Background::Noise { seed } => (BackgroundKind::Noise, seed),
            Background::Fourier { seed } => (BackgroundKind::Fourier, seed),
        };
        background::generate(kind, size, size, seed)
    }
}

impl Renderer for VolumeRenderer<'_> {
    type Tape = (Camera, Rendered);

    fn render(&self, lut: &Lut, view: &View) -> Result<(Image, Vec<f32>, Self::Tape), BoxError> {
        let camera = self.camera(view)?;
        let bg = self.background(view);
        let r = render::forward(self.volume, lut, &camera, &bg, &self.options(view))?;
        Ok((r.image.clone(), r.transmittance.clone(), (camera, r)))
    }

    /// preview.png views at least `PREVIEW_SIZE` pixels wide, whatever CLIP's input size.
    fn render_preview(&self, lut: &Lut, view: &View) -> Result<Image, BoxError> {
        let size = self.size.max(PREVIEW_SIZE);
        let camera = self.camera(view)?;
        let bg = self.background_sized(view, size);
        Ok(render::forward(self.volume, lut, &camera, &bg, &self.options(view))?.image)
    }

    fn backward(
        &self,
        lut: &Lut,
        view: &View,
        tape: &Self::Tape,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<LutGrad, BoxError> {
        let (camera, rendered) = tape;
        Ok(render::backward_from(
            self.volume,
            lut,
            camera,
            rendered,
            &self.options(view),
            d_image,
            d_transmittance,
        )?)
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
}

/// The paper's parameterization (`TfParams`) with `k` control points, LUT of `lut_size`.
pub struct PaperTf {
    pub k: usize,
    pub lut_size: usize,
}

impl PaperTf {
    fn params(&self, flat: &[f64]) -> Result<TfParams, BoxError> {
        TfParams::from_flat(self.k, flat).ok_or_else(|| {
            format!(
                "{} parameters do not describe a TF of {} control points",
                flat.len(),
                self.k
            )
            .into()
        })
    }
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
        let cp = p.control_points();
        let mut g = cp.lut_backward(self.lut_size, lut);
        for (a, b) in g.sigma.iter_mut().zip(&direct.sigma) {
            *a += b;
        }
        for (a, b) in g.rgb.iter_mut().zip(&direct.rgb) {
            for c in 0..3 {
                a[c] += b[c];
            }
        }
        Ok(p.backward(&g).to_flat())
    }
}
