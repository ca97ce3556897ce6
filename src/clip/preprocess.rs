//! What `transformers`' `CLIPImageProcessor` does to an arbitrary picture before CLIP sees it:
//! resize so the shortest side is `size` with bicubic resampling (Pillow's antialiased filter,
//! a = −0.5, support widened by the downscale factor), then a centred `size`×`size` crop.
//! Normalisation by CLIP's mean/std happens inside the encoder. Unlike Pillow on 8-bit images,
//! no rounding to 8 bits happens between or after the passes (values stay f32, clamped to
//! [0, 1]).

use crate::image::Image;

/// Resize (shortest side → `size`, bicubic) and centre-crop to `size`×`size`.
pub fn preprocess(im: &Image, size: usize) -> Image {
    let (w, h) = (im.width, im.height);
    if w == 0 || h == 0 || size == 0 {
        return Image::new(size, size);
    }
    // As transformers' get_resize_output_image_size: the long side is truncated, not rounded.
    let (nw, nh) = if w <= h {
        (
            size,
            ((size as f64 * h as f64 / w as f64) as usize).max(size),
        )
    } else {
        (
            ((size as f64 * w as f64 / h as f64) as usize).max(size),
            size,
        )
    };
    let resized = if (nw, nh) == (w, h) {
        im.clone()
    } else {
        let horiz = resample_axis(&im.data, w, h, nw, true);
        let data = resample_axis(&horiz, nw, h, nh, false);
        Image {
            width: nw,
            height: nh,
            data,
        }
    };
    let (top, left) = ((nh - size) / 2, (nw - size) / 2);
    let mut out = Image::new(size, size);
    for y in 0..size {
        let src = &resized.data[((top + y) * nw + left) * 3..][..size * 3];
        out.data[y * size * 3..][..size * 3].copy_from_slice(src);
    }
    out
}

/// Pillow's bicubic kernel with a = −0.5.
fn cubic(x: f64) -> f64 {
    let a = -0.5;
    let x = x.abs();
    if x < 1.0 {
        ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        (((x - 5.0) * x + 8.0) * x - 4.0) * a
    } else {
        0.0
    }
}

/// Resample RGB data along x (`horizontal`) or y to `out_len` samples.
fn resample_axis(data: &[f32], w: usize, h: usize, out_len: usize, horizontal: bool) -> Vec<f32> {
    let in_len = if horizontal { w } else { h };
    let scale = in_len as f64 / out_len as f64;
    let filter_scale = scale.max(1.0);
    let support = 2.0 * filter_scale;
    // Per output sample: first input index and normalized weights.
    let taps: Vec<(usize, Vec<f64>)> = (0..out_len)
        .map(|i| {
            let center = (i as f64 + 0.5) * scale;
            let lo = ((center - support + 0.5).floor().max(0.0)) as usize;
            let hi = ((center + support + 0.5).floor() as usize).min(in_len);
            let ws: Vec<f64> = (lo..hi)
                .map(|x| cubic((x as f64 - center + 0.5) / filter_scale))
                .collect();
            let sum: f64 = ws.iter().sum();
            (
                lo,
                ws.iter()
                    .map(|v| if sum != 0.0 { v / sum } else { 0.0 })
                    .collect(),
            )
        })
        .collect();
    let (ow, oh) = if horizontal {
        (out_len, h)
    } else {
        (w, out_len)
    };
    let mut out = vec![0.0f32; ow * oh * 3];
    for y in 0..oh {
        for x in 0..ow {
            let (i, fixed) = if horizontal { (x, y) } else { (y, x) };
            let (lo, ws) = &taps[i];
            let mut acc = [0.0f64; 3];
            for (j, wt) in ws.iter().enumerate() {
                let src = if horizontal {
                    (fixed * w + lo + j) * 3
                } else {
                    ((lo + j) * w + fixed) * 3
                };
                for c in 0..3 {
                    acc[c] += wt * data[src + c] as f64;
                }
            }
            for c in 0..3 {
                out[(y * ow + x) * 3 + c] = acc[c].clamp(0.0, 1.0) as f32;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_image_stays_constant_and_shapes_are_right() {
        let im = Image::filled(300, 200, [0.2, 0.5, 0.9]);
        let out = preprocess(&im, 224);
        assert_eq!((out.width, out.height), (224, 224));
        for px in out.data.chunks_exact(3) {
            assert!(
                (px[0] - 0.2).abs() < 1e-6
                    && (px[1] - 0.5).abs() < 1e-6
                    && (px[2] - 0.9).abs() < 1e-6
            );
        }
    }

    #[test]
    fn right_size_is_identity_and_crop_is_centred() {
        let mut im = Image::new(6, 4);
        for (i, v) in im.data.iter_mut().enumerate() {
            *v = (i % 17) as f32 / 17.0;
        }
        // Shortest side already 4: no resampling, 4x4 crop from x = 1.
        let out = preprocess(&im, 4);
        for y in 0..4 {
            for x in 0..4 {
                assert_eq!(out.pixel(x, y), im.pixel(x + 1, y));
            }
        }
    }

    #[test]
    fn downscale_by_two_averages_neighbourhoods() {
        // A vertical stripe pattern (period 2) downscaled 2x becomes uniform grey: the
        // antialiasing filter integrates over the stripes instead of sampling one of them.
        let mut im = Image::new(64, 64);
        for y in 0..64 {
            for x in 0..64 {
                let v = (x % 2) as f32;
                im.set_pixel(x, y, [v, v, v]);
            }
        }
        let out = preprocess(&im, 32);
        for x in 2..30 {
            assert!(
                (out.pixel(x, 10)[0] - 0.5).abs() < 0.02,
                "{:?}",
                out.pixel(x, 10)
            );
        }
    }
}
