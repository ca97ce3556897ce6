//! OpenCLIP's own checkpoint layout, as the LAION repositories on the Hugging Face Hub ship it:
//! `open_clip_config.json` (`{"model_cfg": …, "preprocess_cfg": …}`, what OpenCLIP's
//! `save_config_for_hf` writes) next to a state dict under OpenCLIP's tensor names
//! (`open_clip_model.safetensors`, `open_clip_pytorch_model.safetensors` or
//! `open_clip_pytorch_model.bin`).
//!
//! The ViT towers of OpenCLIP's `CLIP` class (open_clip/model.py, transformer.py) compute what
//! `transformers`' `CLIPModel` computes; only the names and three storage conventions differ,
//! so this module maps one onto the other and the model code is shared:
//!
//! | transformers `CLIPModel` | OpenCLIP `CLIP` |
//! |---|---|
//! | `…encoder.layers.N.self_attn.{q,k,v}_proj` | `…transformer.resblocks.N.attn.in_proj_{weight,bias}`, q, k, v stacked on dim 0 |
//! | `…self_attn.out_proj`, `layer_norm1`, `layer_norm2`, `mlp.fc1`, `mlp.fc2` | `attn.out_proj`, `ln_1`, `ln_2`, `mlp.c_fc`, `mlp.c_proj` |
//! | `vision_model.embeddings.{patch_embedding.weight, class_embedding, position_embedding.weight}` | `visual.{conv1.weight, class_embedding, positional_embedding}` |
//! | `vision_model.{pre_layrnorm, post_layernorm}` | `visual.{ln_pre, ln_post}` |
//! | `visual_projection.weight` `[P, D]` (x Wᵀ) | `visual.proj` `[D, P]` (x @ proj) |
//! | `text_model.embeddings.{token_embedding.weight, position_embedding.weight}` | `token_embedding.weight`, `positional_embedding` |
//! | `text_model.final_layer_norm` | `ln_final` |
//! | `text_projection.weight` `[P, D]` | `text_projection` `[D, P]` (x @ P) |
//! | `logit_scale` | `logit_scale` |
//!
//! The config: a tower's `width` is the hidden size, `width / head_width` (vision) or `heads`
//! (text) the heads, `int(width * mlp_ratio)` the MLP width (6144 for ViT-g/14's 1408 × 4.3637),
//! `embed_dim` the projection size, `context_length` the text positions. The activation is
//! exact GELU unless `quick_gelu` is true; layer norms use ε = 1e-5 (`nn.LayerNorm`'s default).
//! Text pooling is OpenCLIP's `argmax` (the first occurrence of the largest token id, the
//! end-of-text token), which is what the legacy `eos_token_id` 2 means in this crate. Settings
//! that change the computation in ways this code does not implement (layer scale, attentional
//! pooling, timm or Hugging Face towers, custom attention blocks, a logit bias, …) are refused
//! with their name; settings that only matter for training (`patch_dropout`) are ignored, and an
//! unknown setting is refused rather than guessed at.

use std::cell::RefCell;
use std::path::Path;

use serde_json::{Map, Value};

use super::config::{json_error, kind, ClipConfig, ConfigError, Section};
use super::load::WeightFormat;
use super::preprocess::Preprocessing;
use super::source::TensorSource;
use super::weights::Checkpoint;
use super::ClipError;

/// OpenCLIP's config file name (`HF_CONFIG_NAME` in open_clip/constants.py).
pub const CONFIG: &str = "open_clip_config.json";

/// OpenCLIP weight files in the order they are looked for: OpenCLIP's own order
/// (`download_pretrained_from_hf`: `open_clip_model.safetensors`, then
/// `open_clip_pytorch_model.bin`), with `open_clip_pytorch_model.safetensors` (the name the Hub's
/// safetensors conversion bot gave some LAION repositories' copy) before the `.bin`.
pub const WEIGHT_FILES: [(&str, WeightFormat); 3] = [
    ("open_clip_model.safetensors", WeightFormat::Safetensors),
    (
        "open_clip_pytorch_model.safetensors",
        WeightFormat::Safetensors,
    ),
    ("open_clip_pytorch_model.bin", WeightFormat::PyTorch),
];

/// A model described by `open_clip_config.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct OpenClipConfig {
    /// The same architecture as a `CLIPModel` config.
    pub clip: ClipConfig,
    /// `preprocess_cfg`: mean and std, resize and crop to the image size.
    pub preprocessing: Preprocessing,
}

