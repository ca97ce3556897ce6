//! The CLIP model flags every command that loads a model shares.

use std::path::PathBuf;

use crate::clip::{ModelRequest, DEFAULT_MODEL, DEFAULT_REVISION};

/// `--model`, `--revision`, `--tokenizer`.
#[derive(clap::Args, Debug, Clone)]
pub struct ModelArgs {
    /// CLIP model: a Hugging Face repo id (downloaded into the Hugging Face cache on first use)
    /// or a local folder with config.json, tokenizer.json and the weights (model.safetensors,
    /// pytorch_model.bin, or their sharded forms).
    #[arg(long, value_name = "REPO_ID|DIR", default_value = DEFAULT_MODEL)]
    pub model: String,

    /// Branch, tag, pull-request ref (refs/pr/N) or commit of a Hub model.
    #[arg(long, value_name = "REV", default_value = DEFAULT_REVISION)]
    pub revision: String,

    /// tokenizer.json to use instead of the model's own (e.g. `../shared/data/clip/tokenizer.json`).
    #[arg(long, value_name = "PATH")]
    pub tokenizer: Option<PathBuf>,
}

impl ModelArgs {
    /// What to load.
    pub fn request(&self) -> ModelRequest {
        ModelRequest {
            model: self.model.clone(),
            revision: self.revision.clone(),
            tokenizer: self.tokenizer.clone(),
        }
    }
}
