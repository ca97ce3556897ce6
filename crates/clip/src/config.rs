//! CLIP architecture from a Hugging Face `config.json` (`CLIPModel`).
//!
//! Reads every field of `transformers`' `CLIPConfig`, `CLIPTextConfig` and `CLIPVisionConfig`
//! (configuration_clip.py) that the forward pass depends on, with the same defaults and the same
//! merge rules, so the configs of every CLIP family on the Hub load as `transformers` 5.x (and
//! 4.x since 4.31) loads them:
//!
//! - **`text_config_dict` / `vision_config_dict`** (written by older `transformers`, still in the
//!   LAION OpenCLIP repositories, sometimes next to a `text_config`): when present and not null,
//!   `transformers` builds a `CLIPTextConfig` from the dict alone and overwrites `text_config`
//!   with *all* its fields. So a field comes from the dict or, if the dict lacks it, from the
//!   class default; `text_config` is ignored for every field we read (checked against
//!   `transformers` 5.23: `text_config: {"hidden_act": "gelu"}` with a `text_config_dict` that
//!   has no `hidden_act` gives `quick_gelu`).
//! - **`projection_dim`**: `CLIPModel` uses the top-level value (default 512) for both
//!   projections; the sub-configs' `projection_dim` only matters to `CLIP*ModelWithProjection`
//!   and is not read here.
//! - **`eos_token_id`**: default 49407 (`transformers` ≥ 4.31); the legacy value 2 means "pool at
//!   the largest token id" (`text::TextModel::pool_index`).
//! - **`image_size` not a multiple of `patch_size`**: the patch embedding is a stride-p
//!   convolution, so the grid is ⌊S / p⌋ and the last S mod p rows and columns are not seen,
//!   exactly as in `CLIPVisionEmbeddings`.
//! - A missing or null `text_config` / `vision_config` takes all defaults (ViT-B/32), as in
//!   `transformers`.
//!
//! Values that describe no physical model are refused with the field named: zero sizes,
//! `hidden_size` not divisible by `num_attention_heads`, `layer_norm_eps` ≤ 0 or non-finite,
//! images smaller than a patch, and configs whose weights would exceed `MAX_F32_BYTES` in f32
//! (so `"num_hidden_layers": 1e9` is an error naming the size, not an allocation abort).

use std::path::Path;

use serde_json::{Map, Value};

use super::ClipError;

/// Largest model (weights in f32) a config may describe: 64 GiB. ViT-bigG/14, the largest CLIP
/// on the Hub, is 2.54 G parameters (10.2 GB).
pub const MAX_F32_BYTES: u64 = 64 << 30;

/// The non-linearity between the two MLP layers (`hidden_act`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// `x * sigmoid(1.702 x)`, what OpenAI's CLIP was trained with.
    QuickGelu,
    /// Exact erf GELU (`gelu`, `gelu_python`): the LAION OpenCLIP models.
    Gelu,
    /// tanh approximation (`gelu_new`, `gelu_pytorch_tanh`, `gelu_fast`: the same formula).
    GeluTanh,
}

impl Activation {
    /// `transformers`' `ACT2FN` names this model implements.
    pub const NAMES: [&'static str; 6] = [
        "quick_gelu",
        "gelu",
        "gelu_python",
        "gelu_new",
        "gelu_pytorch_tanh",
        "gelu_fast",
    ];

    fn parse(name: &str) -> Option<Activation> {
        match name {
            "quick_gelu" => Some(Activation::QuickGelu),
            "gelu" | "gelu_python" => Some(Activation::Gelu),
            "gelu_new" | "gelu_pytorch_tanh" | "gelu_fast" => Some(Activation::GeluTanh),
            _ => None,
        }
    }
}

/// Shape of one transformer tower (text or vision).
#[derive(Clone, Debug, PartialEq)]
pub struct TowerConfig {
    /// Width D of the residual stream.
    pub hidden_size: usize,
    /// Width of the MLP's hidden layer.
    pub intermediate_size: usize,
    /// Number of encoder layers.
    pub num_layers: usize,
    /// Attention heads per layer (D / heads channels each).
    pub num_heads: usize,
    /// The MLP's activation.
    pub act: Activation,
    /// Layer norms' ε.
    pub layer_norm_eps: f32,
}

impl TowerConfig {
    /// Channels per attention head.
    pub fn head_dim(&self) -> usize {
        self.hidden_size / self.num_heads
    }

