//! CLIP in Rust: tokenizer, weights, text and image encoders, and the gradient of the image
//! embedding with respect to the input pixels (what the optimizer back-propagates through).
//!
//! The model is written by hand: candle's CLIP gives no input gradient (its fused layer norm has
//! no backward), and the hand-written kernels (`packed`) are what the optimizer's time goes to.
//!
//! Parts, each reproducing a `transformers` modeling_clip.py class:
//! `config` (CLIPConfig), `weights` (safetensors or PyTorch checkpoints, one file or shards;
//! `checkpoint` reads the PyTorch ones), `tokenizer` (CLIPTokenizerFast),
//! `layers` (Linear, LayerNorm, activations), `attention` (CLIPAttention), `encoder`
//! (CLIPEncoderLayer), `tower` (CLIPEncoder), `text` (CLIPTextTransformer), `vision`
//! (CLIPVisionTransformer), `load` (files and the Hugging Face cache), `openclip` (OpenCLIP's
//! checkpoint layout read as `CLIPModel`'s), `preprocess`
//! (CLIPImageProcessor's resize + crop), `similarity` (cosine and softmax). Weight products run
//! on `packed` (weights packed at load for hand-written AVX-512F, AVX512_BF16 and AVX2 + FMA
//! kernels: the engine wherever a SIMD f32 kernel exists) or `matmul` (the `gemm` crate, where
//! no kernel applies); attention's per-head products are its own (`attention::mm`). How they
//! run is a [`Compute`] value given at load (`Clip::load_files_with`), never a global setting.
//!
//! ```no_run
//! # fn main() -> Result<(), t2tf_clip::ClipError> {
//! use t2tf_clip::{cosine, cosine_grad, Clip};
//! let clip = Clip::load("openai/clip-vit-base-patch32")?;
//! let text = clip.encode_text(&["a skull in white bone"])?;
//! let s = clip.image_size();
//! let views = vec![t2tf_core::image::Image::new(s, s); 3];
//! let (emb, cache) = clip.encode_images(&views)?;
//! let d: Vec<Vec<f32>> = emb.iter().map(|e| cosine_grad(e, &text[0])).collect();
//! let d_pixels = clip.image_backward(&cache, &d)?; // ∂Σcos/∂pixel, one Image per view
//! # let _ = (cosine(&emb[0], &text[0]), d_pixels); Ok(()) }
//! ```

#![warn(missing_docs)]

// The Hugging Face Hub client (feature `hub`, on by default; without it models load from
// local folders only). Its own docs are inside the module.
#[cfg(feature = "hub")]
pub use t2tf_hub as hub;

mod attention;
mod checkpoint;
/// `config.json`: the shapes of both towers.
pub mod config;
mod encoder;
mod layers;
/// Finding a model's files (a directory or the Hugging Face Hub).
pub mod load;
/// Products by the `gemm` crate (public only with the `bench` feature, for `bench_clip`).
#[cfg(feature = "bench")]
pub mod matmul;
#[cfg(not(feature = "bench"))]
pub(crate) mod matmul;
/// OpenCLIP's checkpoint layout (`open_clip_config.json`, OpenCLIP's tensor names).
pub mod openclip;
/// Weights packed at load for the hand-written micro-kernels, and the engine and precision
/// settings.
pub mod packed;
mod prefix;
mod preprocess;
mod similarity;
mod source;
mod text;
mod tokenizer;
mod tower;
mod vision;
mod weights;

use std::path::{Path, PathBuf};

pub use config::{Activation, ClipConfig, ConfigError};
pub use load::{Layout, ModelFiles, ModelRequest, DEFAULT_MODEL, DEFAULT_REVISION};
pub use openclip::OpenClipConfig;
pub use packed::{
    bf16_speedup, calibration, Calibration, Compute, Engine, Kernel, Precision,
    AUTO_BF16_MIN_SPEEDUP, CALIBRATION_FILE,
};
pub use preprocess::{preprocess, Preprocessing, MEAN, STD};
pub use similarity::{
    cosine, cosine_checked, cosine_grad, softmax_scaled, unit, BadLogitScale, Head, Incomparable,
    Logits, LogitsError,
};
pub use source::{RandomSource, TensorSource};
pub use tokenizer::ClipTokenizer;
pub use vision::ImageCache;
pub use weights::Checkpoint;

use std::sync::{Arc, Mutex, PoisonError};

use t2tf_core::image::Image;
use text::{TextModel, TokenTable};
use vision::VisionModel;