/// Rules for one `*_cfg` object: the keys read, the keys allowed only at the value that means
/// "off" (OpenCLIP's default), and the keys that do not change inference.
struct Keys {
    read: &'static [&'static str],
    /// `(key, allowed values as JSON text)`; absent and `null` are always allowed.
    fixed: &'static [(&'static str, &'static [&'static str])],
    ignored: &'static [&'static str],
}

const OFF: &[&str] = &["false"];
const CUSTOM_BLOCK: [(&str, &[&str]); 8] = [
    ("block_type", &["\"default\""]),
    ("qk_norm", OFF),
    ("scaled_cosine_attn", OFF),
    ("scale_heads", OFF),
    ("scale_attn_inner", OFF),
    ("scale_attn", OFF),
    ("scale_fc", OFF),
    ("act_kwargs", &[]),
];

const MODEL_KEYS: Keys = Keys {
    read: &["embed_dim", "vision_cfg", "text_cfg", "quick_gelu"],
    fixed: &[
        ("custom_text", OFF),
        ("init_logit_bias", &[]),
        ("multimodal_cfg", &[]),
    ],
    // The checkpoint holds the logit scale; its shape ([] or [1]) is accepted either way.
    ignored: &[
        "init_logit_scale",
        "nonscalar_logit_scale",
        "cast_dtype",
        "output_dict",
    ],
};

const VISION_KEYS: Keys = Keys {
    read: &[
        "layers",
        "width",
        "head_width",
        "mlp_ratio",
        "patch_size",
        "image_size",
    ],
    fixed: &[
        ("ls_init_value", &[]),
        ("attentional_pool", OFF),
        ("no_ln_pre", OFF),
        ("input_patchnorm", OFF),
        ("pos_embed_type", &["\"learnable\""]),
        ("pool_type", &["\"tok\""]),
        ("norm_kwargs", &[]),
        ("timm_model_name", &[]),
        CUSTOM_BLOCK[0],
        CUSTOM_BLOCK[1],
        CUSTOM_BLOCK[2],
        CUSTOM_BLOCK[3],
        CUSTOM_BLOCK[4],
        CUSTOM_BLOCK[5],
        CUSTOM_BLOCK[6],
        CUSTOM_BLOCK[7],
    ],
    // Training-only, output shape options, the pooler's sizes when it is off, timm settings
    // without a timm model; with 'tok' pooling a layer norm before or after the pooling is the
    // same (it is per token).
    ignored: &[
        "patch_dropout",
        "output_tokens",
        "image_seq_len",
        "final_ln_after_pool",
        "attn_pooler_queries",
        "attn_pooler_heads",
        "timm_model_pretrained",
        "timm_pool",
        "timm_proj",
        "timm_proj_bias",
        "timm_drop",
        "timm_drop_path",
        "timm_model_kwargs",
    ],
};

const TEXT_KEYS: Keys = Keys {
    read: &[
        "context_length",
        "vocab_size",
        "width",
        "heads",
        "layers",
        "mlp_ratio",
    ],
    fixed: &[
        ("text_arch", &["\"clip\""]),
        ("variable_text", OFF),
        ("ls_init_value", &[]),
        ("embed_cls", OFF),
        ("no_causal_mask", OFF),
        ("pool_type", &["\"argmax\""]),
        ("proj_bias", OFF),
        ("proj_type", &["\"linear\""]),
        ("attention_bias", &["true"]),
        ("mlp_bias", &["true"]),
        ("norm_kwargs", &[]),
        ("hf_model_name", &[]),
        CUSTOM_BLOCK[0],
        CUSTOM_BLOCK[1],
        CUSTOM_BLOCK[2],
        CUSTOM_BLOCK[3],
        CUSTOM_BLOCK[4],
        CUSTOM_BLOCK[5],
        CUSTOM_BLOCK[6],
        CUSTOM_BLOCK[7],
    ],
    // The tokenizer is the model's tokenizer.json; padding never reaches the model (captions
    // run up to their end-of-text token); a layer norm per token commutes with picking one
    // token; the rest configure the "modern" or Hugging Face text towers, refused above.
    ignored: &[
        "output_tokens",
        "pad_id",
        "bos_id",
        "eos_id",
        "hf_tokenizer_name",
        "tokenizer_mode",
        "tokenizer_kwargs",
        "tokenizer_type",
        "tiktoken_name",
        "final_ln_after_pool",
        "hf_model_pretrained",
        "hf_proj_type",
        "hf_pooler_type",
        "hf_model_config",
        "attention_mode",
        "pos_embed",
        "rope_temperature",
        "mlp_type",
        "norm_type",
        "norm_eps",
        "attn_gated",
        "pre_norm",
        "norm_placement",
        "zero_init_residual",
        "reg_tokens",
        "value_residual",
        "gate_bias",
    ],
};