    /// Parameters of one encoder layer: q, k, v, out projections with biases, fc1 and fc2 with
    /// biases, two layer norms.
    fn layer_params(&self) -> u128 {
        let (d, i) = (self.hidden_size as u128, self.intermediate_size as u128);
        add(&[mul(&[4, d, d]), 4 * d, mul(&[2, d, i]), i + d, 4 * d])
    }
}

/// The text tower (`CLIPTextConfig`).
#[derive(Clone, Debug, PartialEq)]
pub struct TextConfig {
    /// Its transformer.
    pub tower: TowerConfig,
    /// Token ids are below this.
    pub vocab_size: usize,
    /// Context length; captions are truncated to this many tokens (77 for OpenAI CLIP).
    pub max_positions: usize,
    /// `eos_token_id` as stored; 2 is the legacy value meaning "pool at the largest id".
    pub eos_token_id: i64,
}

/// The vision tower (`CLIPVisionConfig`).
#[derive(Clone, Debug, PartialEq)]
pub struct VisionConfig {
    /// Its transformer.
    pub tower: TowerConfig,
    /// Side of the square input images, in pixels.
    pub image_size: usize,
    /// Side of the square patches, in pixels.
    pub patch_size: usize,
    /// Colour channels of the input (3).
    pub num_channels: usize,
}

impl VisionConfig {
    /// Patches per side: ⌊image_size / patch_size⌋ (the stride-p convolution's output size).
    pub fn grid(&self) -> usize {
        self.image_size / self.patch_size
    }
    /// Tokens per image: one class token plus grid² patches (50 for ViT-B/32, 577 for
    /// ViT-L/14 at 336 pixels).
    pub fn num_tokens(&self) -> usize {
        self.grid() * self.grid() + 1
    }
}

/// A whole `CLIPModel`.
#[derive(Clone, Debug, PartialEq)]
pub struct ClipConfig {
    /// The text tower.
    pub text: TextConfig,
    /// The vision tower.
    pub vision: VisionConfig,
    /// Length of both towers' projected embeddings.
    pub projection_dim: usize,
}

/// One contribution to the parameter count, for error messages: `what` = `count` × `each`.
struct Term {
    what: &'static str,
    count: u128,
    each: u128,
}

/// What is wrong in a configuration file's text (`config.json`,
/// `preprocessor_config.json`): the offending field and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ConfigError(pub String);