/// What can go wrong loading or running CLIP; every variant about a file names it.
#[derive(Debug, thiserror::Error)]
pub enum ClipError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// `config.json` (or `preprocessor_config.json`) is not a configuration this code runs.
    #[error("{path}: bad CLIP config: {msg}")]
    Config {
        /// The file.
        path: PathBuf,
        /// What is wrong in it.
        msg: String,
    },
    /// A weight file is malformed or lacks a tensor of the right shape.
    #[error("{path}: {msg}")]
    Weights {
        /// The file.
        path: PathBuf,
        /// What is wrong in it.
        msg: String,
    },
    /// `tokenizer.json` cannot be loaded or cannot encode a text.
    #[error("{path}: tokenizer: {msg}")]
    Tokenizer {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A model, file or tensor is not where it was looked for (the message says where).
    #[error("{0}")]
    Missing(String),
    /// The model request cannot be met as given (a `model` that is neither a folder nor a
    /// repo id, a folder that lacks files, a repo not in the cache offline): `hint` tells a
    /// front end which option to point to.
    #[error("{message}")]
    Request {
        /// What is wrong, naming the option by its field (`model`, `tokenizer`).
        message: String,
        /// Its kind and option.
        hint: t2tf_core::error::Hint,
    },
    /// The Hugging Face Hub or its cache could not give a file.
    #[cfg(feature = "hub")]
    #[error(transparent)]
    Hub(#[from] hub::HubError),
    /// An input the model cannot take (image size, token ids, gradient shapes).
    #[error("CLIP input: {0}")]
    Input(String),
}

impl ClipError {
    /// What a front end needs to word its advice.
    pub fn hint(&self) -> t2tf_core::error::Hint {
        use t2tf_core::error::{ErrorKind, Hint};
        match self {
            ClipError::Io { .. } => Hint::new(ErrorKind::Io),
            ClipError::Request { hint, .. } => hint.clone(),
            #[cfg(feature = "hub")]
            ClipError::Hub(e) => e.hint(),
            _ => Hint::other(),
        }
    }
}

/// A loaded CLIP model (`CLIPModel`).
pub struct Clip {
    config: ClipConfig,
    text: TextTower,
    vision: VisionModel,
    tokenizer: Option<ClipTokenizer>,
    logit_scale: f32,
    preprocessing: Preprocessing,
    compute: Compute,
}

/// The text tower, which only turns texts into embeddings: a run needs it before its loop
/// and never in it, while the image tower's weights stay for every step.
enum TextTower {
    /// Built from a tensor source at hand (random weights, a test's tensors): kept whole.
    Kept(Box<(TextModel, TokenTable)>),
    /// Built from the memory-mapped checkpoint when texts are encoded, kept until
    /// [`Clip::release_text`]; each call reads only its tokens' rows of the token table.
    FromFile {
        weights: Checkpoint,
        layout: Layout,
        built: Mutex<Option<Arc<TextModel>>>,
    },
}

impl Clip {
    /// `model`: a directory with `config.json` (or OpenCLIP's `open_clip_config.json`),
    /// `tokenizer.json` and the weights, or a Hugging
    /// Face repo id (at its `main` branch, fetched into the standard cache; `HF_HUB_OFFLINE=1`
    /// forbids the network).
    pub fn load(model: &str) -> Result<Clip, ClipError> {
        Clip::load_request(&ModelRequest::new(model))
    }

    /// As `load`, with `tokenizer.json` taken from `tokenizer` when given.
    pub fn load_with_tokenizer(model: &str, tokenizer: Option<&Path>) -> Result<Clip, ClipError> {
        let mut req = ModelRequest::new(model);
        req.tokenizer = tokenizer.map(Path::to_path_buf);
        Clip::load_request(&req)
    }

    /// Load what `req` names (model, revision, tokenizer).
    pub fn load_request(req: &ModelRequest) -> Result<Clip, ClipError> {
        Clip::load_files(&load::resolve(req)?)
    }

    /// Load what `req` names, the weight products running as `compute` says.
    pub fn load_request_with(req: &ModelRequest, compute: Compute) -> Result<Clip, ClipError> {
        Clip::load_files_with(&load::resolve(req)?, compute)
    }

    /// Load from files already resolved (see `load::resolve`), f32 on the faster engine.
    pub fn load_files(files: &ModelFiles) -> Result<Clip, ClipError> {
        Clip::load_files_with(files, Compute::default())
    }

    /// Load from files already resolved, the weight products running as `compute` says.
    pub fn load_files_with(files: &ModelFiles, compute: Compute) -> Result<Clip, ClipError> {
        let (config, prep) = files.read_config_and_preprocessing()?;
        let tok = ClipTokenizer::from_file(&files.tokenizer, config.text.max_positions)?;
        let weights = Checkpoint::open(&files.weights)?;
        // The text tower is built here once to check its tensors (shapes, values), and
        // dropped before the image tower is built: the two are never held together at load.
        with_root(&weights, files.layout, compute, |root| {
            TextModel::load(root, &config.text, config.projection_dim)?;
            TokenTable::for_ids(root, &config.text, &[])
        })?;
        t2tf_core::platform::return_freed_memory();
        let (vision, logit_scale) = with_root(&weights, files.layout, compute, |root| {
            Ok((
                VisionModel::load(root, &config.vision, config.projection_dim)?,
                root.tensor("logit_scale", &[])?[0].exp(),
            ))
        })?;
        let text = TextTower::FromFile {
            weights,
            layout: files.layout,
            built: Mutex::new(None),
        };
        let mut clip = Clip::assemble(config, text, vision, logit_scale, compute);
        // The text tower and every tensor read for packing are freed.
        t2tf_core::platform::return_freed_memory();
        clip.tokenizer = Some(tok);
        if let Some(p) = prep {
            clip.set_preprocessing(p);
        }
        Ok(clip)
    }

    /// Check resolved files without building the model (which can take many GiB): the
    /// config parses, the tokenizer loads, every weight file's header or pickle parses.
    /// Returns a one-line summary.
    pub fn check(files: &ModelFiles) -> Result<String, ClipError> {
        let (config, _) = files.read_config_and_preprocessing()?;
        ClipTokenizer::from_file(&files.tokenizer, config.text.max_positions)?;
        let weights = Checkpoint::open(&files.weights)?;
        Ok(format!(
            "{:?} weights ({:?} layout) in {} file(s), {} tensors; vision {}x{} px, patch {}, {} \
             layers",
            files.format,
            files.layout,
            files.weights.len(),
            weights.names().len(),
            config.vision.image_size,
            config.vision.image_size,
            config.vision.patch_size,
            config.vision.tower.num_layers,
        ))
    }

    /// Build the model from any tensor source (checkpoint or `RandomSource`); no tokenizer, so
    /// `encode_text` needs `set_tokenizer` first, `encode_tokens` works.
    pub fn from_source(config: ClipConfig, src: &dyn TensorSource) -> Result<Clip, ClipError> {
        Clip::from_source_with(config, src, Compute::default())
    }

    /// [`Clip::from_source`], the weight products running as `compute` says.
    pub fn from_source_with(
        config: ClipConfig,
        src: &dyn TensorSource,
        compute: Compute,
    ) -> Result<Clip, ClipError> {
        let root = source::Names::root(src, compute);
        let text = TextModel::load(&root, &config.text, config.projection_dim)?;
        let tokens = TokenTable::whole(&root, &config.text)?;
        let vision = VisionModel::load(&root, &config.vision, config.projection_dim)?;
        let logit_scale = root.tensor("logit_scale", &[])?[0].exp();
        let text = TextTower::Kept(Box::new((text, tokens)));
        Ok(Clip::assemble(config, text, vision, logit_scale, compute))
    }

    fn assemble(
        config: ClipConfig,
        text: TextTower,
        vision: VisionModel,
        logit_scale: f32,
        compute: Compute,
    ) -> Clip {
        let preprocessing = Preprocessing::clip(config.vision.image_size);
        Clip {
            config,
            text,
            vision,
            tokenizer: None,
            logit_scale,
            preprocessing,
            compute,
        }
    }

    /// How its weight products run (what it was built with).
    pub fn compute(&self) -> &Compute {
        &self.compute
    }

    /// Use `tokenizer` for `encode_text` (a model built `from_source` has none).
    pub fn set_tokenizer(&mut self, tokenizer: ClipTokenizer) {
        self.tokenizer = Some(tokenizer);
    }

    /// Use another image processor's statistics and sizes (`load_files` reads the model's
    /// `preprocessor_config.json` when it has one; CLIP's constants otherwise).
    pub fn set_preprocessing(&mut self, p: Preprocessing) {
        self.vision.set_normalization(p.mean, p.std);
        self.preprocessing = p;
    }

    /// The image processor in force: pixel mean/std, resize and crop.
    pub fn preprocessing(&self) -> &Preprocessing {
        &self.preprocessing
    }

    /// The model's configuration (`config.json`).
    pub fn config(&self) -> &ClipConfig {
        &self.config
    }

    /// Token ids of each text (with start/end tokens, truncated to the context length).
    pub fn tokenize(&self, texts: &[&str]) -> Result<Vec<Vec<u32>>, ClipError> {
        let tok = self
            .tokenizer
            .as_ref()
            .ok_or_else(|| ClipError::Input("this model was built without a tokenizer".into()))?;
        texts.iter().map(|t| tok.encode(t)).collect()
    }

    /// Projected, not normalized, text embeddings `[texts][projection_dim]`.
    pub fn encode_text(&self, texts: &[&str]) -> Result<Vec<Vec<f32>>, ClipError> {
        let ids = self.tokenize(texts)?;
        self.encode_tokens(&ids)
    }

    /// Text embeddings from token ids (each sequence as the tokenizer returns it).
    pub fn encode_tokens(&self, ids: &[Vec<u32>]) -> Result<Vec<Vec<f32>>, ClipError> {
        match &self.text {
            TextTower::Kept(kept) => kept.0.forward(ids, &kept.1),
            TextTower::FromFile {
                weights,
                layout,
                built,
            } => {
                let slot = || built.lock().unwrap_or_else(PoisonError::into_inner);
                let cached = slot().clone();
                let model = match cached {
                    Some(m) => m,
                    None => {
                        // Built outside the lock: the build runs rayon tasks, and a task this
                        // thread takes up meanwhile may encode texts too. Calls that race
                        // may each build; the first one stored is kept.
                        let m = with_root(weights, *layout, self.compute, |root| {
                            TextModel::load(root, &self.config.text, self.config.projection_dim)
                        })?;
                        Arc::clone(slot().get_or_insert_with(|| Arc::new(m)))
                    }
                };
                let tokens = with_root(weights, *layout, self.compute, |root| {
                    TokenTable::for_ids(root, &self.config.text, ids)
                })?;
                model.forward(ids, &tokens)
            }
        }
    }

    /// Free the text tower's weights until texts are encoded again (then read back from the
    /// checkpoint, ≈ 0.2 s for ViT-B/32): what a run calls once its texts are embedded, as
    /// its loop needs only the image tower. A model built from a tensor source keeps them.
    pub fn release_text(&self) {
        if let TextTower::FromFile { built, .. } = &self.text {
            built.lock().unwrap_or_else(PoisonError::into_inner).take();
            t2tf_core::platform::return_freed_memory();
        }
    }

    /// Side of the square images the vision tower takes (224 for ViT-B/32).
    pub fn image_size(&self) -> usize {
        self.config.vision.image_size
    }

    /// Projected, not normalized, image embeddings of `image_size()`² RGB images in [0, 1]
    /// (CLIP's mean/std normalisation is applied inside), and what `image_backward` needs.
    pub fn encode_images(
        &self,
        images: &[Image],
    ) -> Result<(Vec<Vec<f32>>, ImageCache), ClipError> {
        self.vision.forward(images)
    }

    /// Gradient with respect to the input pixels of a scalar loss whose gradient with respect
    /// to the embeddings `encode_images` returned is `d_embeddings`.
    pub fn image_backward(
        &self,
        cache: &ImageCache,
        d_embeddings: &[Vec<f32>],
    ) -> Result<Vec<Image>, ClipError> {
        self.vision.backward(cache, d_embeddings)
    }

    /// exp(logit_scale): the temperature CLIP multiplies cosine similarities by (100 for
    /// OpenAI's models).
    pub fn logit_scale(&self) -> f32 {
        self.logit_scale
    }

    /// How this model scores an image embedding against class embeddings (CLIP: the scaled
    /// cosine) and the gradient of those logits: what a loss asks the model for instead of
    /// knowing its formula. An error where the checkpoint's logit scale is not positive and
    /// finite.
    pub fn head(&self) -> Result<Head, ClipError> {
        Head::new(self.logit_scale as f64).map_err(|e| ClipError::Input(e.to_string()))
    }

    /// `CLIPImageProcessor`'s resize (shortest side, bicubic) and centre crop to
    /// `image_size()`², for arbitrary pictures, with the sizes of `preprocessing()`.
    pub fn preprocess(&self, image: &Image) -> Image {
        self.preprocessing.apply(image)
    }
}

/// `f` on the root names of `weights`, read in `layout`, layers running as `compute` says.
fn with_root<R>(
    weights: &Checkpoint,
    layout: Layout,
    compute: Compute,
    f: impl FnOnce(&source::Names) -> Result<R, ClipError>,
) -> Result<R, ClipError> {
    match layout {
        Layout::Transformers => f(&source::Names::root(weights, compute)),
        Layout::OpenClip => {
            let tensors = openclip::OpenClipTensors::new(weights);
            f(&source::Names::root(&tensors, compute))
        }
    }
}
