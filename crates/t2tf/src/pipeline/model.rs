//! A CLIP model as a run uses it: resolved (a folder or the Hub cache), checked against the
//! memory budget, loaded with explicit compute settings, and hashed for the caption cache.

use std::path::{Path, PathBuf};

use sha2::Digest;

use super::PipelineError;
use crate::clip::{Clip, ClipConfig, Compute, ModelFiles, ModelRequest, Precision};
use crate::memory::Budget;
use crate::optimize::captions;
use crate::optimize::report::{absolute, ModelInfo};

/// What model to load and how it runs.
#[derive(Clone, Debug)]
pub struct ModelOptions {
    /// A Hugging Face repo id or a local folder with a config (config.json, or OpenCLIP's
    /// open_clip_config.json), tokenizer.json and weights.
    pub model: String,
    /// Branch, tag, pull-request ref (refs/pr/N) or commit of a Hub model.
    pub revision: String,
    /// A tokenizer.json to use instead of the model's own.
    pub tokenizer: Option<PathBuf>,
    /// Engine, precision and kernel of the weight products.
    pub compute: Compute,
    /// What the weights may take.
    pub budget: Budget,
    /// How to reach the Hugging Face Hub for a repo id; [`ModelOptions::new`] gives the
    /// public Hub and the default cache, the CLI and the Python module the `HF_*` variables'
    /// ([`crate::hub::HubSettings::from_env`]).
    pub hub: crate::hub::HubSettings,
}

impl ModelOptions {
    /// `model` at its main revision with its own tokenizer, f32 on the faster engine, within
    /// what the system has.
    pub fn new(model: impl Into<String>) -> ModelOptions {
        ModelOptions {
            model: model.into(),
            revision: crate::clip::DEFAULT_REVISION.to_string(),
            tokenizer: None,
            compute: Compute::default(),
            budget: Budget::system(),
            hub: crate::hub::HubSettings::defaults(),
        }
    }

    /// The files to load: a local folder, or the Hub cache (downloading on first use).
    fn request(&self) -> ModelRequest {
        ModelRequest {
            model: self.model.clone(),
            revision: self.revision.clone(),
            tokenizer: self.tokenizer.clone(),
            hub: self.hub.clone(),
        }
    }
}

/// CLIP loaded for a run, with what report.json and the caption cache say about it.
pub struct Model {
    clip: Clip,
    info: ModelInfo,
    /// Key of the caption-embedding cache: weights, tokenizer and config (and a precision
    /// other than f32) hashed together.
    cache_key: [u8; 32],
}

impl Model {
    /// Resolve, check and load the model `opts` names.
    pub fn load(opts: &ModelOptions) -> Result<Model, PipelineError> {
        let files = crate::clip::load::resolve(&opts.request())?;
        // A local folder has no revision.
        let local = Path::new(&opts.model).is_dir();
        let revision = (!local).then(|| opts.revision.clone());
        let mut model =
            Model::load_files(&files, &opts.model, revision, opts.compute, opts.budget)?;
        model.info.folder = local.then(|| absolute(Path::new(&opts.model)));
        Ok(model)
    }

    /// Load resolved files; `id` and `revision` are what the report names (its `folder`,
    /// the local folder, is [`Model::load`]'s to set).
    pub fn load_files(
        files: &ModelFiles,
        id: &str,
        revision: Option<String>,
        compute: Compute,
        budget: Budget,
    ) -> Result<Model, PipelineError> {
        // The f32 weights must fit before they are read.
        let config = files.read_config()?;
        budget.check(
            "the CLIP model's weights",
            Some(config.f32_bytes()),
            1,
            "choose a smaller model",
        )?;
        let compute = compute.with_one_copy(
            compute.one_copy || !keep_backward_copy(&config, compute, budget.available()),
        );
        let clip = Clip::load_files_with(files, compute)?;
        let weights_hash = captions::hash_files(&files.weights)?;
        let hex: String = weights_hash.iter().map(|b| format!("{b:02x}")).collect();
        let mut cache_key = captions::model_key(
            &weights_hash,
            &[files.tokenizer.clone(), files.config.clone()],
        )?;
        if compute.precision != Precision::F32 {
            // Embeddings computed in bf16 differ from f32 ones: their own cache entry, so a
            // later f32 run never reuses them (f32 keeps the key it always had).
            let mut h = sha2::Sha256::new();
            h.update(cache_key);
            h.update(format!(" precision={}", compute.precision.name()));
            cache_key = h.finalize().into();
        }
        let tokenizer_hash = captions::hash_files(std::slice::from_ref(&files.tokenizer))?;
        let info = ModelInfo {
            id: id.to_string(),
            revision,
            folder: None,
            tokenizer: Some(absolute(&files.tokenizer)),
            weights_sha256: Some(hex),
            tokenizer_sha256: Some(tokenizer_hash.iter().map(|b| format!("{b:02x}")).collect()),
            logit_scale: clip.logit_scale() as f64,
        };
        Ok(Model {
            clip,
            info,
            cache_key,
        })
    }

