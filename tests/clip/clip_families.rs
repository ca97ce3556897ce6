//! Shapes of every CLIP family, and the old LAION config layout, against Hugging Face
//! `transformers`: the odd_shapes fixture made by tests/fixtures/clip/make_family_fixtures.py is
//! a tiny CLIPModel whose config.json uses `text_config_dict` / `vision_config_dict` next to
//! stale sub-configs, gelu, layer_norm_eps 1e-6, head dims 3 and 13, intermediate sizes 11 and
//! 60, projection_dim 10, and 23-pixel images cut into 5-pixel patches (17 tokens, the last 3
//! rows and columns unseen). Parity is checked as in tests/clip/clip_golden.rs, with both GEMM
//! engines: text embeddings, image embeddings, input gradient of a cosine similarity.

use std::path::Path;

use serde::Deserialize;
use t2tf::clip::config::ClipConfig;
use t2tf::clip::{cosine_grad, Activation, Clip, ClipError, TensorSource};
use t2tf::clip::{Compute, Engine, ModelRequest};
use t2tf::image::Image;

// The golden-file format, the parity criterion (max |rust − reference| ≤ TOL · max |reference|)
// and the comparison itself are clip_golden's.
use crate::clip_golden::{check_against_golden, rel_err, Golden, TOKENIZER, TOL};

const DIR: &str = "tests/fixtures/clip/odd_shapes";

fn golden() -> Golden {
    serde_json::from_str(&std::fs::read_to_string(format!("{DIR}/golden.json")).unwrap()).unwrap()
}

/// The old layout is read as transformers reads it (make_family_fixtures.py asserts the same
/// values on transformers' side): dicts win, their missing fields take class defaults.
#[test]
fn old_layout_config_reads_as_transformers_reads_it() {
    let c = ClipConfig::from_file(Path::new(&format!("{DIR}/config.json"))).unwrap();
    let (t, v) = (&c.text, &c.vision);
    assert_eq!(
        (t.tower.hidden_size, t.tower.num_heads, t.tower.head_dim()),
        (6, 2, 3)
    );
    assert_eq!((t.tower.intermediate_size, t.tower.num_layers), (11, 2));
    assert_eq!(
        (t.tower.act, t.tower.layer_norm_eps),
        (Activation::Gelu, 1e-6)
    );
    assert_eq!(
        (t.vocab_size, t.max_positions, t.eos_token_id),
        (49408, 77, 49407)
    );
    assert_eq!(
        (v.tower.hidden_size, v.tower.num_heads, v.tower.head_dim()),
        (52, 4, 13)
    );
    assert_eq!((v.tower.intermediate_size, v.tower.num_layers), (60, 2));
    assert_eq!(
        (v.tower.act, v.tower.layer_norm_eps),
        (Activation::Gelu, 1e-6)
    );
    assert_eq!(
        (v.image_size, v.patch_size, v.grid(), v.num_tokens()),
        (23, 5, 4, 17)
    );
    assert_eq!(c.projection_dim, 10);
    // Every parameter of the file (safetensors header) is accounted for.
    let st = std::fs::read(format!("{DIR}/model.safetensors")).unwrap();
    let header_len = u64::from_le_bytes(st[..8].try_into().unwrap()) as usize;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&st[8..8 + header_len]).unwrap();
    let stored: u64 = header
        .iter()
        .filter(|(k, _)| k.as_str() != "__metadata__")
        .map(|(_, t)| {
            t["shape"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| d.as_u64().unwrap())
                .product::<u64>()
        })
        .sum();
    assert_eq!(c.parameter_count(), stored);
    assert_eq!(c.f32_bytes(), (st.len() - 8 - header_len) as u64);
}

fn check_engine(engine: Engine) {
    let name = format!("odd_shapes ({engine:?})");
    let golden = golden();
    let mut req = ModelRequest::new(DIR);
    req.tokenizer = Some(Path::new(TOKENIZER).to_path_buf());
    let clip = Clip::load_request_with(&req, Compute::default().with_engine(engine)).unwrap();
    assert_eq!(clip.image_size(), 23);
    let out = check_against_golden(&clip, &golden, &name);
    assert!(out.text_embeddings.iter().all(|e| e.len() == 10));
    for (b, got) in out.input_gradients.iter().enumerate() {
        // Rows and columns 20..23 lie past the 4 × 4 grid of 5-pixel patches.
        for y in 0..23 {
            for x in 0..23 {
                if x >= 20 || y >= 20 {
                    let px = &got.data[(y * 23 + x) * 3..][..3];
                    assert!(
                        px.iter().all(|&g| g == 0.0),
                        "{name}: image {b} pixel ({x}, {y})"
                    );
                }
            }
        }
    }
}

#[test]
fn odd_shapes_match_transformers_with_both_engines() {
    for engine in [Engine::Packed, Engine::Crate] {
        check_engine(engine);
    }
}

/// `formula_tensor` / `formula_unit` of make_family_fixtures.py, bit for bit: a splitmix64 hash
/// of (FNV-1a of the name, index) gives k / 2^24 in [0, 1); the scalings are exact or one f32
/// rounding, the same in numpy and here.
struct FormulaSource;