impl ClipConfig {
    /// Read `config.json`; errors name the file and the offending field.
    pub fn from_file(path: &Path) -> Result<ClipConfig, ClipError> {
        let text = t2tf_core::input::read_to_string(path).map_err(|e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        ClipConfig::from_json(&text).map_err(|e| ClipError::Config {
            path: path.to_path_buf(),
            msg: e.0,
        })
    }

    /// Parse the JSON text of a `CLIPModel` config (see the module comment for the rules).
    pub fn from_json(json: &str) -> Result<ClipConfig, ConfigError> {
        ClipConfig::parse(json).map_err(ConfigError)
    }

    /// [`ClipConfig::from_json`], the error as text.
    fn parse(json: &str) -> Result<ClipConfig, String> {
        let root: Value = serde_json::from_str(json).map_err(|e| json_error(json, &e))?;
        let obj = root
            .as_object()
            .ok_or("the top level is not a JSON object")?;
        match obj.get("model_type") {
            None | Some(Value::Null) => {}
            Some(Value::String(s)) if s == "clip" => {}
            Some(other) => {
                return Err(format!(
                    "model_type is {other}, not \"clip\": this is not a CLIPModel config"
                ))
            }
        }
        let t = Section::of(obj, "text_config")?;
        let v = Section::of(obj, "vision_config")?;
        if t.fields.is_none() && v.fields.is_none() && !obj.contains_key("model_type") {
            return Err("no text_config, vision_config or model_type: \
                        this is not a CLIPModel config"
                .into());
        }
        let top = Section {
            name: "",
            fields: Some(obj),
        };
        // Defaults are those of transformers' CLIPTextConfig / CLIPVisionConfig / CLIPConfig.
        let text = TextConfig {
            tower: t.tower(512, 2048, 12, 8)?,
            vocab_size: t.size("vocab_size", 49408)?,
            max_positions: t.size("max_position_embeddings", 77)?,
            eos_token_id: t.int("eos_token_id", 49407)?,
        };
        let vision = VisionConfig {
            tower: v.tower(768, 3072, 12, 12)?,
            image_size: v.size("image_size", 224)?,
            patch_size: v.size("patch_size", 32)?,
            num_channels: v.size("num_channels", 3)?,
        };
        let config = ClipConfig {
            text,
            vision,
            projection_dim: top.size("projection_dim", 512)?,
        };
        config.validate(&t, &v)?;
        Ok(config)
    }

    fn validate(&self, t: &Section, v: &Section) -> Result<(), String> {
        let (text, vision) = (&self.text, &self.vision);
        t.positive("vocab_size", text.vocab_size)?;
        if text.max_positions < 2 {
            return Err(format!(
                "{} is {}, it must be at least 2 (start and end tokens)",
                t.path("max_position_embeddings"),
                text.max_positions
            ));
        }
        if vision.num_channels != 3 {
            return Err(format!(
                "{} is {}, only RGB (3) is supported",
                v.path("num_channels"),
                vision.num_channels
            ));
        }
        v.positive("patch_size", vision.patch_size)?;
        if vision.image_size < vision.patch_size {
            return Err(format!(
                "{} {} is smaller than {} {}: the image holds no patch",
                v.path("image_size"),
                vision.image_size,
                v.path("patch_size"),
                vision.patch_size
            ));
        }
        if self.projection_dim == 0 {
            return Err("projection_dim is 0, it must be positive".into());
        }
        let bytes = self.params_u128().saturating_mul(4);
        if bytes > MAX_F32_BYTES as u128 {
            let terms = self.terms();
            let big = terms
                .iter()
                .max_by_key(|t| t.count.saturating_mul(t.each))
                .expect("terms");
            return Err(format!(
                "the weights this config describes would take {} in f32 ({} parameters), over \
                 the {} limit; the largest part is {} ({} × {})",
                t2tf_core::units::human_bytes(bytes),
                human_count(self.params_u128()),
                t2tf_core::units::human_bytes(MAX_F32_BYTES as u128),
                big.what,
                big.count,
                big.each
            ));
        }
        Ok(())
    }

    /// Every parameter tensor of `CLIPModel`, grouped; their sum is `parameter_count`.
    fn terms(&self) -> Vec<Term> {
        let (t, v) = (&self.text, &self.vision);
        let (dt, dv) = (t.tower.hidden_size as u128, v.tower.hidden_size as u128);
        let p = v.patch_size as u128;
        let proj = self.projection_dim as u128;
        // `grid()` without dividing by zero for a config built by hand.
        let grid = v.image_size.checked_div(v.patch_size).unwrap_or(0) as u128;
        let term = |what, count: usize, each| Term {
            what,
            count: count as u128,
            each,
        };
        vec![
            term("text vocab_size × hidden_size", t.vocab_size, dt),
            term(
                "text max_position_embeddings × hidden_size",
                t.max_positions,
                dt,
            ),
            term(
                "text num_hidden_layers × per-layer weights",
                t.tower.num_layers,
                t.tower.layer_params(),
            ),
            term("text final layer norm", 2, dt),
            term("projection_dim × text hidden_size", self.projection_dim, dt),
            term(
                "vision hidden_size × 3 patch_size²",
                v.tower.hidden_size,
                mul(&[3, p, p]),
            ),
            // class embedding, pre and post layer norms
            term("vision class embedding and layer norms", 5, dv),
            Term {
                what: "vision (⌊image_size / patch_size⌋² + 1) × hidden_size",
                count: mul(&[grid, grid]).saturating_add(1),
                each: dv,
            },
            term(
                "vision num_hidden_layers × per-layer weights",
                v.tower.num_layers,
                v.tower.layer_params(),
            ),
            Term {
                what: "projection_dim × vision hidden_size",
                count: proj,
                each: dv,
            },
            term("logit_scale", 1, 1),
        ]
    }

    fn params_u128(&self) -> u128 {
        add(&self
            .terms()
            .iter()
            .map(|t| t.count.saturating_mul(t.each))
            .collect::<Vec<_>>())
    }

    /// Number of parameters of the `CLIPModel` this config describes (text and vision towers,
    /// both projections, `logit_scale`): 151 277 313 for ViT-B/32. Saturates at `u64::MAX` for
    /// a config built by hand past the limits `from_json` enforces.
    pub fn parameter_count(&self) -> u64 {
        self.params_u128().min(u64::MAX as u128) as u64
    }

    /// Size of those parameters in f32, in bytes (`4 × parameter_count`), at most
    /// `MAX_F32_BYTES` for a config from `from_json`.
    pub fn f32_bytes(&self) -> u64 {
        self.params_u128().saturating_mul(4).min(u64::MAX as u128) as u64
    }

    /// OpenAI ViT-B/32 (`openai/clip-vit-base-patch32`), for benchmarks with random weights.
    pub fn vit_b32() -> ClipConfig {
        let t = |h, i, heads| TowerConfig {
            hidden_size: h,
            intermediate_size: i,
            num_layers: 12,
            num_heads: heads,
            act: Activation::QuickGelu,
            layer_norm_eps: 1e-5,
        };
        ClipConfig {
            text: TextConfig {
                tower: t(512, 2048, 8),
                vocab_size: 49408,
                max_positions: 77,
                eos_token_id: 2,
            },
            vision: VisionConfig {
                tower: t(768, 3072, 12),
                image_size: 224,
                patch_size: 32,
                num_channels: 3,
            },
            projection_dim: 512,
        }
    }
}

/// Where a tower's fields are read from: `text_config_dict` when present (and not null), else
/// `text_config`, else nowhere (all defaults). `name` prefixes field names in errors.
pub(crate) struct Section<'a> {
    pub(crate) name: &'static str,
    pub(crate) fields: Option<&'a Map<String, Value>>,
}

