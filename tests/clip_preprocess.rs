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
