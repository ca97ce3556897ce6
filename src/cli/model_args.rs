//! The CLIP model flags every command that loads a model shares.

use std::path::{Path, PathBuf};

use crate::clip::packed::{with_precision, Precision};
use crate::clip::{Clip, ModelFiles, ModelRequest, DEFAULT_MODEL, DEFAULT_REVISION};

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

    /// Number format of CLIP's weight products: f32, bf16 (weights and activations rounded to
    /// bf16, f32 accumulation; needs AVX512_BF16) or auto (bf16 where the CPU has it). f32 is
    /// the default: bf16's end-to-end effect on a run is not measured yet (BENCHMARKS.md).
    #[arg(long, value_name = "f32|bf16|auto", default_value = "f32")]
    pub precision: String,
}

impl ModelArgs {
    /// `--precision` for this CPU, or why it cannot be had.
    pub fn precision(&self) -> anyhow::Result<Precision> {
        Precision::resolve(&self.precision).map_err(|e| anyhow::anyhow!("--precision: {e}"))
    }

    /// Resolve `--model` once to its files (a local folder, or the Hub cache, downloading on
    /// first use), to be loaded at `precision` (from [`ModelArgs::precision`]).
    pub fn resolve(&self, precision: Precision) -> anyhow::Result<ChosenModel> {
        let files = crate::clip::load::resolve(&self.request())?;
        Ok(ChosenModel {
            files,
            precision,
            // A local folder has no revision.
            revision: (!Path::new(&self.model).is_dir()).then(|| self.revision.clone()),
        })
    }

    /// What to load.
    pub fn request(&self) -> ModelRequest {
        ModelRequest {
            model: self.model.clone(),
            revision: self.revision.clone(),
            tokenizer: self.tokenizer.clone(),
        }
    }
}

/// The model the flags chose, resolved once by [`ModelArgs::resolve`].
pub struct ChosenModel {
    /// Its config, tokenizer and weight files.
    pub files: ModelFiles,
    /// The number format of its weight products on this CPU.
    pub precision: Precision,
    /// The Hub revision asked for; `None` for a local folder.
    pub revision: Option<String>,
}

impl ChosenModel {
    /// Load the model at its precision.
    pub fn load(&self) -> anyhow::Result<Clip> {
        Ok(with_precision(self.precision, || {
            Clip::load_files(&self.files)
        })?)
    }
}
