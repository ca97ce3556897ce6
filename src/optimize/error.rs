//! Errors of the optimizer: every one names what went wrong in one line.

/// Boxed error from a component the loop drives (renderer, image encoder, TF parameterization).
pub type BoxError = Box<dyn std::error::Error + Send + Sync + 'static>;

#[derive(Debug, thiserror::Error)]
pub enum OptimizeError {
    /// A setting is out of its valid range (name of the flag, what is wrong).
    #[error("invalid setting --{name}: {message}")]
    Setting { name: &'static str, message: String },
    /// The contrastive loss needs at least one negative class.
    #[error("the contrastive loss needs at least one negative prompt, got none")]
    NoNegatives,
    /// Embeddings that cannot be compared (length mismatch, zero norm, non-finite value).
    #[error("{0}")]
    Embedding(String),
    /// A value that must be finite is not (where, and which index).
    #[error("non-finite {what} at index {index} in step {step}: stopping instead of corrupting the transfer function")]
    NonFinite {
        what: &'static str,
        index: usize,
        step: usize,
    },
    /// Transmittance input to the prior is unusable.
    #[error("{0}")]
    Transmittance(String),
    /// The initialization could not be computed.
    #[error("initialization: {0}")]
    Init(String),
    /// A caption list or cache file problem (the message names the file).
    #[error("{0}")]
    Captions(String),
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
