//! The optimizer's traits on the real components: the renderer (`crate::render`), CLIP
//! (`crate::clip`) and the paper's TF parameterization (`crate::tf::TfParams`).

use crate::camera::{Camera, Orbit, UpAxis};
use crate::clip::{Clip, ImageCache};
use crate::image::{resize_bilinear, resize_bilinear_adjoint, Image};
use crate::render::{self, RenderOptions, Rendered};
use crate::tf::{ControlPoints, Lut, LutGrad, TfParams};
use crate::volume::Volume;

use super::driver::TextEncoder;
use super::{BoxError, ImageEncoder, Parameterization, PointGrad, Renderer, View};

/// Side of each view in preview.png when CLIP's input is smaller.
pub const PREVIEW_SIZE: usize = 256;

/// The differentiable renderer on one volume, at CLIP's image size.
pub struct VolumeRenderer<'a> {
    pub volume: &'a Volume,
    pub options: RenderOptions,
    pub up: UpAxis,
    /// Square image side (CLIP's `image_size()`).
    pub size: usize,
    /// Side the rays are cast at. Below `size`, the volume's colour and transmittance are
    /// rendered at this size, upsampled bilinearly, and composited over the full-size
    /// background there (so CLIP still sees sharp checkerboards and noise): the renderer's
    /// work shrinks with the square of the ratio.
    pub render_size: usize,
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
        view.background.draw(size, size)
    }
}

impl Renderer for VolumeRenderer<'_> {
    /// The camera, the forward's result at `render_size`, and — when that is below `size` —
    /// the full-size background it was composited over.
    type Tape = (Camera, Rendered, Option<Image>);

    fn render(&self, lut: &Lut, view: &View) -> Result<(Image, Vec<f32>, Self::Tape), BoxError> {
        let camera = self.camera(view)?;
        let bg = self.background(view);
        let opts = self.options(view);
        if self.render_size >= self.size {
            let r = render::forward(self.volume, lut, &camera, &bg, &opts)?;
            return Ok((r.image.clone(), r.transmittance.clone(), (camera, r, None)));
        }
        // Colour over black is the accumulated colour alone: I = up(acc) + up(T) · B.
        let (s, n) = (self.render_size, self.size);
        let r = render::forward(self.volume, lut, &camera, &Image::new(s, s), &opts)?;
        let acc = resize_bilinear(&r.image.data, (s, s), 3, (n, n));
        let t = resize_bilinear(&r.transmittance, (s, s), 1, (n, n));
        let mut image = Image::new(n, n);
        for (p, px) in image.data.chunks_exact_mut(3).enumerate() {
            for c in 0..3 {
                px[c] = acc[3 * p + c] + t[p] * bg.data[3 * p + c];
            }
        }
        Ok((image, t, (camera, r, Some(bg))))
    }

    /// preview.png views at least `PREVIEW_SIZE` pixels wide, whatever CLIP's input size.
    fn render_preview(&self, lut: &Lut, view: &View) -> Result<Image, BoxError> {
        let size = self.size.max(PREVIEW_SIZE);
        let camera = self.camera(view)?;
        let bg = self.background_sized(view, size);
        // A picture for people: final quality (BENCHMARKS.md, render defaults), not the loop's
        // cheaper settings.
        let opts = RenderOptions::final_quality();
        Ok(render::forward(self.volume, lut, &camera, &bg, &opts)?.image)
    }

    fn backward(
        &self,
        lut: &Lut,
        view: &View,
        tape: &Self::Tape,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<LutGrad, BoxError> {
        let (camera, rendered, bg) = tape;
        let opts = self.options(view);
        let Some(bg) = bg else {
            return Ok(render::backward_from(
                self.volume,
                lut,
                camera,
                rendered,
                &opts,
                d_image,
                d_transmittance,
            )?);
        };
        // Through I = up(acc) + up(T) · B: ∂/∂up(acc) = ∂/∂I, ∂/∂up(T) = ∂/∂T + Σ_c ∂/∂I_c B_c,
        // then the upsampling's transpose.
        let (s, n) = (self.render_size, self.size);
        let d_t: Vec<f32> = (0..n * n)
            .map(|p| {
                let from_image: f32 = (0..3)
                    .map(|c| d_image[3 * p + c] * bg.data[3 * p + c])
                    .sum();
                d_transmittance.get(p).copied().unwrap_or(0.0) + from_image
            })
            .collect();
        let d_acc_s = resize_bilinear_adjoint(d_image, (n, n), 3, (s, s));
        let d_t_s = resize_bilinear_adjoint(&d_t, (n, n), 1, (s, s));
        Ok(render::backward_from(
            self.volume,
            lut,
            camera,
            rendered,
            &opts,
            &d_acc_s,
            &d_t_s,
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
