//! The CLIP model flags every command that loads a model shares.

use std::path::PathBuf;

use crate::clip::{Clip, Compute, ModelRequest, Precision, DEFAULT_MODEL, DEFAULT_REVISION};
use crate::hub::HubSettings;
use crate::memory::Budget;
use crate::pipeline::{Model, ModelOptions};

/// `--model`, `--revision`, `--tokenizer`.
#[derive(clap::Args, Debug, Clone)]
pub struct ModelArgs {
    /// CLIP model: a Hugging Face repo id (downloaded into the Hugging Face cache on first use)
    /// or a local folder with config.json, tokenizer.json and the weights (model.safetensors,
    /// pytorch_model.bin, or their sharded forms), or with OpenCLIP's open_clip_config.json,
    /// tokenizer.json and open_clip_pytorch_model.bin (or open_clip_model.safetensors).
    #[arg(long, value_name = "REPO_ID|DIR", default_value = DEFAULT_MODEL)]
    pub model: String,

    /// Branch, tag, pull-request ref (refs/pr/N) or commit of a Hub model.
    #[arg(long, value_name = "REV", default_value = DEFAULT_REVISION)]
    pub revision: String,

    /// tokenizer.json to use instead of the model's own (e.g. `../shared/data/clip/tokenizer.json`).
    #[arg(long, value_name = "PATH")]
    pub tokenizer: Option<PathBuf>,

    /// Number format of CLIP's weight products: auto (bf16 where the CPU has a bf16 kernel,
    /// AMX or AVX512_BF16, and a calibration measures it at least 1.15× as fast as f32, else
    /// f32; the calibration is kept per CPU in the cache folder, so every run on a machine
    /// picks alike, and report.json records the choice), f32 (bit-reproducible across
    /// machines and thread counts) or bf16 (weights and activations rounded to bf16, f32
    /// accumulation). A default run with auto (bf16 there) took 0.58× the f32 time on Zen 4 and
    /// ends on another TF than f32's: bf16 rounding changes the path of the descent
    /// (BENCHMARKS.md, "Precision").
    #[arg(long, value_name = "auto|f32|bf16", default_value = "auto")]
    pub precision: String,
}

impl ModelArgs {
    /// `--precision` for this CPU, or why it cannot be had. An explicit bf16 that this CPU
    /// runs slower than f32 is honoured with a warning.
    pub fn precision(&self) -> anyhow::Result<Precision> {
        let cache = crate::optimize::captions::cache_dir();
        let p = Precision::resolve_cached(&self.precision, cache.as_deref())
            .map_err(|e| anyhow::anyhow!("--precision: {e}"))?;
        if self.precision == "bf16" {
            if let Some(s) = crate::clip::bf16_speedup().filter(|s| *s < 1.0) {
                errln!(
                    "t2tf: warning: --precision bf16 measures {s:.2}× f32's speed on this CPU: f32 is faster here (and exact)"
                );
            }
        }
        Ok(p)
    }

    /// How the model's products run: `--precision` on the faster engine of this CPU.
    pub fn compute(&self) -> anyhow::Result<Compute> {
        let precision = self.precision()?;
        Ok(Compute {
            auto: self.precision == "auto",
            ..Compute::new(precision)
        })
    }

    /// What the library loads.
    pub fn options(&self, budget: Budget) -> anyhow::Result<ModelOptions> {
        Ok(ModelOptions {
            model: self.model.clone(),
            revision: self.revision.clone(),
            tokenizer: self.tokenizer.clone(),
            compute: self.compute()?,
            budget,
            hub: hub_settings(),
        })
    }

    /// Resolve and load the model for an optimization (its weights checked against `budget`).
    pub fn load(&self, budget: Budget) -> anyhow::Result<Model> {
        Model::load(&self.options(budget)?).map_err(crate::flags::pipeline)
    }

    /// Resolve and load the model alone.
    pub fn load_clip(&self) -> anyhow::Result<Clip> {
        let files = crate::clip::load::resolve(&self.request())?;
        Ok(Clip::load_files_with(&files, self.compute()?)?)
    }

    /// What to load.
    pub fn request(&self) -> ModelRequest {
        ModelRequest {
            model: self.model.clone(),
            revision: self.revision.clone(),
            tokenizer: self.tokenizer.clone(),
            hub: hub_settings(),
        }
    }
}

/// The `HF_*` variables' Hub settings, downloads shown on stderr.
pub fn hub_settings() -> HubSettings {
    crate::download_progress::on_stderr(HubSettings::from_env())
}
