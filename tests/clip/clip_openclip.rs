//! OpenCLIP's own Hub layout (`open_clip_config.json` + `open_clip_pytorch_model.bin` under
//! OpenCLIP's tensor names, what `laion/CLIP-ViT-g-14-laion2B-s34B-b88K` ships) against OpenCLIP
//! itself: the tiny fixture of tests/fixtures/clip/make_openclip_fixtures.py, whose golden
//! outputs OpenCLIP computed after loading the folder with its own `local-dir:` loader.

use std::path::Path;

use serde::Deserialize;
use t2tf::clip::load::{resolve, WeightFormat};
use t2tf::clip::{cosine, Checkpoint, Clip, Compute, Engine, Layout, ModelRequest};
use t2tf::clip::{ClipConfig, OpenClipConfig};

use crate::clip_golden::{check_against_golden, rel_err, Golden, TOKENIZER, TOL};

const DIR: &str = "tests/fixtures/clip/openclip";
const VIT_G: &str =
    "tests/fixtures/clip/configs/laion-clip-vit-g-14-laion2b-s34b-b88k.open_clip_config.json";

/// What golden.json adds to the transformers fixtures' schema.
#[derive(Deserialize)]
struct Extra {
    logit_captions: Vec<usize>,
    /// exp(logit_scale) · cos(image b, caption logit_captions[c]): `[images][captions]`.
    logits: Vec<Vec<f32>>,
    real_configs: std::collections::BTreeMap<String, RealConfig>,
}

#[derive(Deserialize)]
struct RealConfig {
    parameter_count: u64,
}

fn golden() -> (Golden, Extra) {
    let text = std::fs::read_to_string(format!("{DIR}/golden.json")).unwrap();
    (
        serde_json::from_str(&text).unwrap(),
        serde_json::from_str(&text).unwrap(),
    )
}

fn request(dir: &Path) -> ModelRequest {
    let mut req = ModelRequest::new(dir.to_str().unwrap());
    req.tokenizer = Some(Path::new(TOKENIZER).to_path_buf());
    req
}

/// The folder is read as OpenCLIP's layout, and the model matches OpenCLIP (embeddings, token
/// ids from OpenCLIP's own tokenizer, input gradient, logits) with both GEMM engines.
#[test]
fn openclip_layout_matches_open_clip() {
    let (g, extra) = golden();
    let files = resolve(&request(Path::new(DIR))).unwrap();
    assert_eq!(files.layout, Layout::OpenClip);
    assert_eq!(files.format, WeightFormat::PyTorch);
    assert!(files.config.ends_with("open_clip_config.json"));
    assert_eq!(
        files.weights,
        vec![Path::new(DIR).join("open_clip_pytorch_model.bin")]
    );
    for engine in [Engine::Packed, Engine::Crate] {
        let clip = Clip::load_files_with(&files, Compute::default().with_engine(engine)).unwrap();
        let out = check_against_golden(&clip, &g, &format!("openclip ({engine:?})"));
        let mut worst = 0.0f64;
        for (b, want) in extra.logits.iter().enumerate() {
            let got: Vec<f32> = extra
                .logit_captions
                .iter()
                .map(|&c| {
                    clip.logit_scale() * cosine(&out.image_embeddings[b], &out.text_embeddings[c])
                })
                .collect();
            let e = rel_err(&got, want);
            assert!(e <= TOL, "{engine:?}: logits of image {b}: rel err {e:.2e}");
            worst = worst.max(e);
        }
        eprintln!("openclip ({engine:?}): worst logit rel err {worst:.2e}");
    }
}