    /// The model.
    pub fn clip(&self) -> &Clip {
        &self.clip
    }

    /// What report.json says of it.
    pub fn info(&self) -> &ModelInfo {
        &self.info
    }

    /// Key of its caption-embedding cache.
    pub fn cache_key(&self) -> &[u8; 32] {
        &self.cache_key
    }
}

/// Bytes of the image tower's weights the input backward keeps a second packed copy of (its
/// linear layers and patch embedding), in f32.
fn backward_copy_bytes(config: &ClipConfig) -> u64 {
    let v = &config.vision;
    let (d, i) = (v.tower.hidden_size as u64, v.tower.intermediate_size as u64);
    let per_layer = 4 * d * d + 2 * d * i;
    let patch = v.num_channels as u64 * (v.patch_size as u64).pow(2) * d;
    let projection = d * config.projection_dim as u64;
    4 * (v.tower.num_layers as u64 * per_layer + patch + projection)
}

/// Whether the image tower's f32 layers keep a second copy of their weights for the backward:
/// where it fits ([`backward_copy_fits`]) and the layers' kernel is markedly slower without it
/// (not [`Kernel::fast_one_copy`]: with the AVX2 kernel one copy saves 351 MB with ViT-B/32
/// and the default run's step measured the same, BENCHMARKS.md).
fn keep_backward_copy(config: &ClipConfig, compute: Compute, available: u64) -> bool {
    !compute.prefers_one_copy() && backward_copy_fits(config, compute, available)
}

/// Whether the image tower's f32 layers have room for a second copy of their weights for the
/// backward (the faster backward products, [`Compute::one_copy`]): when the weights with that copy take
/// at most half of `available`, leaving the other half to the volume, the renderer and the
/// activations. With ViT-B/32 (605 MB of weights, 351 MB more with the copy) that is any
/// budget from 1.9 GB; below it the run keeps one copy, at a slower backward (BENCHMARKS.md,
/// "Memory of a default run"). bf16 layers always keep both bf16 copies (the bytes of one f32
/// copy).
fn backward_copy_fits(config: &ClipConfig, compute: Compute, available: u64) -> bool {
    if compute.precision == Precision::Bf16 && Precision::Bf16.native() {
        return true;
    }
    let with_copy = config
        .f32_bytes()
        .saturating_add(backward_copy_bytes(config));
    with_copy <= available / 2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clip::Kernel;

    #[test]
    fn the_backward_copy_is_kept_when_the_weights_with_it_take_half_the_budget() {
        let c = ClipConfig::vit_b32();
        // ViT-B/32: 351 MB more for the image tower's copy, 956 MB with it.
        assert_eq!(backward_copy_bytes(&c), 350_748_672);
        let f32 = Compute::new(Precision::F32);
        let with_copy = c.f32_bytes() + backward_copy_bytes(&c);
        assert!(backward_copy_fits(&c, f32, 2 * with_copy));
        assert!(!backward_copy_fits(&c, f32, 2 * with_copy - 1));
        assert!(!backward_copy_fits(&c, f32, 1 << 30));
        assert!(backward_copy_fits(&c, f32, 4 << 30));
    }

    #[test]
    fn one_copy_is_kept_where_its_kernel_reads_it_fast() {
        let c = ClipConfig::vit_b32();
        let f32 = Compute::new(Precision::F32);
        let kernels = Kernel::ALL.into_iter();
        for kernel in kernels.filter(|k| k.available() && k.precision() == Precision::F32) {
            let compute = f32.with_kernel(kernel).unwrap();
            let keep = keep_backward_copy(&c, compute, 64 << 30);
            assert_eq!(keep, !kernel.fast_one_copy(), "{}", kernel.name());
            // Never where the copy does not fit.
            assert!(
                !keep_backward_copy(&c, compute, 1 << 30),
                "{}",
                kernel.name()
            );
        }
        assert!(Kernel::Avx2Fma.fast_one_copy());
        assert!(!Kernel::Avx512F.fast_one_copy());
    }
}
