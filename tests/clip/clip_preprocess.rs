//! `clip::preprocess` against `transformers`' CLIPImageProcessor (Pillow backend) on 8-bit
//! images (tests/fixtures/clip/preprocess.json): a downscale and an upscale, both non-square.

use serde::Deserialize;
use t2tf::clip::preprocess;
use t2tf::image::Image;

#[derive(Deserialize)]
struct Case {
    width: usize,
    height: usize,
    rgb8: Vec<u8>,
    expected: Vec<f32>,
}

#[derive(Deserialize)]
struct Cases {
    cases: Vec<Case>,
}

/// Pillow resamples 8-bit images in two passes and rounds to 8 bits after each; we keep f32
/// throughout. Two roundings of at most half a level each, the first one spread by the
/// vertical filter (whose weights sum to 1 but include negative lobes, |w| summing to ~1.3),
/// bound the difference by about 1.2 levels; 1.5/255 leaves a little margin.
const TOL: f32 = 1.5 / 255.0;

#[test]
fn matches_clip_image_processor() {
    let cases: Cases = serde_json::from_str(
        &std::fs::read_to_string("tests/fixtures/clip/preprocess.json").unwrap(),
    )
    .unwrap();
    for c in &cases.cases {
        let im = Image {
            width: c.width,
            height: c.height,
            data: c.rgb8.iter().map(|&v| v as f32 / 255.0).collect(),
        };
        let out = preprocess(&im, 32);
        assert_eq!((out.width, out.height), (32, 32));
        let worst = out
            .data
            .iter()
            .zip(&c.expected)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        eprintln!(
            "{}x{}: worst difference {:.2} levels",
            c.width,
            c.height,
            worst * 255.0
        );
        assert!(worst <= TOL, "{}x{}: {worst}", c.width, c.height);
    }
}

/// A model folder with a `preprocessor_config.json` uses its statistics, one without it
/// CLIP's constants: with `do_normalize: false` the encoder sees the pixels as given, so it
/// must agree with the plain model fed pixels normalized by hand with CLIP's mean/std (the
/// same f32 operations, so the same bits), and an image-processor crop that the vision tower
/// cannot take is refused naming the file.
#[test]
fn preprocessor_config_is_used_when_present_and_clip_constants_otherwise() {
    use t2tf::clip::{Clip, Preprocessing, MEAN, STD};
    let tok = std::path::Path::new("../shared/data/clip/tokenizer.json");
    let fixture = std::path::Path::new("tests/fixtures/clip/quick_gelu");
    let dir = tempfile::tempdir().unwrap();
    for f in ["config.json", "model.safetensors"] {
        std::fs::copy(fixture.join(f), dir.path().join(f)).unwrap();
    }
    let plain = Clip::load_with_tokenizer(dir.path().to_str().unwrap(), Some(tok)).unwrap();
    let s = plain.image_size();
    assert_eq!(plain.preprocessing(), &Preprocessing::clip(s));

    std::fs::write(
        dir.path().join("preprocessor_config.json"),
        format!(r#"{{"do_normalize": false, "crop_size": {s}, "size": {{"shortest_edge": {s}}}}}"#),
    )
    .unwrap();
    let raw = Clip::load_with_tokenizer(dir.path().to_str().unwrap(), Some(tok)).unwrap();
    assert_eq!(
        (raw.preprocessing().mean, raw.preprocessing().std),
        ([0.0; 3], [1.0; 3])
    );
    let mut im = Image::new(s, s);
    for (i, v) in im.data.iter_mut().enumerate() {
        *v = ((i * 37) % 251) as f32 / 250.0;
    }
    let mut normalized = im.clone();
    for (i, v) in normalized.data.iter_mut().enumerate() {
        *v = (*v - MEAN[i % 3]) / STD[i % 3];
    }
    let (want, _) = plain.encode_images(std::slice::from_ref(&im)).unwrap();
    let (got, _) = raw.encode_images(&[normalized]).unwrap();
    assert_eq!(got, want);
    let (other, _) = raw.encode_images(&[im]).unwrap();
    assert_ne!(other, want, "the statistics are really not applied");

    std::fs::write(
        dir.path().join("preprocessor_config.json"),
        format!(r#"{{"crop_size": {}}}"#, s + 8),
    )
    .unwrap();
    let e = Clip::load_with_tokenizer(dir.path().to_str().unwrap(), Some(tok))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("preprocessor_config.json") && e.contains("crops to"),
        "{e}"
    );
}