const PREPROCESS_KEYS: Keys = Keys {
    read: &["mean", "std", "size"],
    fixed: &[
        ("interpolation", &["\"bicubic\""]),
        ("resize_mode", &["\"shortest\""]),
    ],
    ignored: &["fill_color"],
};

/// Every key of `section` is known to `keys`, and each fixed one has an allowed value.
fn check_keys(section: &Section, keys: &Keys, what: &str) -> Result<(), String> {
    let Some(fields) = section.fields else {
        return Ok(());
    };
    for (key, value) in fields {
        let key = key.as_str();
        if keys.read.contains(&key) || keys.ignored.contains(&key) {
            continue;
        }
        let Some((_, allowed)) = keys.fixed.iter().find(|(k, _)| *k == key) else {
            return Err(format!(
                "{} is an OpenCLIP setting this loader does not know; it reads {what}",
                section.path(key)
            ));
        };
        let ok = value.is_null()
            || allowed
                .iter()
                .any(|a| serde_json::from_str::<Value>(a).is_ok_and(|a| &a == value));
        if !ok {
            let want = if allowed.is_empty() {
                "null".to_string()
            } else {
                allowed.join(" or ")
            };
            return Err(format!(
                "{} is {value}: only {want} is supported (this loader implements OpenCLIP's plain \
                 ViT towers)",
                section.path(key)
            ));
        }
    }
    Ok(())
}

/// An object-valued field, or `None` when absent or null.
fn object<'a>(parent: &Section<'a>, field: &str) -> Result<Option<&'a Map<String, Value>>, String> {
    match parent.get(field) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Object(m)) => Ok(Some(m)),
        Some(v) => Err(format!(
            "{} is {}, not an object",
            parent.path(field),
            kind(v)
        )),
    }
}

/// `int(width * mlp_ratio)`, as OpenCLIP sizes the MLP (Python floats are f64).
fn mlp_width(s: &Section, width: usize, default_ratio: f64) -> Result<usize, String> {
    let ratio = s.float("mlp_ratio", default_ratio)?;
    let w = width as f64 * ratio;
    if !(w.is_finite() && w >= 1.0 && w < (1u64 << 52) as f64) {
        return Err(format!(
            "{} is {ratio}: the MLP width int(width × mlp_ratio) must be a positive number",
            s.path("mlp_ratio")
        ));
    }
    Ok(w as usize)
}

/// An `image_size` or `size`: one number, or `[h, w]` with h = w (the towers here are square).
fn square(s: &Section, field: &str, default: usize) -> Result<usize, String> {
    if let Some(Value::Array(items)) = s.get(field) {
        let sides: Vec<Option<u64>> = items.iter().map(Value::as_u64).collect();
        return match sides.as_slice() {
            [Some(h), Some(w)] if h == w => Ok(*h as usize),
            _ => Err(format!(
                "{} is {}: only square images (one size, or [s, s]) are supported",
                s.path(field),
                Value::Array(items.clone())
            )),
        };
    }
    s.size(field, default)
}

fn triple(s: &Section, field: &str, default: [f32; 3]) -> Result<[f32; 3], String> {
    let Some(v) = s.get(field) else {
        return Ok(default);
    };
    let bad = || format!("{} is {v}: it must be a list of 3 numbers", s.path(field));
    let items = v.as_array().ok_or_else(bad)?;
    let nums: Vec<f64> = items.iter().filter_map(Value::as_f64).collect();
    match nums.as_slice() {
        [a, b, c] if items.len() == 3 => Ok([*a as f32, *b as f32, *c as f32]),
        _ => Err(bad()),
    }
}

