//! `t2tf clip-score` on the tiny fixture model.

use std::process::Command;

use t2tf::clip::{cosine, softmax_scaled, Clip};
use t2tf::image::Image;

const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const MODEL: &str = "tests/fixtures/clip/quick_gelu";

#[test]
fn prints_cosines_and_probabilities_of_each_caption() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("view.png");
    // 48x40: not the model's 32x32, so preprocessing (resize + crop) is exercised.
    let mut im = Image::new(48, 40);
    for (i, v) in im.data.iter_mut().enumerate() {
        *v = ((i * 31) % 255) as f32 / 255.0;
    }
    im.save_png(&png).unwrap();
    let captions = ["a white skull", "a red engine", "héllo ☃"];
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_t2tf"));
    cmd.args([
        "clip-score",
        png.to_str().unwrap(),
        "--model",
        MODEL,
        "--tokenizer",
        TOKENIZER,
        // The library's `Clip::load_with_tokenizer` below is f32; the command's default is auto.
        "--precision",
        "f32",
    ]);
    for c in captions {
        cmd.args(["--caption", c]);
    }
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    let rows: Vec<&str> = stdout.lines().skip(1).collect();
    assert_eq!(rows.len(), 3, "{stdout}");

    // Same numbers through the library, from the PNG as written (8-bit).
    let clip = Clip::load_with_tokenizer(MODEL, Some(std::path::Path::new(TOKENIZER))).unwrap();
    let img = Image::load_png(&png).unwrap();
    let (e, _) = clip.encode_images(&[clip.preprocess(&img)]).unwrap();
    let t = clip.encode_text(&captions).unwrap();
    let sims: Vec<f32> = t.iter().map(|t| cosine(&e[0], t)).collect();
    let probs = softmax_scaled(&sims, clip.logit_scale());
    let mut total = 0.0;
    for ((row, c), (s, p)) in rows.iter().zip(captions).zip(sims.iter().zip(&probs)) {
        let f: Vec<&str> = row.split_whitespace().collect();
        let (cs, ps): (f32, f32) = (f[0].parse().unwrap(), f[1].parse().unwrap());
        assert!((cs - s).abs() <= 1e-4 && (ps - p).abs() <= 1e-4, "{row}");
        assert!(row.ends_with(c));
        total += ps;
    }
    assert!((total - 1.0).abs() < 1e-3);
}

#[test]
fn missing_image_and_bad_model_are_one_line_errors() {
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args([
            "clip-score",
            "no/such.png",
            "--model",
            MODEL,
            "--caption",
            "x",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no/such.png") && err.lines().count() == 1,
        "{err}"
    );

    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("a.png");
    Image::new(8, 8).save_png(&png).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args([
            "clip-score",
            png.to_str().unwrap(),
            "--model",
            dir.path().to_str().unwrap(),
        ])
        .args(["--caption", "x"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("model.safetensors") && err.contains("config.json"),
        "{err}"
    );
}
