//! CLIP architecture from a Hugging Face `config.json` (`CLIPModel`).
//!
//! Reproduces the fields and defaults of `transformers`' `CLIPConfig`, `CLIPTextConfig` and
//! `CLIPVisionConfig` (configuration_clip.py) that the forward pass depends on. A field missing
//! from the file takes the `transformers` default, so old and new configs of ViT-B/32, B/16 and
//! L/14 all load.

use std::path::Path;

use serde::Deserialize;

use super::ClipError;

/// The non-linearity between the two MLP layers (`hidden_act`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// `x * sigmoid(1.702 x)`, what OpenAI's CLIP was trained with.
    QuickGelu,
    /// Exact erf GELU (`gelu`).
    Gelu,
    /// tanh approximation (`gelu_new`, `gelu_pytorch_tanh`).
    GeluTanh,
}

impl Activation {
    fn parse(name: &str) -> Option<Activation> {
        match name {
            "quick_gelu" => Some(Activation::QuickGelu),
            "gelu" => Some(Activation::Gelu),
            "gelu_new" | "gelu_pytorch_tanh" | "gelu_fast" => Some(Activation::GeluTanh),
            _ => None,
        }
    }
}

/// Shape of one transformer tower (text or vision).
#[derive(Clone, Debug, PartialEq)]
pub struct TowerConfig {
    pub hidden_size: usize,
    pub intermediate_size: usize,
    pub num_layers: usize,
    pub num_heads: usize,
    pub act: Activation,
    pub layer_norm_eps: f32,
}

impl TowerConfig {
    pub fn head_dim(&self) -> usize {
        self.hidden_size / self.num_heads
    }
}

/// The text tower (`CLIPTextConfig`).
#[derive(Clone, Debug, PartialEq)]
pub struct TextConfig {
    pub tower: TowerConfig,
    pub vocab_size: usize,
    /// Context length; captions are truncated to this many tokens (77 for OpenAI CLIP).
    pub max_positions: usize,
    /// `eos_token_id` as stored; 2 is the legacy value meaning "pool at the largest id".
    pub eos_token_id: i64,
}

/// The vision tower (`CLIPVisionConfig`).
#[derive(Clone, Debug, PartialEq)]
pub struct VisionConfig {
    pub tower: TowerConfig,
    pub image_size: usize,
    pub patch_size: usize,
    pub num_channels: usize,
}

impl VisionConfig {
    /// Patches per side.
    pub fn grid(&self) -> usize {
        self.image_size / self.patch_size
    }
    /// Tokens per image: one class token plus grid² patches (50 for ViT-B/32).
    pub fn num_tokens(&self) -> usize {
        self.grid() * self.grid() + 1
    }
}

/// A whole `CLIPModel`.
#[derive(Clone, Debug, PartialEq)]
pub struct ClipConfig {
    pub text: TextConfig,
    pub vision: VisionConfig,
    pub projection_dim: usize,
}

#[derive(Deserialize)]
struct RawTower {
    hidden_size: Option<usize>,
    intermediate_size: Option<usize>,
    num_hidden_layers: Option<usize>,
    num_attention_heads: Option<usize>,
    hidden_act: Option<String>,
    layer_norm_eps: Option<f64>,
    // text only
    vocab_size: Option<usize>,
    max_position_embeddings: Option<usize>,
    eos_token_id: Option<i64>,
    // vision only
    image_size: Option<usize>,
    patch_size: Option<usize>,
    num_channels: Option<usize>,
}

#[derive(Deserialize)]
struct RawConfig {
    text_config: Option<RawTower>,
    vision_config: Option<RawTower>,
    projection_dim: Option<usize>,
}