impl<'a> Section<'a> {
    fn of(obj: &'a Map<String, Value>, key: &'static str) -> Result<Section<'a>, String> {
        let dict_key = match key {
            "text_config" => "text_config_dict",
            _ => "vision_config_dict",
        };
        for name in [dict_key, key] {
            match obj.get(name) {
                Some(Value::Object(m)) => {
                    return Ok(Section {
                        name,
                        fields: Some(m),
                    })
                }
                None | Some(Value::Null) => {}
                Some(other) => return Err(format!("{name} is {}, not an object", kind(other))),
            }
        }
        Ok(Section {
            name: key,
            fields: None,
        })
    }

    pub(crate) fn path(&self, field: &str) -> String {
        if self.name.is_empty() {
            field.to_string()
        } else {
            format!("{}.{field}", self.name)
        }
    }

    pub(crate) fn get(&self, field: &str) -> Option<&'a Value> {
        self.fields.and_then(|m| m.get(field))
    }

    /// A non-negative whole number (also when written as a float, `1e9`, as Python's `json`
    /// would read it), or `default` when absent.
    pub(crate) fn size(&self, field: &str, default: usize) -> Result<usize, String> {
        let Some(v) = self.get(field) else {
            return Ok(default);
        };
        let bad = |why: &str| format!("{} is {v}: {why}", self.path(field));
        let n = match v {
            Value::Number(n) => {
                if let Some(u) = n.as_u64() {
                    u
                } else if n.as_i64().is_some() {
                    return Err(bad("it must not be negative"));
                } else {
                    let f = n.as_f64().unwrap_or(f64::NAN);
                    if f < 0.0 {
                        return Err(bad("it must not be negative"));
                    }
                    if f.fract() != 0.0 || !f.is_finite() {
                        return Err(bad("it must be a whole number"));
                    }
                    if f >= u64::MAX as f64 {
                        return Err(bad("far too large"));
                    }
                    f as u64
                }
            }
            _ => return Err(bad("it must be a whole number")),
        };
        usize::try_from(n).map_err(|_| bad("too large for this machine"))
    }

    pub(crate) fn positive(&self, field: &str, value: usize) -> Result<(), String> {
        if value == 0 {
            Err(format!("{} is 0, it must be positive", self.path(field)))
        } else {
            Ok(())
        }
    }

    fn int(&self, field: &str, default: i64) -> Result<i64, String> {
        match self.get(field) {
            None => Ok(default),
            Some(Value::Number(n)) if n.as_i64().is_some() => Ok(n.as_i64().unwrap_or(default)),
            Some(v @ Value::Array(_)) => Err(format!(
                "{} is {v}: CLIPTextModel pools at one end-of-text id, a list is not supported",
                self.path(field)
            )),
            Some(v) => Err(format!(
                "{} is {v}: it must be an integer",
                self.path(field)
            )),
        }
    }

    pub(crate) fn float(&self, field: &str, default: f64) -> Result<f64, String> {
        match self.get(field) {
            None => Ok(default),
            Some(Value::Number(n)) => Ok(n.as_f64().unwrap_or(f64::NAN)),
            Some(v) => Err(format!("{} is {v}: it must be a number", self.path(field))),
        }
    }

    pub(crate) fn string(&self, field: &str, default: &'a str) -> Result<&'a str, String> {
        match self.get(field) {
            None => Ok(default),
            Some(Value::String(s)) => Ok(s),
            Some(v) => Err(format!("{} is {v}: it must be a string", self.path(field))),
        }
    }

    fn tower(
        &self,
        hidden: usize,
        inter: usize,
        layers: usize,
        heads: usize,
    ) -> Result<TowerConfig, String> {
        let act_name = self.string("hidden_act", "quick_gelu")?;
        let act = Activation::parse(act_name).ok_or_else(|| {
            format!(
                "{} \"{act_name}\" is not supported (supported: {})",
                self.path("hidden_act"),
                Activation::NAMES.join(", ")
            )
        })?;
        let eps = self.float("layer_norm_eps", 1e-5)?;
        // The f32 the layer norm adds must itself be positive and finite.
        if !(eps > 0.0 && (eps as f32) > 0.0 && (eps as f32).is_finite()) {
            return Err(format!(
                "{} is {eps}: it must be a positive, finite number (1e-5 in CLIP)",
                self.path("layer_norm_eps")
            ));
        }
        let tc = TowerConfig {
            hidden_size: self.size("hidden_size", hidden)?,
            intermediate_size: self.size("intermediate_size", inter)?,
            num_layers: self.size("num_hidden_layers", layers)?,
            num_heads: self.size("num_attention_heads", heads)?,
            act,
            layer_norm_eps: eps as f32,
        };
        self.positive("hidden_size", tc.hidden_size)?;
        self.positive("intermediate_size", tc.intermediate_size)?;
        self.positive("num_attention_heads", tc.num_heads)?;
        if !tc.hidden_size.is_multiple_of(tc.num_heads) {
            return Err(format!(
                "{} {} is not a multiple of num_attention_heads {}",
                self.path("hidden_size"),
                tc.hidden_size,
                tc.num_heads
            ));
        }
        Ok(tc)
    }
}

