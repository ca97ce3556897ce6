//! Vision tower, `transformers` modeling_clip.py `CLIPVisionEmbeddings` + `CLIPVisionTransformer`
//! + `CLIPModel.visual_projection`, with a backward pass to the input pixels.
//!
//! Forward for B images of S×S pixels, patch p, g = S/p, n = g² + 1 tokens, width D:
//! pixels → CLIP mean/std normalisation → patch embedding (the stride-p convolution as one GEMM
//! `[B g², 3p²] · [3p², D]`) → prepend class embedding, add position embeddings `[B n, D]` →
//! pre layer norm → transformer → post layer norm of each class token `[B, D]` → projection
//! `[B, P]`.

use rayon::prelude::*;

use super::attention::Segments;
use super::config::VisionConfig;
use super::layers::{LayerNorm, Linear, LnSaved};
use super::preprocess::{MEAN, STD};
use super::source::Names;
use super::tower::{Tower, TowerSaved};
use super::ClipError;
use t2tf_core::image::Image;

pub struct VisionModel {
    pub cfg: VisionConfig,
    /// Convolution weight `[D, 3, p, p]` viewed as a linear map `[D, 3p²]`, no bias.
    patch_embedding: Linear,
    /// `[D]`
    class_embedding: Vec<f32>,
    /// `[n, D]`
    position_embedding: Vec<f32>,
    pre_ln: LayerNorm,
    tower: Tower,
    post_ln: LayerNorm,
    /// `[P, D]`, no bias
    projection: Linear,
    /// Per-channel pixel mean and std (`Preprocessing`; CLIP's constants by default).
    mean: [f32; 3],
    std: [f32; 3],
}

/// The activations `VisionModel::backward` needs, from one `forward` call.
pub struct ImageCache {
    images: usize,
    pre_ln: LnSaved,
    layers: TowerSaved,
    post_ln: LnSaved,
}

impl ImageCache {
    /// How many images the forward pass encoded.
    pub fn len(&self) -> usize {
        self.images
    }
    /// Whether it encoded no image.
    pub fn is_empty(&self) -> bool {
        self.images == 0
    }
}

impl VisionModel {
    /// The vision tower under `root` (the checkpoint's top level: `vision_model.*` and
    /// `visual_projection`), projecting to `proj` dimensions.
    pub fn load(root: &Names, cfg: &VisionConfig, proj: usize) -> Result<VisionModel, ClipError> {
        let d = cfg.tower.hidden_size;
        let p = cfg.patch_size;
        let eps = cfg.tower.layer_norm_eps;
        let model = root.pp("vision_model");
        let emb = model.pp("embeddings");
        let pe = emb.pp("patch_embedding").tensor("weight", &[d, 3, p, p])?;
        Ok(VisionModel {
            cfg: cfg.clone(),
            patch_embedding: root.linear_from(pe, None, 3 * p * p, d),
            class_embedding: emb.tensor("class_embedding", &[d])?,
            position_embedding: emb
                .pp("position_embedding")
                .tensor("weight", &[cfg.num_tokens(), d])?,
            // "pre_layrnorm" is the checkpoint's spelling.
            pre_ln: model.pp("pre_layrnorm").layer_norm(d, eps)?,
            tower: Tower::load(&model.pp("encoder"), &cfg.tower)?,
            post_ln: model.pp("post_layernorm").layer_norm(d, eps)?,
            projection: root.pp("visual_projection").linear(proj, d, false)?,
            mean: MEAN,
            std: STD,
        })
    }

    /// Normalise pixels with these per-channel statistics (a model's
    /// `preprocessor_config.json`) instead of CLIP's.
    pub fn set_normalization(&mut self, mean: [f32; 3], std: [f32; 3]) {
        self.mean = mean;
        self.std = std;
    }

    fn check(&self, images: &[Image]) -> Result<(), ClipError> {
        let s = self.cfg.image_size;
        for (i, im) in images.iter().enumerate() {
            if im.width != s || im.height != s || im.data.len() != s * s * 3 {
                return Err(ClipError::Input(format!(
                    "image {i} is {}x{}, this CLIP takes {s}x{s} (use clip::preprocess)",
                    im.width, im.height
                )));
            }
            if let Some(k) = im.data.iter().position(|v| !v.is_finite()) {
                return Err(ClipError::Input(format!(
                    "image {i} has a non-finite value at pixel {} channel {}",
                    k / 3,
                    k % 3
                )));
            }
        }
        Ok(())
    }