impl ClipConfig {
    /// Read `config.json`; errors name the file and the offending field.
    pub fn from_file(path: &Path) -> Result<ClipConfig, ClipError> {
        let text = std::fs::read_to_string(path).map_err(|e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        ClipConfig::from_json(&text).map_err(|msg| ClipError::Config {
            path: path.to_path_buf(),
            msg,
        })
    }

    /// Parse the JSON text of a `CLIPModel` config.
    pub fn from_json(json: &str) -> Result<ClipConfig, String> {
        let raw: RawConfig = serde_json::from_str(json).map_err(|e| e.to_string())?;
        let t = raw
            .text_config
            .ok_or("no \"text_config\" (is this a CLIPModel config?)")?;
        let v = raw
            .vision_config
            .ok_or("no \"vision_config\" (is this a CLIPModel config?)")?;
        // Defaults are those of transformers' CLIPTextConfig / CLIPVisionConfig.
        let text_tower = tower("text_config", &t, 512, 2048, 12, 8)?;
        let vision_tower = tower("vision_config", &v, 768, 3072, 12, 12)?;
        let text = TextConfig {
            tower: text_tower,
            vocab_size: t.vocab_size.unwrap_or(49408),
            max_positions: t.max_position_embeddings.unwrap_or(77),
            eos_token_id: t.eos_token_id.unwrap_or(49407),
        };
        let vision = VisionConfig {
            tower: vision_tower,
            image_size: v.image_size.unwrap_or(224),
            patch_size: v.patch_size.unwrap_or(32),
            num_channels: v.num_channels.unwrap_or(3),
        };
        if vision.num_channels != 3 {
            return Err(format!(
                "vision_config.num_channels is {}, only RGB (3) is supported",
                vision.num_channels
            ));
        }
        if vision.patch_size == 0 || vision.image_size % vision.patch_size != 0 {
            return Err(format!(
                "vision_config.image_size {} is not a multiple of patch_size {}",
                vision.image_size, vision.patch_size
            ));
        }
        if text.max_positions < 2 {
            return Err("text_config.max_position_embeddings must be at least 2".into());
        }
        Ok(ClipConfig {
            text,
            vision,
            projection_dim: raw.projection_dim.unwrap_or(512),
        })
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

fn tower(
    which: &str,
    r: &RawTower,
    hidden: usize,
    inter: usize,
    layers: usize,
    heads: usize,
) -> Result<TowerConfig, String> {
    let act_name = r.hidden_act.as_deref().unwrap_or("quick_gelu");
    let act = Activation::parse(act_name)
        .ok_or_else(|| format!("{which}.hidden_act \"{act_name}\" is not supported"))?;
    let tc = TowerConfig {
        hidden_size: r.hidden_size.unwrap_or(hidden),
        intermediate_size: r.intermediate_size.unwrap_or(inter),
        num_layers: r.num_hidden_layers.unwrap_or(layers),
        num_heads: r.num_attention_heads.unwrap_or(heads),
        act,
        layer_norm_eps: r.layer_norm_eps.unwrap_or(1e-5) as f32,
    };
    if tc.num_heads == 0 || tc.hidden_size % tc.num_heads != 0 {
        return Err(format!(
            "{which}.hidden_size {} is not a multiple of num_attention_heads {}",
            tc.hidden_size, tc.num_heads
        ));
    }
    Ok(tc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real_b32_config_loads() {
        let c = ClipConfig::from_file(Path::new("../shared/data/clip/config.json")).unwrap();
        assert_eq!(c, ClipConfig::vit_b32());
        assert_eq!(c.vision.num_tokens(), 50);
    }

    #[test]
    fn l14_and_b16_shapes_load() {
        // Fields as in openai/clip-vit-large-patch14 and clip-vit-base-patch16 config.json.
        let l14 = r#"{"projection_dim":768,
          "text_config":{"hidden_size":768,"intermediate_size":3072,"num_attention_heads":12,"projection_dim":768},
          "vision_config":{"hidden_size":1024,"intermediate_size":4096,"num_attention_heads":16,
                           "num_hidden_layers":24,"patch_size":14,"projection_dim":768}}"#;
        let c = ClipConfig::from_json(l14).unwrap();
        assert_eq!(c.vision.num_tokens(), 257);
        assert_eq!(c.vision.tower.head_dim(), 64);
        assert_eq!(c.projection_dim, 768);
        let b16 = r#"{"text_config":{},"vision_config":{"patch_size":16}}"#;
        assert_eq!(ClipConfig::from_json(b16).unwrap().vision.num_tokens(), 197);
    }

    #[test]
    fn bad_configs_say_what_is_wrong() {
        let e = ClipConfig::from_json(r#"{"vision_config":{}}"#).unwrap_err();
        assert!(e.contains("text_config"), "{e}");
        let e =
            ClipConfig::from_json(r#"{"text_config":{"hidden_act":"relu"},"vision_config":{}}"#)
                .unwrap_err();
        assert!(e.contains("relu"), "{e}");
        let e = ClipConfig::from_json(r#"{"text_config":{},"vision_config":{"patch_size":30}}"#)
            .unwrap_err();
        assert!(e.contains("patch_size"), "{e}");
    }
}
