//! The image encoder's input gradient against central finite differences of its own forward
//! pass, on the tiny fixture models (both activations, and the OpenCLIP-layout model).

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use t2tf::clip::{cosine, cosine_grad, Clip};
use t2tf::image::Image;

fn model(name: &str) -> Clip {
    Clip::load_with_tokenizer(
        &format!("tests/fixtures/clip/{name}"),
        Some(Path::new("../shared/data/clip/tokenizer.json")),
    )
    .unwrap()
}

/// L(images) = Σ_b cos(image_embedding_b, text), accumulated in f64.
fn loss(clip: &Clip, images: &[Image], text: &[f32]) -> f64 {
    let (emb, _) = clip.encode_images(images).unwrap();
    emb.iter().map(|e| cosine(e, text) as f64).sum()
}

/// Directional derivatives along random directions and single-pixel derivatives at the pixels
/// with the largest gradient. The forward pass is f32: the loss carries ~1e-6 absolute
/// round-off, so with a step h = 1e-2 (pixels are in [0, 1]) central differences have ~1e-4
/// noise, and the O(h²) truncation of this smooth network is of the same order. Directional
/// derivatives are O(0.1–1), so 1 % relative (plus 2e-4 absolute) separates a correct
/// gradient from any wrong one (a wrong channel order, a missing 1/std, or a transposed patch
/// all give O(1) relative errors).
#[test]
fn input_gradient_matches_finite_differences() {
    for name in ["quick_gelu", "gelu", "openclip"] {
        let clip = model(name);
        let s = clip.image_size();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let images: Vec<Image> = (0..2)
            .map(|_| Image {
                width: s,
                height: s,
                data: (0..s * s * 3).map(|_| rng.random_range(0.1..0.9)).collect(),
            })
            .collect();
        let text = clip
            .encode_text(&["a bright red engine"])
            .unwrap()
            .remove(0);
        let (emb, cache) = clip.encode_images(&images).unwrap();
        let d: Vec<Vec<f32>> = emb.iter().map(|e| cosine_grad(e, &text)).collect();
        let grads = clip.image_backward(&cache, &d).unwrap();
        let h = 1e-2f32;
        let step = |dir: &[Vec<f32>], sign: f32| -> Vec<Image> {
            images
                .iter()
                .zip(dir)
                .map(|(im, v)| Image {
                    width: s,
                    height: s,
                    data: im
                        .data
                        .iter()
                        .zip(v)
                        .map(|(x, d)| x + sign * h * d)
                        .collect(),
                })
                .collect()
        };
        let check = |dir: &[Vec<f32>], what: &str| {
            let fd = (loss(&clip, &step(dir, 1.0), &text) - loss(&clip, &step(dir, -1.0), &text))
                / (2.0 * h as f64);
            let an: f64 = grads
                .iter()
                .zip(dir)
                .flat_map(|(g, v)| g.data.iter().zip(v).map(|(a, b)| *a as f64 * *b as f64))
                .sum();
            eprintln!(
                "{name} {what}: analytic {an:.6e} fd {fd:.6e} rel {:.1e}",
                (an - fd).abs() / fd.abs()
            );
            assert!(
                (an - fd).abs() <= 1e-2 * fd.abs() + 2e-4,
                "{name} {what}: analytic {an:.6e} vs finite difference {fd:.6e}"
            );
        };
        for k in 0..4 {
            let dir: Vec<Vec<f32>> = (0..2)
                .map(|_| {
                    (0..s * s * 3)
                        .map(|_| rng.random_range(-1.0..1.0))
                        .collect()
                })
                .collect();
            check(&dir, &format!("random direction {k}"));
        }
        // Single pixels: the largest |gradient| entries of image 1.
        let mut order: Vec<usize> = (0..s * s * 3).collect();
        order.sort_by(|&a, &b| grads[1].data[b].abs().total_cmp(&grads[1].data[a].abs()));
        for &i in &order[..3] {
            let mut dir = vec![vec![0.0f32; s * s * 3]; 2];
            dir[1][i] = 1.0;
            check(&dir, &format!("pixel {} channel {}", i / 3, i % 3));
        }
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let clip = model("quick_gelu");
    let s = clip.image_size();
    let e = clip
        .encode_images(&[Image::new(s + 1, s)])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("33x32") && e.contains("32x32"), "{e}");
    let mut nan = Image::new(s, s);
    nan.data[5] = f32::NAN;
    let e = clip.encode_images(&[nan]).err().unwrap().to_string();
    assert!(e.contains("non-finite"), "{e}");
    let (_, cache) = clip.encode_images(&[Image::new(s, s)]).unwrap();
    let e = clip.image_backward(&cache, &[]).err().unwrap().to_string();
    assert!(e.contains("1 gradients"), "{e}");
    let e = clip
        .encode_tokens(&[vec![49406, 60000]])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("60000"), "{e}");
    // Saturated pixels (all 0 or all 1) and a constant image give finite results.
    for v in [0.0, 1.0] {
        let (emb, cache) = clip.encode_images(&[Image::filled(s, s, [v; 3])]).unwrap();
        let g = clip.image_backward(&cache, &emb).unwrap();
        assert!(emb[0].iter().chain(&g[0].data).all(|x| x.is_finite()));
    }
}

/// Batching the views (what the optimizer does) gives the same embeddings and gradients as
/// encoding them one at a time, and the model can be shared across threads.
#[test]
fn batched_views_equal_single_views() {
    fn shareable<T: Send + Sync>(_: &T) {}
    let clip = model("gelu");
    shareable(&clip);
    let s = clip.image_size();
    let views: Vec<Image> = (0..3)
        .map(|v| Image {
            width: s,
            height: s,
            data: (0..s * s * 3)
                .map(|i| ((i * 13 + v * 71) % 97) as f32 / 96.0)
                .collect(),
        })
        .collect();
    let text = clip.encode_text(&["a blue teapot"]).unwrap().remove(0);
    let (emb, cache) = clip.encode_images(&views).unwrap();
    let d: Vec<Vec<f32>> = emb.iter().map(|e| cosine_grad(e, &text)).collect();
    let grads = clip.image_backward(&cache, &d).unwrap();
    for (v, view) in views.iter().enumerate() {
        let (e1, c1) = clip.encode_images(std::slice::from_ref(view)).unwrap();
        let g1 = clip
            .image_backward(&c1, &[cosine_grad(&e1[0], &text)])
            .unwrap();
        let close = |a: &[f32], b: &[f32]| {
            let scale = b.iter().fold(0.0f32, |m, x| m.max(x.abs()));
            a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-5 * scale)
        };
        assert!(close(&emb[v], &e1[0]), "embedding of view {v}");
        assert!(close(&grads[v].data, &g1[0].data), "gradient of view {v}");
    }
    // Texts in one batch equal texts one by one (packing without padding).
    let caps = [
        "",
        "a red engine",
        "a much longer caption about a translucent skull",
    ];
    let batch = clip.encode_text(&caps).unwrap();
    for (c, b) in caps.iter().zip(&batch) {
        let one = clip.encode_text(&[c]).unwrap().remove(0);
        assert!(
            one.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-5 * (1.0 + y.abs())),
            "{c:?}"
        );
    }
}
