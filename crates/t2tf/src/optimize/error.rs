//! Errors of the optimizer: every one names what went wrong in one line.

use crate::clip::Incomparable;
use crate::error::{ErrorKind, Hint};

/// Boxed error from a component the loop drives (renderer, image encoder, TF parameterization).
pub type BoxError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Why an optimization (or one of its parts) could not go on.
#[derive(Debug, thiserror::Error)]
pub enum OptimizeError {
    /// A setting is out of its valid range (its name, what is wrong).
    #[error("invalid setting `{name}`: {message}")]
    Setting {
        /// The setting by its field's name (`views`, `prior_ab`; one of
        /// `t2tf_core::error::OPTIONS`).
        name: &'static str,
        /// What is wrong with its value.
        message: String,
    },
    /// The prompt says nothing (empty or blank): checked by [`super::driver::check_prompt`],
    /// which the CLI calls before loading anything and the driver before encoding.
    #[error("the prompt is empty: say what the renderings should show")]
    EmptyPrompt,
    /// The contrastive loss needs at least one negative class.
    #[error("the contrastive loss needs at least one negative prompt, got none")]
    NoNegatives,
    /// Embeddings that cannot be compared (length mismatch, zero norm, non-finite value).
    #[error(transparent)]
    Embedding(#[from] EmbeddingError),
    /// A value that must be finite is not (where, and which index).
    #[error("non-finite {what} at index {index} in step {step}: stopping instead of corrupting the transfer function")]
    NonFinite {
        /// What was not finite ("loss", "gradient", "initial parameter", …).
        what: &'static str,
        /// Its index in the vector it belongs to.
        index: usize,
        /// The step it happened in.
        step: usize,
    },
    /// Transmittance input to the prior is unusable.
    #[error(transparent)]
    Transmittance(#[from] TransmittanceError),
    /// The initialization could not be computed. (Not a `source`: the message already
    /// includes it, and a chain printer would repeat it.)
    #[error("initialization: {0}")]
    Init(InitError),
    /// A caption list or cache file problem (the message names the file).
    #[error(transparent)]
    Captions(#[from] CaptionError),
    /// The renderer failed.
    #[error("renderer: {0}")]
    Renderer(BoxError),
    /// The image encoder (CLIP) failed.
    #[error("image encoder: {0}")]
    Encoder(BoxError),
    /// The TF parameterization failed.
    #[error("transfer-function parameters: {0}")]
    Parameters(BoxError),
}

impl OptimizeError {
    /// What a front end needs to word its advice. A component's boxed error (the renderer's,
    /// CLIP's) gives its own.
    pub fn hint(&self) -> Hint {
        match self {
            OptimizeError::Setting { name, .. } => Hint::invalid(name),
            OptimizeError::EmptyPrompt => Hint::new(ErrorKind::EmptyPrompt).about("prompt"),
            OptimizeError::NoNegatives => Hint::invalid("negatives"),
            OptimizeError::Captions(c) => c.hint(),
            OptimizeError::Renderer(e)
            | OptimizeError::Encoder(e)
            | OptimizeError::Parameters(e) => boxed_hint(e.as_ref()),
            _ => Hint::other(),
        }
    }
}

/// The hint of a component's error, where it is one of the library's.
fn boxed_hint(e: &(dyn std::error::Error + 'static)) -> Hint {
    if let Some(e) = e.downcast_ref::<crate::render::RenderError>() {
        e.hint()
    } else if let Some(e) = e.downcast_ref::<crate::clip::ClipError>() {
        e.hint()
    } else if let Some(e) = e.downcast_ref::<crate::volume::VolumeError>() {
        crate::hints::volume_hint(e)
    } else if let Some(e) = e.downcast_ref::<crate::memory::MemoryError>() {
        e.hint()
    } else if let Some(e) = e.downcast_ref::<OptimizeError>() {
        e.hint()
    } else {
        Hint::other()
    }
}

impl From<InitError> for OptimizeError {
    fn from(e: InitError) -> OptimizeError {
        OptimizeError::Init(e)
    }
}

/// Embeddings (or the images of a pixel loss) that cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum EmbeddingError {
    /// CLIP's logit scale is not a positive finite number.
    #[error("CLIP logit scale must be positive and finite, got {0}")]
    LogitScale(f64),
    /// A class embedding whose length differs from the image embedding's.
    #[error("text embedding {class} has {len} values but the image embedding has {image_len}")]
    ClassLength {
        /// Index of the class (0: the positive).
        class: usize,
        /// Its length.
        len: usize,
        /// The image embedding's length.
        image_len: usize,
    },
    /// Two embeddings of different lengths (`clip::cosine_checked`'s own words).
    #[error("{0}")]
    Lengths(Incomparable),
    /// One embedding that cannot be normalized (zero norm, non-finite value), named.
    #[error("{what} {problem}")]
    Unusable {
        /// Which embedding ("image embedding", "text embedding", "an embedding").
        what: &'static str,
        /// What is wrong with it.
        problem: Incomparable,
    },
    /// A pixel loss got a different number of renders than targets.
    #[error("{renders} renders for {targets} targets")]
    TargetCount {
        /// Renders given.
        renders: usize,
        /// Targets it was made with.
        targets: usize,
    },
    /// A pixel loss got a render of another size than its target.
    #[error("render {}x{} against target {}x{}", render.0, render.1, target.0, target.1)]
    TargetSize {
        /// The render's width and height.
        render: (usize, usize),
        /// The target's width and height.
        target: (usize, usize),
    },
}

/// Transmittance (or prior parameters) the Beta prior cannot use.
#[derive(Debug, thiserror::Error)]
pub enum TransmittanceError {
    /// No pixels.
    #[error("the Beta prior needs at least one pixel, got an empty transmittance image")]
    Empty,
    /// a or b not a positive finite number.
    #[error("Beta prior parameters must be positive and finite, got a = {a}, b = {b}")]
    Parameters {
        /// Beta parameter a.
        a: f64,
        /// Beta parameter b.
        b: f64,
    },
    /// A pixel's transmittance is NaN.
    #[error("transmittance of pixel {0} is NaN")]
    NaN(usize),
}

/// Why the paper's density initialization could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum InitError {
    /// Every voxel is non-finite, so the histogram is empty.
    #[error("the volume histogram is empty (no finite voxel): densities cannot be initialized")]
    EmptyHistogram,
    /// Control-point positions that are not ≥ 2 ascending values in [0, 1].
    #[error("control points must be at least 2 ascending positions in [0, 1], got {0:?}")]
    Positions(Vec<f64>),
    /// The target transmittance ρ is outside (0, 1).
    #[error("ρ must be in (0, 1), got {0}")]
    Rho(f64),
    /// Weights or colours that do not fit the control points.
    #[error("weights and colours must match the control points, weights finite and > 0")]
    Weights,
    /// The measured mean transmittance is not a number in [0, 1].
    #[error("mean transmittance of view V0 is {transmittance} at density scale {scale}: expected a value in [0, 1]")]
    Transmittance {
        /// What was measured.
        transmittance: f64,
        /// At this density scale.
        scale: f64,
    },
    /// No ray of the initial view meets the volume.
    #[error("no ray of the initial view sees the volume (every ray misses it or crosses only NaN voxels)")]
    NoRayHits,
}

impl CaptionError {
    /// What a front end needs to word its advice: the caption file is the `negatives_file`.
    pub fn hint(&self) -> Hint {
        match self {
            CaptionError::Read { .. } => Hint::new(ErrorKind::Io).about("negatives_file"),
            CaptionError::NotUtf8 { .. } | CaptionError::Empty { .. } => {
                Hint::invalid("negatives_file")
            }
            CaptionError::Hash { .. } => Hint::new(ErrorKind::Io),
        }
    }
}

/// A caption file (`negatives_file`) or a weights file hashed for the caption cache could not
/// be used. Each message names the file. (The io error is a field named `error`, not `source`,
/// so a chain printer does not print it twice.)
#[derive(Debug, thiserror::Error)]
pub enum CaptionError {
    /// The caption file could not be read.
    #[error("{}: cannot read caption file: {error}", path.display())]
    Read {
        /// The caption file.
        path: std::path::PathBuf,
        /// Why reading failed.
        error: std::io::Error,
    },
    /// The caption file is not UTF-8.
    #[error("{}: not UTF-8 text (invalid byte at offset {offset})", path.display())]
    NotUtf8 {
        /// The caption file.
        path: std::path::PathBuf,
        /// Offset of the first invalid byte.
        offset: usize,
    },
    /// The caption file holds no captions.
    #[error("{}: holds no captions (one per line expected)", path.display())]
    Empty {
        /// The caption file.
        path: std::path::PathBuf,
    },
    /// A file to hash for the cache key could not be read.
    #[error("{}: cannot read to hash it: {error}", path.display())]
    Hash {
        /// The file being hashed.
        path: std::path::PathBuf,
        /// Why reading failed.
        error: std::io::Error,
    },
}
