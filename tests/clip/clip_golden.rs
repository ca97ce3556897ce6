//! Parity with Hugging Face `transformers` on the tiny CLIP fixtures made by
//! tests/fixtures/clip/make_fixtures.py: token ids, text embeddings, image embeddings and the
//! input gradient of a cosine similarity, for the quick_gelu (f16 weights, legacy
//! eos_token_id = 2 pooling) and gelu (bf16 weights, eos_token_id pooling) variants.

use std::path::Path;

use serde::Deserialize;
use t2tf::clip::{cosine, cosine_grad, Clip};
use t2tf::clip::{Compute, Engine, ModelRequest};
use t2tf::image::Image;

/// A golden file written by transformers (`tests/fixtures/clip/*/golden.json`); also read by
/// `clip_families` and `clip_kernels`.
#[derive(Deserialize)]
pub(crate) struct TextCase {
    pub(crate) caption: String,
    pub(crate) ids: Vec<u32>,
    pub(crate) embedding: Vec<f32>,
}

#[derive(Deserialize)]
pub(crate) struct Golden {
    pub(crate) texts: Vec<TextCase>,
    pub(crate) logit_scale: f32,
    /// [B][H][W][3]
    pub(crate) images: Vec<Vec<Vec<Vec<f32>>>>,
    pub(crate) image_embeddings: Vec<Vec<f32>>,
    pub(crate) grad_pairs: Vec<usize>,
    pub(crate) grad_images: Vec<Vec<Vec<Vec<f32>>>>,
}

pub(crate) const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";

/// Parity criterion: max |rust − reference| ≤ TOL · max |reference| over the whole vector.
/// Both sides compute in f32 from identical weights; the differences come from summation
/// order (GEMM blocking vs PyTorch's kernels), ~1e-6 relative per layer.
pub(crate) const TOL: f64 = 1e-4;

pub(crate) fn rel_err(got: &[f32], want: &[f32]) -> f64 {
    assert_eq!(got.len(), want.len());
    let scale = want.iter().fold(0.0f64, |m, &v| m.max(v.abs() as f64));
    let diff = got
        .iter()
        .zip(want)
        .fold(0.0f64, |m, (&a, &b)| m.max((a as f64 - b as f64).abs()));
    diff / scale.max(1e-30)
}

pub(crate) fn to_image(nested: &[Vec<Vec<f32>>]) -> Image {
    let (h, w) = (nested.len(), nested[0].len());
    Image {
        width: w,
        height: h,
        data: nested.iter().flatten().flatten().copied().collect(),
    }
}

/// What [`check_against_golden`] computed, for a caller's further checks.
pub(crate) struct Outputs {
    pub(crate) text_embeddings: Vec<Vec<f32>>,
    pub(crate) image_embeddings: Vec<Vec<f32>>,
    pub(crate) input_gradients: Vec<Image>,
}

/// `clip` against a golden file, within [`TOL`]: the logit scale, token ids, text embeddings
/// of all captions in one batch, image embeddings, and the input gradient of
/// Σ_b cos(image_b, text_pair[b]). Prints the worst error of each (`name` first).
pub(crate) fn check_against_golden(clip: &Clip, golden: &Golden, name: &str) -> Outputs {
    assert!((clip.logit_scale() - golden.logit_scale).abs() <= 1e-5 * golden.logit_scale);
    // Text: ids from our tokenizer, embeddings of all captions in one batch.
    let captions: Vec<&str> = golden.texts.iter().map(|t| t.caption.as_str()).collect();
    let ids = clip.tokenize(&captions).unwrap();
    for (t, got) in golden.texts.iter().zip(&ids) {
        assert_eq!(got, &t.ids, "{name}: ids of {:?}", t.caption);
    }
    let text_emb = clip.encode_text(&captions).unwrap();
    let mut worst = 0.0f64;
    for (t, got) in golden.texts.iter().zip(&text_emb) {
        let e = rel_err(got, &t.embedding);
        assert!(e <= TOL, "{name}: text {:?} rel err {e:.2e}", t.caption);
        worst = worst.max(e);
    }
    eprintln!("{name}: worst text embedding rel err {worst:.2e}");

    // Images: embeddings.
    let images: Vec<Image> = golden.images.iter().map(|i| to_image(i)).collect();
    let (img_emb, cache) = clip.encode_images(&images).unwrap();
    let mut worst = 0.0f64;
    for (b, (got, want)) in img_emb.iter().zip(&golden.image_embeddings).enumerate() {
        let e = rel_err(got, want);
        assert!(e <= TOL, "{name}: image {b} rel err {e:.2e}");
        worst = worst.max(e);
    }
    eprintln!("{name}: worst image embedding rel err {worst:.2e}");

    // Input gradient of Σ_b cos(image_b, text_pair[b]).
    let d: Vec<Vec<f32>> = img_emb
        .iter()
        .zip(&golden.grad_pairs)
        .map(|(e, &p)| cosine_grad(e, &text_emb[p]))
        .collect();
    let grads = clip.image_backward(&cache, &d).unwrap();
    let mut worst = 0.0f64;
    for (b, (got, want)) in grads.iter().zip(&golden.grad_images).enumerate() {
        let want = to_image(want);
        let e = rel_err(&got.data, &want.data);
        assert!(e <= TOL, "{name}: gradient of image {b} rel err {e:.2e}");
        worst = worst.max(e);
    }
    eprintln!("{name}: worst input-gradient rel err {worst:.2e}");
    Outputs {
        text_embeddings: text_emb,
        image_embeddings: img_emb,
        input_gradients: grads,
    }
}