    /// `images`: B images of S×S RGB in [0, 1] → projected embeddings `[B][P]` and the cache
    /// for `backward`.
    pub fn forward(&self, images: &[Image]) -> Result<(Vec<Vec<f32>>, ImageCache), ClipError> {
        self.check(images)?;
        let (b, d, p, g, n) = self.dims(images.len());
        let s = self.cfg.image_size;
        let k = 3 * p * p;
        // Patch matrix [B g², 3p²], columns ordered (channel, ky, kx) like the conv weight;
        // one patch per parallel task (serial, these loops cost ~1 % of the 2-thread pass).
        let mut patches = vec![0.0f32; b * g * g * k];
        patches
            .par_chunks_mut(k)
            .enumerate()
            .for_each(|(row_index, row)| {
                let (bi, gy, gx) = (row_index / (g * g), row_index / g % g, row_index % g);
                let im = &images[bi];
                for ky in 0..p {
                    for kx in 0..p {
                        let px = ((gy * p + ky) * s + gx * p + kx) * 3;
                        for c in 0..3 {
                            row[c * p * p + ky * p + kx] =
                                (im.data[px + c] - self.mean[c]) / self.std[c];
                        }
                    }
                }
            });
        let pe = self.patch_embedding.forward(&patches, b * g * g);
        // x [B n, D]: class token then patches, plus position embeddings.
        let mut x = vec![0.0f32; b * n * d];
        x.par_chunks_mut(d)
            .enumerate()
            .for_each(|(row_index, row)| {
                let (bi, t) = (row_index / n, row_index % n);
                let src = if t == 0 {
                    &self.class_embedding[..]
                } else {
                    &pe[(bi * g * g + t - 1) * d..][..d]
                };
                let pos = &self.position_embedding[t * d..][..d];
                for ((r, a), q) in row.iter_mut().zip(src).zip(pos) {
                    *r = a + q;
                }
            });
        let (x, pre_saved) = self.pre_ln.forward(&x, true);
        let seg = Segments::uniform(b, n, false);
        let (cls, layers) = self.tower.forward_pooled(x, &seg, &vec![0; b], true);
        let (pooled, post_saved) = self.post_ln.forward(&cls, true);
        let out = self.projection.forward(&pooled, b);
        let emb = out
            .chunks_exact(self.projection.out_dim)
            .map(<[f32]>::to_vec)
            .collect();
        let cache = ImageCache {
            images: b,
            pre_ln: pre_saved.expect("saved"),
            layers,
            post_ln: post_saved.expect("saved"),
        };
        Ok((emb, cache))
    }

    /// Gradient of a scalar loss with respect to the input pixels (in [0, 1] units, through the
    /// mean/std normalisation), given its gradient `d_embeddings [B][P]` with respect to the
    /// projected embeddings `forward` returned.
    pub fn backward(
        &self,
        cache: &ImageCache,
        d_embeddings: &[Vec<f32>],
    ) -> Result<Vec<Image>, ClipError> {
        let (b, d, p, g, n) = self.dims(cache.images);
        let proj = self.projection.out_dim;
        if d_embeddings.len() != b || d_embeddings.iter().any(|v| v.len() != proj) {
            return Err(ClipError::Input(format!(
                "image_backward needs {b} gradients of length {proj} (one per encoded image)"
            )));
        }
        if d_embeddings.iter().flatten().any(|v| !v.is_finite()) {
            return Err(ClipError::Input(
                "image_backward got a non-finite gradient".into(),
            ));
        }
        let de: Vec<f32> = d_embeddings.concat();
        let d_pooled = self.projection.backward(&de, b);
        let d_cls = self.post_ln.backward(&d_pooled, &cache.post_ln);
        let seg = Segments::uniform(b, n, false);
        let dx = self
            .tower
            .backward_pooled(&d_cls, &seg, &vec![0; b], &cache.layers, d);
        let dx = self.pre_ln.backward(&dx, &cache.pre_ln);
        // Patch rows only (the class token has no pixels behind it).
        let mut d_pe = vec![0.0f32; b * g * g * d];
        d_pe.par_chunks_mut(d)
            .enumerate()
            .for_each(|(row_index, row)| {
                let (bi, t) = (row_index / (g * g), row_index % (g * g) + 1);
                row.copy_from_slice(&dx[(bi * n + t) * d..][..d]);
            });
        let d_patches = self.patch_embedding.backward(&d_pe, b * g * g);
        let s = self.cfg.image_size;
        let k = 3 * p * p;
        let mut out: Vec<Image> = (0..b).map(|_| Image::new(s, s)).collect();
        // One pixel row per parallel task; rows and columns past the g·p patch grid (an image
        // size that is not a multiple of p) keep a zero gradient.
        out.par_iter_mut().enumerate().for_each(|(bi, im)| {
            im.data
                .par_chunks_mut(s * 3)
                .take(g * p)
                .enumerate()
                .for_each(|(y, line)| {
                    let (gy, ky) = (y / p, y % p);
                    for gx in 0..g {
                        let row = &d_patches[((bi * g + gy) * g + gx) * k..][..k];
                        for kx in 0..p {
                            let px = (gx * p + kx) * 3;
                            for c in 0..3 {
                                line[px + c] = row[c * p * p + ky * p + kx] / self.std[c];
                            }
                        }
                    }
                });
        });
        Ok(out)
    }

    /// (B, D, p, g, n)
    fn dims(&self, b: usize) -> (usize, usize, usize, usize, usize) {
        let c = &self.cfg;
        (
            b,
            c.tower.hidden_size,
            c.patch_size,
            c.grid(),
            c.num_tokens(),
        )
    }
}