impl OpenClipConfig {
    /// Read `open_clip_config.json`; errors name the file and the offending setting.
    pub fn from_file(path: &Path) -> Result<OpenClipConfig, ClipError> {
        let text = t2tf_core::input::read_to_string(path).map_err(|e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        OpenClipConfig::from_json(&text).map_err(|e| ClipError::Config {
            path: path.to_path_buf(),
            msg: e.0,
        })
    }

    /// Parse the JSON text of an `open_clip_config.json`.
    pub fn from_json(json: &str) -> Result<OpenClipConfig, ConfigError> {
        OpenClipConfig::parse(json).map_err(ConfigError)
    }

    fn parse(json: &str) -> Result<OpenClipConfig, String> {
        let root: Value = serde_json::from_str(json).map_err(|e| json_error(json, &e))?;
        let obj = root
            .as_object()
            .ok_or("the top level is not a JSON object")?;
        let top = Section {
            name: "",
            fields: Some(obj),
        };
        let model = Section {
            name: "model_cfg",
            fields: Some(object(&top, "model_cfg")?.ok_or(
                "no model_cfg: an open_clip_config.json holds the model's configuration under \
                 \"model_cfg\"",
            )?),
        };
        check_keys(
            &model,
            &MODEL_KEYS,
            "embed_dim, vision_cfg, text_cfg and quick_gelu",
        )?;
        let vision = Section {
            name: "model_cfg.vision_cfg",
            fields: object(&model, "vision_cfg")?,
        };
        check_keys(
            &vision,
            &VISION_KEYS,
            "a plain ViT: layers, width, head_width, mlp_ratio, patch_size, image_size",
        )?;
        let text = Section {
            name: "model_cfg.text_cfg",
            fields: object(&model, "text_cfg")?,
        };
        check_keys(
            &text,
            &TEXT_KEYS,
            "a plain text transformer: context_length, vocab_size, width, heads, layers, \
             mlp_ratio",
        )?;
        let prep = Section {
            name: "preprocess_cfg",
            fields: object(&top, "preprocess_cfg")?,
        };
        check_keys(&prep, &PREPROCESS_KEYS, "mean, std and size")?;

        if matches!(vision.get("layers"), Some(Value::Array(_))) {
            return Err(format!(
                "{} is a list: that is OpenCLIP's ModifiedResNet image tower, which is not \
                 supported (only ViT towers)",
                vision.path("layers")
            ));
        }
        let quick_gelu = match model.get("quick_gelu") {
            None | Some(Value::Null) | Some(Value::Bool(false)) => false,
            Some(Value::Bool(true)) => true,
            Some(v) => {
                return Err(format!(
                    "{} is {v}: it must be true or false",
                    model.path("quick_gelu")
                ))
            }
        };
        let act = if quick_gelu { "quick_gelu" } else { "gelu" };

        // OpenCLIP's defaults (CLIPVisionCfg, CLIPTextCfg in open_clip/model.py).
        let v_width = vision.size("width", 768)?;
        vision.positive("width", v_width)?;
        let head_width = vision.size("head_width", 64)?;
        vision.positive("head_width", head_width)?;
        if !v_width.is_multiple_of(head_width) {
            return Err(format!(
                "{} {v_width} is not a multiple of {} {head_width}",
                vision.path("width"),
                vision.path("head_width")
            ));
        }
        let t_width = text.size("width", 512)?;
        text.positive("width", t_width)?;
        let embed_dim = match model.get("embed_dim") {
            None => return Err("model_cfg.embed_dim is missing".into()),
            Some(_) => model.size("embed_dim", 0)?,
        };
        model.positive("embed_dim", embed_dim)?;
        let image_size = square(&vision, "image_size", 224)?;

        // The same architecture as a CLIPModel config, validated by its parser (sizes, heads
        // dividing widths, the 64 GiB limit).
        let hf = serde_json::json!({
            "model_type": "clip",
            "projection_dim": embed_dim,
            "text_config": {
                "hidden_size": t_width,
                "intermediate_size": mlp_width(&text, t_width, 4.0)?,
                "num_hidden_layers": text.size("layers", 12)?,
                "num_attention_heads": text.size("heads", 8)?,
                "max_position_embeddings": text.size("context_length", 77)?,
                "vocab_size": text.size("vocab_size", 49408)?,
                "hidden_act": act,
                "layer_norm_eps": 1e-5,
                "eos_token_id": 2,
            },
            "vision_config": {
                "hidden_size": v_width,
                "intermediate_size": mlp_width(&vision, v_width, 4.0)?,
                "num_hidden_layers": vision.size("layers", 12)?,
                "num_attention_heads": v_width / head_width,
                "image_size": image_size,
                "patch_size": vision.size("patch_size", 16)?,
                "hidden_act": act,
                "layer_norm_eps": 1e-5,
            },
        });
        let clip = ClipConfig::from_json(&hf.to_string())
            .map_err(|e| format!("{} (as the equivalent CLIPModel config)", e.0))?;

        let mut preprocessing = Preprocessing::clip(image_size);
        preprocessing.mean = triple(&prep, "mean", preprocessing.mean)?;
        preprocessing.std = triple(&prep, "std", preprocessing.std)?;
        if preprocessing
            .std
            .iter()
            .any(|&s| !(s > 0.0 && s.is_finite()))
        {
            return Err(format!(
                "{} is {:?}: every entry must be positive",
                prep.path("std"),
                preprocessing.std
            ));
        }
        if prep.get("size").is_some() {
            let size = square(&prep, "size", image_size)?;
            if size != image_size {
                return Err(format!(
                    "{} is {size}, but the vision tower takes {image_size}-pixel images",
                    prep.path("size")
                ));
            }
        }
        Ok(OpenClipConfig {
            clip,
            preprocessing,
        })
    }
}

/// Where a `CLIPModel` tensor lives in an OpenCLIP state dict, and how it is stored there.
#[derive(Debug, PartialEq)]
enum Stored {
    /// Under another name, the same values.
    Same(String),
    /// A projection stored `[in, out]` (used as x @ P): the transpose of the `[out, in]` asked.
    Transposed(String),
    /// Part `k` (0 = q, 1 = k, 2 = v) of the fused in-projection, stacked on dim 0.
    Fused(String, usize),
}

/// The OpenCLIP name of an encoder layer's tensor `leaf` (below `…layers.N.`), under `block`
/// (`…resblocks.N.`).
fn layer_tensor(block: &str, leaf: &str) -> Option<Stored> {
    let (module, param) = leaf.rsplit_once('.')?;
    let fused = |k| Some(Stored::Fused(format!("{block}.attn.in_proj_{param}"), k));
    let renamed = match module {
        "self_attn.q_proj" => return fused(0),
        "self_attn.k_proj" => return fused(1),
        "self_attn.v_proj" => return fused(2),
        "self_attn.out_proj" => "attn.out_proj",
        "layer_norm1" => "ln_1",
        "layer_norm2" => "ln_2",
        "mlp.fc1" => "mlp.c_fc",
        "mlp.fc2" => "mlp.c_proj",
        _ => return None,
    };
    Some(Stored::Same(format!("{block}.{renamed}.{param}")))
}

/// Where `name` (a `CLIPModel` tensor name) is in an OpenCLIP state dict.
fn stored(name: &str) -> Option<Stored> {
    let same = |s: &str| Some(Stored::Same(s.to_string()));
    match name {
        "logit_scale" => return same("logit_scale"),
        "text_projection.weight" => return Some(Stored::Transposed("text_projection".into())),
        "visual_projection.weight" => return Some(Stored::Transposed("visual.proj".into())),
        "text_model.embeddings.token_embedding.weight" => return same("token_embedding.weight"),
        "text_model.embeddings.position_embedding.weight" => return same("positional_embedding"),
        "vision_model.embeddings.patch_embedding.weight" => return same("visual.conv1.weight"),
        "vision_model.embeddings.class_embedding" => return same("visual.class_embedding"),
        "vision_model.embeddings.position_embedding.weight" => {
            return same("visual.positional_embedding")
        }
        _ => {}
    }
    let (tower, rest) = name.split_once('.')?;
    let (prefix, norms): (&str, &[(&str, &str)]) = match tower {
        "text_model" => ("", &[("final_layer_norm", "ln_final")]),
        "vision_model" => (
            "visual.",
            &[("pre_layrnorm", "ln_pre"), ("post_layernorm", "ln_post")],
        ),
        _ => return None,
    };
    if let Some(layer) = rest.strip_prefix("encoder.layers.") {
        let (index, leaf) = layer.split_once('.')?;
        return layer_tensor(&format!("{prefix}transformer.resblocks.{index}"), leaf);
    }
    let (module, param) = rest.split_once('.')?;
    let (_, renamed) = norms.iter().find(|(hf, _)| *hf == module)?;
    Some(Stored::Same(format!("{prefix}{renamed}.{param}")))
}

/// A checkpoint in OpenCLIP's layout seen under `CLIPModel`'s tensor names.
pub(crate) struct OpenClipTensors<'a> {
    checkpoint: &'a Checkpoint,
    /// The last fused in-projection weight read: q, k and v are asked for one after another.
    fused: RefCell<Option<(String, Vec<f32>)>>,
}