fn fnv1a(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

fn formula_unit(name: &str, n: usize) -> Vec<f32> {
    let seed = fnv1a(name);
    (0..n as u64)
        .map(|i| {
            let mut x = seed.wrapping_add(i.wrapping_mul(0x9e37_79b9_7f4a_7c15));
            x ^= x >> 30;
            x = x.wrapping_mul(0xbf58_476d_1ce4_e5b9);
            x ^= x >> 27;
            x = x.wrapping_mul(0x94d0_49bb_1331_11eb);
            x ^= x >> 31;
            (x >> 40) as f32 / (1u32 << 24) as f32
        })
        .collect()
}

impl TensorSource for FormulaSource {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let n: usize = shape.iter().product();
        if name == "logit_scale" {
            return Ok(vec![4.5; n.max(1)]);
        }
        let c = formula_unit(name, n).into_iter().map(|u| u - 0.5);
        Ok(if shape.len() == 1 && name.ends_with("weight") {
            c.map(|c| 1.0 + c * 0.5).collect()
        } else if name.ends_with("bias") {
            c.map(|c| c * 0.2).collect()
        } else if name.contains("embedding") && !name.contains("patch_embedding") {
            c.collect()
        } else {
            let fan_in = n / shape[0];
            let e = (usize::BITS - 1 - fan_in.leading_zeros()) / 2;
            let a = 2f32.powi(1 - e as i32);
            c.map(|c| c * a).collect()
        })
    }
}

#[derive(Deserialize)]
struct RealCase {
    ids: Vec<u32>,
    embedding: Vec<f32>,
}

#[derive(Deserialize)]
struct RealGolden {
    config: serde_json::Value,
    texts: Vec<RealCase>,
    image_embeddings: Vec<Vec<f32>>,
    grad_pairs: Vec<usize>,
    grad_stride: usize,
    grad_samples: Vec<Vec<f32>>,
}

/// Real families' per-layer shapes, two layers each, against transformers (golden from
/// make_family_fixtures.py, weights and images from the shared formula): text 1280 wide with
/// 20 heads of 64 and an MLP of 5120 (ViT-bigG/14's text tower), vision heads of 104 and an
/// MLP of 8192 (bigG's) on 336-pixel images in 14-pixel patches (577 tokens, L/14-336's).
/// Beyond the tiny fixture this runs the GEMMs with several k-blocks (k > 256) and several
/// row blocks (1154 rows > 168), and attention over 577 tokens.
#[test]
fn real_family_shapes_match_transformers_with_both_engines() {
    let g: RealGolden =
        serde_json::from_str(&std::fs::read_to_string(format!("{DIR}/real_shapes.json")).unwrap())
            .unwrap();
    let config = ClipConfig::from_json(&g.config.to_string()).unwrap();
    assert_eq!(config.text.tower.num_heads, 20);
    assert_eq!(config.vision.tower.head_dim(), 104);
    assert_eq!(config.vision.num_tokens(), 577);
    let s = config.vision.image_size;
    let images: Vec<Image> = (0..2)
        .map(|b| Image {
            width: s,
            height: s,
            data: formula_unit(&format!("image{b}"), s * s * 3),
        })
        .collect();
    let ids: Vec<Vec<u32>> = g.texts.iter().map(|t| t.ids.clone()).collect();
    for engine in [Engine::Packed, Engine::Crate] {
        {
            let compute = Compute::default().with_engine(engine);
            let clip = Clip::from_source_with(config.clone(), &FormulaSource, compute).unwrap();
            let text = clip.encode_tokens(&ids).unwrap();
            let worst = g
                .texts
                .iter()
                .zip(&text)
                .map(|(t, got)| rel_err(got, &t.embedding))
                .fold(0.0, f64::max);
            eprintln!("real shapes ({engine:?}): worst text embedding rel err {worst:.2e}");
            assert!(worst <= TOL, "{engine:?}: text rel err {worst:.2e}");
            let (emb, cache) = clip.encode_images(&images).unwrap();
            let worst = emb
                .iter()
                .zip(&g.image_embeddings)
                .map(|(got, want)| rel_err(got, want))
                .fold(0.0, f64::max);
            eprintln!("real shapes ({engine:?}): worst image embedding rel err {worst:.2e}");
            assert!(worst <= TOL, "{engine:?}: image rel err {worst:.2e}");
            let d: Vec<Vec<f32>> = emb
                .iter()
                .zip(&g.grad_pairs)
                .map(|(e, &p)| cosine_grad(e, &text[p]))
                .collect();
            let grads = clip.image_backward(&cache, &d).unwrap();
            let worst = grads
                .iter()
                .zip(&g.grad_samples)
                .map(|(got, want)| {
                    let got: Vec<f32> = got.data.iter().step_by(g.grad_stride).copied().collect();
                    rel_err(&got, want)
                })
                .fold(0.0, f64::max);
            eprintln!("real shapes ({engine:?}): worst input-gradient rel err {worst:.2e}");
            assert!(worst <= TOL, "{engine:?}: gradient rel err {worst:.2e}");
        }
    }
}
