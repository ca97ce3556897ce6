//! Preparing a `--reference-image` picture for CLIP the way Hugging Face's
//! `CLIPImageProcessor` does: resize so the shorter side is the model's image size (PIL
//! bicubic with antialiasing), then crop the centre square.
//!
//! Hand-written because the only resampler in our dependencies would be the `image` crate's,
//! whose bicubic filter does not widen its support when shrinking the way PIL's does (PIL is
//! what the CLIP reference pipeline uses), and a 4 MP photo shrunk 10× would alias.

use crate::image::Image;

/// PIL's bicubic kernel (a = −0.5).
fn bicubic(x: f64) -> f64 {
    const A: f64 = -0.5;
    let x = x.abs();
    if x < 1.0 {
        ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        (((x - 5.0) * x + 8.0) * x - 4.0) * A
    } else {
        0.0
    }
}

/// For each output index: the first input index and the normalized weights (PIL's
/// `precompute_coeffs`: support scaled by the shrink factor, so shrinking averages).
fn coefficients(input: usize, output: usize) -> Vec<(usize, Vec<f64>)> {
    let scale = input as f64 / output as f64;
    let filter_scale = scale.max(1.0);
    let support = 2.0 * filter_scale;
    (0..output)
        .map(|o| {
            let center = (o as f64 + 0.5) * scale;
            let lo = ((center - support + 0.5).floor().max(0.0)) as usize;
            let hi = ((center + support + 0.5).floor() as usize).min(input);
            let mut w: Vec<f64> = (lo..hi)
                .map(|i| bicubic((i as f64 - center + 0.5) / filter_scale))
                .collect();
            let sum: f64 = w.iter().sum();
            if sum != 0.0 {
                w.iter_mut().for_each(|v| *v /= sum);
            }
            (lo, w)
        })
        .collect()
}

/// Resample to `width × height` (horizontal pass, then vertical, as PIL), clamped to [0, 1].
pub fn resize(img: &Image, width: usize, height: usize) -> Image {
    let (w0, h0) = (img.width, img.height);
    let cx = coefficients(w0, width);
    let mut tmp = vec![0.0f64; width * h0 * 3];
    for y in 0..h0 {
        for (x, (lo, w)) in cx.iter().enumerate() {
            for c in 0..3 {
                let v: f64 = w
                    .iter()
                    .enumerate()
                    .map(|(k, wk)| wk * img.data[(y * w0 + lo + k) * 3 + c] as f64)
                    .sum();
                tmp[(y * width + x) * 3 + c] = v.clamp(0.0, 1.0);
            }
        }
    }
    let cy = coefficients(h0, height);
    let mut out = Image::new(width, height);
    for (y, (lo, w)) in cy.iter().enumerate() {
        for x in 0..width {
            for c in 0..3 {
                let v: f64 = w
                    .iter()
                    .enumerate()
                    .map(|(k, wk)| wk * tmp[((lo + k) * width + x) * 3 + c])
                    .sum();
                out.data[(y * width + x) * 3 + c] = v.clamp(0.0, 1.0) as f32;
            }
        }
    }
    out
}

/// CLIP preprocessing without the mean/std normalization (CLIP applies that itself):
/// shorter side → `size` (longer side `⌊size · long / short⌋`, as transformers computes it),
/// then the centre `size × size` crop with offsets `⌊(dim − size) / 2⌋`.
pub fn clip_preprocess(img: &Image, size: usize) -> Image {
    let (w, h) = (img.width.max(1), img.height.max(1));
    let (nw, nh) = if w <= h {
        (size, (size as f64 * h as f64 / w as f64) as usize)
    } else {
        ((size as f64 * w as f64 / h as f64) as usize, size)
    };
    let r = resize(img, nw.max(size), nh.max(size));
    let (left, top) = ((r.width - size) / 2, (r.height - size) / 2);
    let mut out = Image::new(size, size);
    for y in 0..size {
        let src = ((top + y) * r.width + left) * 3;
        out.data[y * size * 3..(y + 1) * size * 3].copy_from_slice(&r.data[src..src + size * 3]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 9 × 6 test picture of `tests/fixtures/optimize/make_reference_fixture.py`.
    fn picture() -> Image {
        let mut im = Image::new(9, 6);
        for y in 0..6 {
            for x in 0..9 {
                let v = [
                    (x * 29 + y * 7) % 256,
                    (x * 3 + y * 41) % 256,
                    (x * y * 13 + 50) % 256,
                ];
                im.set_pixel(x, y, v.map(|v| v as f32 / 255.0));
            }
        }
        im
    }

    #[test]
    fn matches_pil_bicubic_and_hf_center_crop() {
        // Golden from PIL 13 (the script above): resize (6, 4) bicubic, then crop 4 × 4 at
        // left = (6 − 4) // 2 = 1, as CLIPImageProcessor does for shortest_edge = crop = 4.
        let golden: [[u8; 3]; 16] = include!("../../tests/fixtures/optimize/reference_golden.in");
        let out = clip_preprocess(&picture(), 4);
        assert_eq!((out.width, out.height), (4, 4));
        // PIL rounds to 8 bits after each of its two passes and uses 22-bit fixed-point
        // weights: at most 0.5/255 per pass reaches the output, so 1.5/255 bounds the gap.
        // (Measured: 0.75/255 at worst.)
        for (i, (g, ours)) in golden.iter().flatten().zip(&out.data).enumerate() {
            let ours = ours * 255.0;
            assert!((ours - *g as f32).abs() <= 1.5, "value {i}: {ours} vs {g}");
        }
    }

    #[test]
    fn constant_stays_constant_and_sizes_follow_transformers() {
        let im = Image::filled(37, 23, [0.25, 0.5, 1.0]);
        let out = clip_preprocess(&im, 8);
        assert_eq!((out.width, out.height), (8, 8));
        for px in out.data.chunks_exact(3) {
            assert!(
                (px[0] - 0.25).abs() < 1e-6
                    && (px[1] - 0.5).abs() < 1e-6
                    && (px[2] - 1.0).abs() < 1e-6
            );
        }
        // Upscaling a tiny picture and a 1-pixel one.
        let up = clip_preprocess(&Image::filled(2, 3, [0.5; 3]), 16);
        assert_eq!((up.width, up.height), (16, 16));
        assert!(up.data.iter().all(|v| (v - 0.5).abs() < 1e-6));
        let one = clip_preprocess(&Image::filled(1, 1, [0.1; 3]), 5);
        assert!(one.data.iter().all(|v| (v - 0.1).abs() < 1e-6));
    }

    #[test]
    fn shrinking_averages_instead_of_aliasing() {
        // A 1-pixel checkerboard shrunk 8×: PIL's widened support gives ~0.5 everywhere,
        // where point sampling would return 0 or 1.
        let mut im = Image::new(64, 64);
        for y in 0..64 {
            for x in 0..64 {
                im.set_pixel(x, y, [((x + y) % 2) as f32; 3]);
            }
        }
        let out = resize(&im, 8, 8);
        assert!(
            out.data.iter().all(|v| (v - 0.5).abs() < 0.02),
            "{:?}",
            &out.data[..6]
        );
    }
}