impl<'a> OpenClipTensors<'a> {
    pub(crate) fn new(checkpoint: &'a Checkpoint) -> OpenClipTensors<'a> {
        OpenClipTensors {
            checkpoint,
            fused: RefCell::new(None),
        }
    }

    fn fused_part(&self, name: &str, part: usize, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let mut full_shape = shape.to_vec();
        full_shape[0] *= 3;
        let len: usize = shape.iter().product();
        let mut cache = self.fused.borrow_mut();
        if let Some((cached, values)) = cache.as_ref() {
            if cached == name {
                return Ok(values[part * len..(part + 1) * len].to_vec());
            }
        }
        let values = self.checkpoint.get(name, &full_shape)?;
        let out = values[part * len..(part + 1) * len].to_vec();
        // Only the weight matrices are worth keeping; a bias is read again.
        if shape.len() == 2 {
            *cache = Some((name.to_string(), values));
        }
        Ok(out)
    }
}

impl TensorSource for OpenClipTensors<'_> {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        match stored(name) {
            Some(Stored::Same(n)) => self.checkpoint.get(&n, shape),
            Some(Stored::Transposed(n)) => {
                let &[out, inp] = shape else {
                    return Err(ClipError::Input(format!(
                        "{name}: a projection has 2 dimensions, not {shape:?}"
                    )));
                };
                let stored = self.checkpoint.get(&n, &[inp, out])?;
                let mut t = vec![0.0f32; stored.len()];
                for (i, row) in stored.chunks_exact(out).enumerate() {
                    for (o, &v) in row.iter().enumerate() {
                        t[o * inp + i] = v;
                    }
                }
                Ok(t)
            }
            Some(Stored::Fused(n, part)) if !shape.is_empty() => self.fused_part(&n, part, shape),
            _ => Err(ClipError::Missing(format!(
                "no tensor of OpenCLIP's layout holds {name} {shape:?}"
            ))),
        }
    }

    fn rows(&self, name: &str, shape: &[usize], rows: &[u32]) -> Result<Vec<f32>, ClipError> {
        match stored(name) {
            Some(Stored::Same(n)) => self.checkpoint.rows(&n, shape, rows),
            _ => crate::source::gather_rows(name, &self.tensor(name, shape)?, shape, rows),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_clipmodel_name_has_its_openclip_place() {
        let s = |n: &str| Some(Stored::Same(n.into()));
        assert_eq!(stored("logit_scale"), s("logit_scale"));
        assert_eq!(
            stored("vision_model.encoder.layers.39.self_attn.v_proj.weight"),
            Some(Stored::Fused(
                "visual.transformer.resblocks.39.attn.in_proj_weight".into(),
                2
            ))
        );
        assert_eq!(
            stored("text_model.encoder.layers.0.self_attn.q_proj.bias"),
            Some(Stored::Fused(
                "transformer.resblocks.0.attn.in_proj_bias".into(),
                0
            ))
        );
        assert_eq!(
            stored("text_model.encoder.layers.3.mlp.fc2.bias"),
            s("transformer.resblocks.3.mlp.c_proj.bias")
        );
        assert_eq!(
            stored("vision_model.encoder.layers.1.layer_norm2.weight"),
            s("visual.transformer.resblocks.1.ln_2.weight")
        );
        assert_eq!(
            stored("vision_model.encoder.layers.1.self_attn.out_proj.weight"),
            s("visual.transformer.resblocks.1.attn.out_proj.weight")
        );
        assert_eq!(
            stored("vision_model.pre_layrnorm.bias"),
            s("visual.ln_pre.bias")
        );
        assert_eq!(
            stored("vision_model.post_layernorm.weight"),
            s("visual.ln_post.weight")
        );
        assert_eq!(
            stored("text_model.final_layer_norm.weight"),
            s("ln_final.weight")
        );
        assert_eq!(
            stored("visual_projection.weight"),
            Some(Stored::Transposed("visual.proj".into()))
        );
        assert_eq!(stored("text_model.pooler.weight"), None);
        assert_eq!(stored("vision_model.encoder.layers.1.odd.weight"), None);
    }

    #[test]
    fn vit_g14_config_gives_its_shapes() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/fixtures/clip/configs/laion-clip-vit-g-14-laion2b-s34b-b88k.open_clip_config.json"
        ))
        .unwrap();
        let c = OpenClipConfig::from_json(&text).unwrap();
        let (v, t) = (&c.clip.vision, &c.clip.text);
        assert_eq!(
            (
                v.tower.hidden_size,
                v.tower.num_layers,
                v.tower.num_heads,
                v.tower.intermediate_size
            ),
            (1408, 40, 16, 6144)
        );
        assert_eq!((v.patch_size, v.image_size), (14, 224));
        assert_eq!(
            (
                t.tower.hidden_size,
                t.tower.num_layers,
                t.tower.num_heads,
                t.tower.intermediate_size
            ),
            (1024, 24, 16, 4096)
        );
        assert_eq!(
            (t.vocab_size, t.max_positions, t.eos_token_id),
            (49408, 77, 2)
        );
        assert_eq!(c.clip.projection_dim, 1024);
        assert_eq!(v.tower.act, crate::Activation::Gelu);
        assert_eq!(t.tower.act, crate::Activation::Gelu);
        assert_eq!(v.tower.layer_norm_eps, 1e-5);
        assert_eq!(c.preprocessing, Preprocessing::clip(224));
    }

    fn err(json: &str) -> String {
        OpenClipConfig::from_json(json).unwrap_err().0
    }

    #[test]
    fn unsupported_settings_are_named() {
        let cases = [
            (r#"{}"#, "no model_cfg"),
            (
                r#"{"model_cfg": {"vision_cfg": {}}}"#,
                "embed_dim is missing",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"layers": [3, 4, 6, 3]}}}"#,
                "ModifiedResNet",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"timm_model_name": "convnext_base"}}}"#,
                "model_cfg.vision_cfg.timm_model_name is \"convnext_base\": only null",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"ls_init_value": 1e-5}}}"#,
                "ls_init_value",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "text_cfg": {"hf_model_name": "xlm-roberta-base"}}}"#,
                "model_cfg.text_cfg.hf_model_name",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "text_cfg": {"pool_type": "last"}}}"#,
                "\"argmax\"",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "init_logit_bias": -10}}"#,
                "init_logit_bias",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "multimodal_cfg": {"width": 8}}}"#,
                "multimodal_cfg",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"brand_new": 1}}}"#,
                "model_cfg.vision_cfg.brand_new is an OpenCLIP setting this loader does not know",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"width": 100, "head_width": 64}}}"#,
                "not a multiple of model_cfg.vision_cfg.head_width 64",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"mlp_ratio": -1}}}"#,
                "mlp_ratio",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "vision_cfg": {"image_size": [224, 160]}}}"#,
                "square",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "text_cfg": {"width": 100, "heads": 8}}}"#,
                "not a multiple of num_attention_heads",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8}, "preprocess_cfg": {"resize_mode": "squash"}}"#,
                "preprocess_cfg.resize_mode",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8}, "preprocess_cfg": {"std": [0.2, 0, 0.2]}}"#,
                "positive",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8}, "preprocess_cfg": {"size": 336}}"#,
                "224-pixel",
            ),
            (
                r#"{"model_cfg": {"embed_dim": 8, "text_cfg": {"layers": 1e12}}}"#,
                "over the",
            ),
        ];
        for (json, needle) in cases {
            let e = err(json);
            assert!(e.contains(needle), "{json}: {e}");
        }
        // Defaults are OpenCLIP's (ViT-B/16-like vision, 512-wide text), quick_gelu honoured,
        // training-only settings ignored.
        let c = OpenClipConfig::from_json(
            r#"{"model_cfg": {"embed_dim": 8, "quick_gelu": true,
                "vision_cfg": {"patch_dropout": 0.5, "final_ln_after_pool": true}}}"#,
        )
        .unwrap();
        assert_eq!(c.clip.vision.patch_size, 16);
        assert_eq!(c.clip.vision.tower.num_heads, 12);
        assert_eq!(c.clip.text.tower.hidden_size, 512);
        assert_eq!(c.clip.text.tower.act, crate::Activation::QuickGelu);
    }
}