pub(crate) fn kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "an object",
    }
}

/// A JSON syntax error with the offending line shown, so a non-JSON value such as Python's
/// `NaN` or `Infinity` is reported with its field.
pub(crate) fn json_error(json: &str, e: &serde_json::Error) -> String {
    let line = json
        .lines()
        .nth(e.line().saturating_sub(1))
        .map(str::trim)
        .unwrap_or("");
    let line: String = line.chars().take(120).collect();
    if line.is_empty() {
        format!("not valid JSON: {e}")
    } else {
        format!("not valid JSON: {e} (`{line}`)")
    }
}

fn mul(xs: &[u128]) -> u128 {
    xs.iter().fold(1u128, |a, &b| a.saturating_mul(b))
}

fn add(xs: &[u128]) -> u128 {
    xs.iter().fold(0u128, |a, &b| a.saturating_add(b))
}

fn human_count(n: u128) -> String {
    if n < 1_000_000 {
        n.to_string()
    } else {
        format!("{:.3e}", n as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(name: &str) -> ClipConfig {
        let path = format!(
            "{}/../../tests/fixtures/clip/configs/{name}.json",
            env!("CARGO_MANIFEST_DIR")
        );
        ClipConfig::from_file(Path::new(&path)).unwrap_or_else(|e| panic!("{path}: {e}"))
    }

    #[test]
    fn real_b32_config_loads() {
        let c = ClipConfig::from_file(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/clip/config.json"
        )))
        .unwrap();
        assert_eq!(c, ClipConfig::vit_b32());
        assert_eq!(c.vision.num_tokens(), 50);
    }

    /// (hidden, intermediate, layers, heads, act) of a tower.
    type Shape = (usize, usize, usize, usize, Activation);

    fn shape(t: &TowerConfig) -> Shape {
        (
            t.hidden_size,
            t.intermediate_size,
            t.num_layers,
            t.num_heads,
            t.act,
        )
    }

    /// Every config in tests/fixtures/clip/configs (sources in its README.md) gives the tower
    /// shapes of its family, and the parameter count the model has. Reference counts:
    /// KerasCV's CLIP presets (keras_cv/models/feature_extractor/clip/clip_presets.py) for the
    /// OpenAI models, which equal the sum over `CLIPModel.parameters()`; KerasHub's
    /// (keras_hub/src/models/clip/clip_presets.py) for the LAION ones, which are n_tokens more
    /// (its OpenAI figures are KerasCV's plus 50, 197, 257, 577: it counts the vision position
    /// ids too, it seems), so n_tokens is subtracted here. `transformers` 5.23 builds models of
    /// exactly these counts from these files.
    #[test]
    fn hub_configs_give_family_shapes_and_parameter_counts() {
        use Activation::{Gelu, QuickGelu};
        #[rustfmt::skip]
        let cases: [(&str, Shape, Shape, usize, usize, usize, u64); 11] = [
            // name, text, vision, image size, patch, projection, parameters
            ("openai-clip-vit-base-patch32", (512, 2048, 12, 8, QuickGelu),
             (768, 3072, 12, 12, QuickGelu), 224, 32, 512, 151_277_313),
            ("openai-clip-vit-base-patch32-v4.16", (512, 2048, 12, 8, QuickGelu),
             (768, 3072, 12, 12, QuickGelu), 224, 32, 512, 151_277_313),
            ("openai-clip-vit-base-patch16-ft", (512, 2048, 12, 8, QuickGelu),
             (768, 3072, 12, 12, QuickGelu), 224, 16, 512, 149_620_737),
            ("openai-clip-vit-large-patch14-v5", (768, 3072, 12, 12, QuickGelu),
             (1024, 4096, 24, 16, QuickGelu), 224, 14, 768, 427_616_513),
            ("openai-clip-vit-large-patch14-336", (768, 3072, 12, 12, QuickGelu),
             (1024, 4096, 24, 16, QuickGelu), 336, 14, 768, 427_944_193),
            ("laion-clip-vit-b-32-laion2b-ft", (512, 2048, 12, 8, Gelu),
             (768, 3072, 12, 12, Gelu), 224, 32, 512, 151_277_363 - 50),
            ("laion-clip-vit-h-14-laion2b-ft", (1024, 4096, 24, 16, Gelu),
             (1280, 5120, 32, 16, Gelu), 224, 14, 1024, 986_109_698 - 257),
            ("laion-clip-vit-h-14-laion2b-s32b-b79k.reconstructed", (1024, 4096, 24, 16, Gelu),
             (1280, 5120, 32, 16, Gelu), 224, 14, 1024, 986_109_698 - 257),
            ("laion-clip-vit-g-14-laion2b-s12b-b42k.reconstructed", (1024, 4096, 24, 16, Gelu),
             (1408, 6144, 40, 16, Gelu), 224, 14, 1024, 1_366_678_530 - 257),
            ("laion-clip-vit-bigg-14-laion2b-39b-b160k.reconstructed", (1280, 5120, 32, 20, Gelu),
             (1664, 8192, 48, 16, Gelu), 224, 14, 1280, 2_539_567_362 - 257),
            ("laion-clip-vit-l-14-laion2b-s32b-b82k.reconstructed", (768, 3072, 12, 12, Gelu),
             (1024, 4096, 24, 16, Gelu), 224, 14, 768, 427_616_513),
        ];
        for (name, text, vision, image, patch, proj, params) in cases {
            let c = fixture(name);
            assert_eq!(shape(&c.text.tower), text, "{name} text");
            assert_eq!(shape(&c.vision.tower), vision, "{name} vision");
            assert_eq!(
                (c.vision.image_size, c.vision.patch_size, c.projection_dim),
                (image, patch, proj),
                "{name}"
            );
            assert_eq!(
                (c.text.vocab_size, c.text.max_positions),
                (49408, 77),
                "{name}"
            );
            assert_eq!(c.text.tower.layer_norm_eps, 1e-5, "{name}");
            assert_eq!(c.parameter_count(), params, "{name}");
            assert_eq!(c.f32_bytes(), 4 * params, "{name}");
        }
        // The shapes that are not multiples of 16 or 64.
        let big_g = fixture("laion-clip-vit-bigg-14-laion2b-39b-b160k.reconstructed");
        assert_eq!(big_g.vision.tower.head_dim(), 104);
        assert_eq!(big_g.text.tower.num_heads, 20);
        assert_eq!(
            fixture("laion-clip-vit-h-14-laion2b-ft")
                .vision
                .tower
                .head_dim(),
            80
        );
        let g = fixture("laion-clip-vit-g-14-laion2b-s12b-b42k.reconstructed");
        assert_eq!(g.vision.tower.head_dim(), 88);
        let l336 = fixture("openai-clip-vit-large-patch14-336");
        assert_eq!(l336.vision.num_tokens(), 577);
        // Pooling: OpenAI's old configs keep the legacy eos_token_id 2; transformers 5 writes
        // 49407; a config whose text_config_dict has no eos_token_id gets the default 49407.
        assert_eq!(
            fixture("openai-clip-vit-base-patch32-v4.16")
                .text
                .eos_token_id,
            2
        );
        assert_eq!(
            fixture("openai-clip-vit-large-patch14-v5")
                .text
                .eos_token_id,
            49407
        );
        assert_eq!(big_g.text.eos_token_id, 49407);
    }

    #[test]
    fn config_dict_wins_and_its_missing_fields_take_class_defaults() {
        // As transformers 5.23 reads it (checked with CLIPConfig.from_pretrained): every field
        // comes from the *_dict or the class default, none from text_config / vision_config.
        let j = r#"{"model_type": "clip", "projection_dim": 1024,
          "text_config": {"hidden_act": "gelu", "eos_token_id": 2, "hidden_size": 1024,
                          "layer_norm_eps": 1e-6, "vocab_size": 100, "projection_dim": 7},
          "text_config_dict": {"hidden_size": 1024, "intermediate_size": 4096,
                               "num_attention_heads": 16, "num_hidden_layers": 24},
          "vision_config": {"hidden_act": "gelu", "projection_dim": 512},
          "vision_config_dict": {"hidden_size": 1280, "patch_size": 14,
                                 "num_attention_heads": 16}}"#;
        let c = ClipConfig::from_json(j).unwrap();
        let t = &c.text;
        assert_eq!(t.tower.act, Activation::QuickGelu);
        assert_eq!(t.eos_token_id, 49407);
        assert_eq!(t.tower.layer_norm_eps, 1e-5);
        assert_eq!(t.vocab_size, 49408);
        assert_eq!(
            (t.tower.hidden_size, t.tower.intermediate_size),
            (1024, 4096)
        );
        assert_eq!((t.tower.num_layers, t.tower.num_heads), (24, 16));
        let v = &c.vision;
        assert_eq!(v.tower.act, Activation::QuickGelu);
        assert_eq!((v.tower.hidden_size, v.patch_size), (1280, 14));
        assert_eq!((v.tower.num_heads, v.tower.num_layers), (16, 12));
        // CLIPModel's projections use the top-level projection_dim.
        assert_eq!(c.projection_dim, 1024);

        // A null *_dict is ignored (OpenAI's original configs); text_config is read.
        let j = r#"{"text_config": {"hidden_act": "gelu"}, "text_config_dict": null,
                    "vision_config": {"image_size": 336, "patch_size": 14},
                    "vision_config_dict": null}"#;
        let c = ClipConfig::from_json(j).unwrap();
        assert_eq!(c.text.tower.act, Activation::Gelu);
        assert_eq!(c.vision.num_tokens(), 577);
        // Sub-config projection_dim is not CLIPModel's; the top level defaults to 512.
        let j = r#"{"text_config": {"projection_dim": 768},
                    "vision_config": {"projection_dim": 768}}"#;
        assert_eq!(ClipConfig::from_json(j).unwrap().projection_dim, 512);
        // Missing towers are ViT-B/32's, as in transformers.
        let c = ClipConfig::from_json(r#"{"model_type": "clip"}"#).unwrap();
        assert_eq!(c.parameter_count(), 151_277_313);
        assert_eq!(c.text.eos_token_id, 49407);
        // Numbers written as floats are read as Python's json reads them.
        let c = ClipConfig::from_json(r#"{"text_config": {"num_hidden_layers": 6.0}}"#).unwrap();
        assert_eq!(c.text.tower.num_layers, 6);
    }

    #[test]
    fn image_size_not_a_multiple_of_patch_size_drops_the_last_pixels() {
        // CLIPVisionEmbeddings' stride-p convolution: ⌊30 / 7⌋ = 4 patches per side.
        let c = ClipConfig::from_json(r#"{"vision_config": {"image_size": 30, "patch_size": 7}}"#)
            .unwrap();
        assert_eq!((c.vision.grid(), c.vision.num_tokens()), (4, 17));
    }

    fn err(json: &str) -> String {
        ClipConfig::from_json(json).unwrap_err().0
    }

    #[test]
    fn bad_configs_say_what_is_wrong() {
        let cases: &[(&str, &[&str])] = &[
            (r#"{}"#, &["not a CLIPModel config"]),
            (r#"[1, 2]"#, &["not a JSON object"]),
            (r#"{"model_type": "siglip"}"#, &["model_type", "siglip"]),
            (
                r#"{"text_config": {"hidden_act": "relu"}}"#,
                &["text_config.hidden_act", "relu", "quick_gelu"],
            ),
            (r#"{"text_config": 5}"#, &["text_config", "not an object"]),
            (
                r#"{"vision_config_dict": {"layer_norm_eps": 0}}"#,
                &["vision_config_dict.layer_norm_eps", "positive"],
            ),
            (
                r#"{"text_config": {"layer_norm_eps": -1e-5}}"#,
                &["text_config.layer_norm_eps", "-0.00001"],
            ),
            // Below f32's smallest subnormal: zero once stored as f32.
            (
                r#"{"text_config": {"layer_norm_eps": 1e-50}}"#,
                &["layer_norm_eps"],
            ),
            (
                r#"{"text_config": {"layer_norm_eps": null}}"#,
                &["layer_norm_eps", "null"],
            ),
            // Python's json writes NaN and Infinity, which are not JSON.
            (
                "{\"text_config\": {\n  \"layer_norm_eps\": NaN\n}}",
                &["layer_norm_eps", "line 2"],
            ),
            (
                "{\"vision_config\": {\n\"layer_norm_eps\": Infinity}}",
                &["layer_norm_eps"],
            ),
            (
                r#"{"text_config": {"hidden_size": 0}}"#,
                &["text_config.hidden_size is 0"],
            ),
            (
                r#"{"text_config": {"intermediate_size": 0}}"#,
                &["text_config.intermediate_size is 0"],
            ),
            (
                r#"{"vision_config": {"num_attention_heads": 0}}"#,
                &["vision_config.num_attention_heads is 0"],
            ),
            (
                r#"{"vision_config": {"hidden_size": 100, "num_attention_heads": 3}}"#,
                &["vision_config.hidden_size 100", "num_attention_heads 3"],
            ),
            (
                r#"{"text_config": {"vocab_size": 0}}"#,
                &["text_config.vocab_size is 0"],
            ),
            (
                r#"{"text_config": {"max_position_embeddings": 1}}"#,
                &["max_position_embeddings is 1"],
            ),
            (
                r#"{"text_config": {"hidden_size": -512}}"#,
                &["hidden_size", "negative"],
            ),
            (
                r#"{"text_config": {"hidden_size": 51.5}}"#,
                &["hidden_size", "whole number"],
            ),
            (
                r#"{"text_config": {"hidden_size": "512"}}"#,
                &["hidden_size", "whole number"],
            ),
            (
                r#"{"text_config": {"hidden_size": 1e30}}"#,
                &["hidden_size", "too large"],
            ),
            (
                r#"{"text_config": {"eos_token_id": [49407, 0]}}"#,
                &["text_config.eos_token_id", "list"],
            ),
            (
                r#"{"vision_config": {"patch_size": 0}}"#,
                &["vision_config.patch_size is 0"],
            ),
            (
                r#"{"vision_config": {"image_size": 10, "patch_size": 14}}"#,
                &["image_size 10", "patch_size 14"],
            ),
            (
                r#"{"vision_config": {"num_channels": 1}}"#,
                &["num_channels is 1"],
            ),
            (
                r#"{"model_type": "clip", "projection_dim": 0}"#,
                &["projection_dim is 0"],
            ),
            (
                r#"{"model_type": "clip", "projection_dim": null}"#,
                &["projection_dim", "null"],
            ),
        ];
        for (json, needles) in cases {
            let e = err(json);
            for n in *needles {
                assert!(e.contains(n), "{json}: {n:?} not in: {e}");
            }
        }
    }

    #[test]
    fn absurd_sizes_are_refused_with_the_computed_size() {
        let e = err(r#"{"text_config": {"num_hidden_layers": 1e9}}"#);
        for n in [
            "11.2 PiB",
            "3.152e15 parameters",
            "64.0 GiB",
            "text num_hidden_layers",
        ] {
            assert!(e.contains(n), "{n:?} not in: {e}");
        }
        let e = err(r#"{"vision_config": {"image_size": 1000000, "patch_size": 1}}"#);
        assert!(e.contains("image_size / patch_size"), "{e}");
        let e = err(r#"{"text_config": {"vocab_size": 18446744073709551615}}"#);
        assert!(e.contains("text vocab_size × hidden_size"), "{e}");
        // Sizes whose products overflow 128 bits saturate rather than wrap.
        let e = err(r#"{"vision_config": {"hidden_size": 18446744073709551615,
                                           "num_attention_heads": 1,
                                           "intermediate_size": 18446744073709551615}}"#);
        assert!(e.contains("EiB"), "{e}");
        // Just under the limit is fine: ~16 G parameters.
        let ok = r#"{"text_config": {"hidden_size": 4096, "num_attention_heads": 32,
                    "intermediate_size": 16384, "num_hidden_layers": 60}}"#;
        let c = ClipConfig::from_json(ok).unwrap();
        assert!(c.f32_bytes() <= MAX_F32_BYTES && c.f32_bytes() > MAX_F32_BYTES / 2);
    }
}