/// The same state dict as safetensors under both names the Hub uses (OpenCLIP's own
/// `open_clip_model.safetensors`, and `open_clip_pytorch_model.safetensors`), f32 as the LAION
/// files are: the same model, bit for bit; with a safetensors file next to the `.bin`, the
/// safetensors file is read (OpenCLIP's order).
#[test]
fn safetensors_copies_give_the_same_model() {
    use safetensors::tensor::TensorView;
    use safetensors::Dtype;

    let reference = Clip::load_request(&request(Path::new(DIR))).unwrap();
    let captions = ["a photo of a cat", "the teeth of a CT head"];
    let want_text = reference.encode_text(&captions).unwrap();
    let s = reference.image_size();
    let image = t2tf::image::Image {
        width: s,
        height: s,
        data: (0..s * s * 3).map(|i| (i % 7) as f32 / 6.0).collect(),
    };
    let want_image = reference
        .encode_images(std::slice::from_ref(&image))
        .unwrap()
        .0;

    let bin = Path::new(DIR).join("open_clip_pytorch_model.bin");
    let ckpt = Checkpoint::open(std::slice::from_ref(&bin)).unwrap();
    let data: Vec<(String, Vec<usize>, Vec<u8>)> = ckpt
        .names()
        .into_iter()
        .map(|n| {
            let shape = ckpt.shape(n).unwrap();
            let values = ckpt.get(n, &shape).unwrap();
            let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            (n.to_string(), shape, bytes)
        })
        .collect();
    let views: Vec<(String, TensorView)> = data
        .iter()
        .map(|(n, s, b)| {
            (
                n.clone(),
                TensorView::new(Dtype::F32, s.clone(), b).unwrap(),
            )
        })
        .collect();
    for name in [
        "open_clip_model.safetensors",
        "open_clip_pytorch_model.safetensors",
    ] {
        let dir = tempfile::tempdir().unwrap();
        std::fs::copy(
            Path::new(DIR).join("open_clip_config.json"),
            dir.path().join("open_clip_config.json"),
        )
        .unwrap();
        safetensors::serialize_to_file(views.clone(), None, &dir.path().join(name)).unwrap();
        std::fs::copy(&bin, dir.path().join("open_clip_pytorch_model.bin")).unwrap();
        let files = resolve(&request(dir.path())).unwrap();
        assert_eq!(files.layout, Layout::OpenClip);
        assert_eq!(files.format, WeightFormat::Safetensors, "{name}");
        assert_eq!(files.weights, vec![dir.path().join(name)]);
        let clip = Clip::load_files(&files).unwrap();
        assert_eq!(clip.encode_text(&captions).unwrap(), want_text, "{name}");
        assert_eq!(
            clip.encode_images(std::slice::from_ref(&image)).unwrap().0,
            want_image,
            "{name}"
        );
    }
}

/// The published ViT-g/14 config (laion/CLIP-ViT-g-14-laion2B-s34B-b88K) builds the model
/// OpenCLIP builds: the parameter count OpenCLIP's `CLIP` has for it, and its shapes.
#[test]
fn vit_g14_config_has_open_clips_parameter_count() {
    let (_, extra) = golden();
    let want =
        extra.real_configs[Path::new(VIT_G).file_name().unwrap().to_str().unwrap()].parameter_count;
    let c = OpenClipConfig::from_file(Path::new(VIT_G)).unwrap();
    assert_eq!(c.clip.parameter_count(), want);
    assert_eq!(c.clip.parameter_count(), 1_366_678_273);
    let v: &ClipConfig = &c.clip;
    assert_eq!(
        (
            v.vision.tower.hidden_size,
            v.vision.tower.num_layers,
            v.vision.tower.num_heads,
            v.vision.tower.intermediate_size,
            v.vision.patch_size,
            v.vision.image_size
        ),
        (1408, 40, 16, 6144, 14, 224)
    );
}

/// A folder with a config but the other layout's weights, or no config at all, says every file
/// it looked for.
#[test]
fn incomplete_openclip_folders_say_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(
        Path::new(DIR).join("open_clip_config.json"),
        dir.path().join("open_clip_config.json"),
    )
    .unwrap();
    let e = resolve(&request(dir.path())).unwrap_err().to_string();
    for name in [
        "open_clip_model.safetensors",
        "open_clip_pytorch_model.safetensors",
        "open_clip_pytorch_model.bin",
    ] {
        assert!(e.contains(name), "{e}");
    }
    std::fs::write(dir.path().join("open_clip_pytorch_model.bin"), b"not a zip").unwrap();
    let e = Clip::load_request(&request(dir.path()))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("open_clip_pytorch_model.bin"), "{e}");
}