/// Both GEMM engines (packed weights + own kernel, and the `gemm` crate) must reach parity.
fn check_variant(variant: &str) {
    for engine in [Engine::Packed, Engine::Crate] {
        check_engine(variant, engine);
    }
}

fn check_engine(variant: &str, engine: Engine) {
    let name = format!("{variant} ({engine:?})");
    let dir = format!("tests/fixtures/clip/{variant}");
    let golden: Golden =
        serde_json::from_str(&std::fs::read_to_string(format!("{dir}/golden.json")).unwrap())
            .unwrap();
    let mut req = ModelRequest::new(&dir);
    req.tokenizer = Some(Path::new(TOKENIZER).to_path_buf());
    let clip = Clip::load_request_with(&req, Compute::default().with_engine(engine)).unwrap();
    let out = check_against_golden(&clip, &golden, &name);
    // The scores themselves, through the public helper.
    for (e, &p) in out.image_embeddings.iter().zip(&golden.grad_pairs) {
        assert!(cosine(e, &out.text_embeddings[p]).is_finite());
    }
}

#[test]
fn quick_gelu_f16_matches_transformers() {
    check_variant("quick_gelu");
}

#[test]
fn gelu_bf16_matches_transformers() {
    check_variant("gelu");
}

/// A model loaded from files builds its text tower when texts are encoded and frees it on
/// `release_text`, reading only the token rows it needs from the file: the embeddings are
/// those of a model that keeps the whole tower (built from the same checkpoint), bit for
/// bit, before and after a release, and from two threads at once.
#[test]
fn text_tower_built_on_demand_matches_a_kept_one() {
    use t2tf::clip::{Checkpoint, ClipTokenizer};
    for variant in ["quick_gelu", "gelu", "openclip"] {
        let dir = format!("tests/fixtures/clip/{variant}");
        let mut req = ModelRequest::new(&dir);
        req.tokenizer = Some(Path::new(TOKENIZER).to_path_buf());
        let files = t2tf::clip::load::resolve(&req).unwrap();
        let on_demand = Clip::load_files(&files).unwrap();
        let captions = ["a photo of a skull", "bones", "a photo of a cat"];
        let first = on_demand.encode_text(&captions).unwrap();
        on_demand.release_text();
        let again = on_demand.encode_text(&captions).unwrap();
        assert_eq!(first, again, "{variant}: after release_text");
        std::thread::scope(|s| {
            on_demand.release_text();
            let a = s.spawn(|| on_demand.encode_text(&captions[..2]).unwrap());
            let b = s.spawn(|| on_demand.encode_text(&captions[1..]).unwrap());
            let (a, b) = (a.join().unwrap(), b.join().unwrap());
            assert_eq!(a[..], first[..2], "{variant}: thread a");
            assert_eq!(b[..], first[1..], "{variant}: thread b");
        });
        if files.layout == t2tf::clip::Layout::Transformers {
            let checkpoint = Checkpoint::open(&files.weights).unwrap();
            let config = on_demand.config().clone();
            let max = config.text.max_positions;
            let mut kept = Clip::from_source(config, &checkpoint).unwrap();
            kept.set_tokenizer(ClipTokenizer::from_file(&files.tokenizer, max).unwrap());
            assert_eq!(
                kept.encode_text(&captions).unwrap(),
                first,
                "{variant}: kept"
            );
        }
    }
}
