//! What `transformers`' `CLIPImageProcessor` does to an arbitrary picture before CLIP sees it:
//! resize so the shortest side is `size` with bicubic resampling (Pillow's antialiased filter,
//! a = −0.5, support widened by the downscale factor), then a centred `size`×`size` crop.
//! Normalisation by CLIP's mean/std happens inside the encoder. Unlike Pillow on 8-bit images,
//! no rounding to 8 bits happens between or after the passes (values stay f32, clamped to
//! [0, 1]).

use crate::config::ConfigError;
use std::path::Path;

use serde_json::Value;

use super::ClipError;
use t2tf_core::image::Image;

/// OpenAI CLIP's pixel statistics (`image_mean` / `image_std` of CLIPImageProcessor), written
/// with the digits published in its preprocessor_config.json: the fallback where a model has
/// no such file.
#[allow(clippy::excessive_precision)]
pub const MEAN: [f32; 3] = [0.481_454_66, 0.457_827_5, 0.408_210_73];
/// See [`MEAN`].
#[allow(clippy::excessive_precision)]
pub const STD: [f32; 3] = [0.268_629_54, 0.261_302_58, 0.275_777_11];

/// What a model's image processor does, from its `preprocessor_config.json`
/// (`transformers`' `CLIPImageProcessor` keys), or CLIP's constants without one.
#[derive(Clone, Debug, PartialEq)]
pub struct Preprocessing {
    /// Per-channel mean subtracted from [0, 1] pixels (`image_mean`).
    pub mean: [f32; 3],
    /// Per-channel divisor after the mean (`image_std`).
    pub std: [f32; 3],
    /// Shortest side after the resize (`size`, or `size.shortest_edge`).
    pub resize: usize,
    /// Side of the centre crop: the vision tower's input (`crop_size`).
    pub crop: usize,
}

impl Preprocessing {
    /// OpenAI CLIP's processor for a vision tower taking `image_size`² pictures: resize and
    /// crop to that size, [`MEAN`] / [`STD`].
    pub fn clip(image_size: usize) -> Preprocessing {
        Preprocessing {
            mean: MEAN,
            std: STD,
            resize: image_size,
            crop: image_size,
        }
    }

    /// Read `preprocessor_config.json` for a vision tower taking `image_size`² pictures. Keys
    /// left out keep CLIP's values (as `CLIPImageProcessor`'s defaults do); `do_normalize:
    /// false` means mean 0 and std 1. A crop that is not `image_size` (the tower could not
    /// take it), a non-positive std or a malformed value is an error naming the file.
    pub fn from_file(path: &Path, image_size: usize) -> Result<Preprocessing, ClipError> {
        let text = t2tf_core::input::read_to_string(path).map_err(|e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Preprocessing::from_json(&text, image_size).map_err(|e| ClipError::Config {
            path: path.to_path_buf(),
            msg: format!("preprocessor config: {e}"),
        })
    }

    /// As [`Preprocessing::from_file`], from the file's text.
    pub fn from_json(text: &str, image_size: usize) -> Result<Preprocessing, ConfigError> {
        Preprocessing::parse(text, image_size).map_err(ConfigError)
    }

    /// [`Preprocessing::from_json`], the error as text.
    fn parse(text: &str, image_size: usize) -> Result<Preprocessing, String> {
        let v: Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
        if !v.is_object() {
            return Err("not a JSON object".into());
        }
        let mut p = Preprocessing::clip(image_size);
        let triple = |key: &str| -> Result<Option<[f32; 3]>, String> {
            let Some(x) = v.get(key).filter(|x| !x.is_null()) else {
                return Ok(None);
            };
            let bad = || format!("{key} must be 3 finite numbers (one per RGB channel), got {x}");
            let a = x.as_array().filter(|a| a.len() == 3).ok_or_else(bad)?;
            let mut out = [0.0f32; 3];
            for (o, e) in out.iter_mut().zip(a) {
                *o = e.as_f64().filter(|f| f.is_finite()).ok_or_else(bad)? as f32;
            }
            Ok(Some(out))
        };
        if v.get("do_normalize").and_then(Value::as_bool) == Some(false) {
            (p.mean, p.std) = ([0.0; 3], [1.0; 3]);
        } else {
            if let Some(m) = triple("image_mean")? {
                p.mean = m;
            }
            if let Some(s) = triple("image_std")? {
                if s.iter().any(|&x| x <= 0.0) {
                    return Err(format!("image_std must be positive, got {s:?}"));
                }
                p.std = s;
            }
        }
        // `size` is an int (older files) or {"shortest_edge": n} / {"height": h, "width": w};
        // `crop_size` an int or {"height": h, "width": w}.
        let side = |key: &str, names: &[&str]| -> Result<Option<usize>, String> {
            let Some(x) = v.get(key).filter(|x| !x.is_null()) else {
                return Ok(None);
            };
            let bad =
                || format!("{key} must be a positive size or a square {{height, width}}, got {x}");
            let get = |n: &str| x.get(n).and_then(Value::as_u64);
            let n = match x.as_u64() {
                Some(n) => n,
                None => match names.iter().find_map(|n| get(n)) {
                    Some(n) => n,
                    None => match (get("height"), get("width")) {
                        (Some(h), Some(w)) if h == w => h,
                        _ => return Err(bad()),
                    },
                },
            };
            usize::try_from(n)
                .ok()
                .filter(|&n| n > 0)
                .map(Some)
                .ok_or_else(bad)
        };
        if let Some(r) = side("size", &["shortest_edge"])? {
            p.resize = r;
        }
        if v.get("do_center_crop").and_then(Value::as_bool) == Some(false) {
            p.crop = p.resize;
        } else if let Some(c) = side("crop_size", &[])? {
            p.crop = c;
        }
        if p.crop != image_size {
            return Err(format!(
                "the processor crops to {}x{0} but config.json's vision tower takes {image_size}x{image_size}",
                p.crop
            ));
        }
        if p.resize < p.crop {
            return Err(format!(
                "resizing to {} cannot be cropped to {}",
                p.resize, p.crop
            ));
        }
        Ok(p)
    }

    /// Resize (shortest side → `resize`, bicubic) and centre-crop to `crop`² (no
    /// normalisation: the encoder applies `mean` / `std`).
    pub fn apply(&self, im: &Image) -> Image {
        resize_and_crop(im, self.resize, self.crop)
    }
}

/// Resize (shortest side → `size`, bicubic) and centre-crop to `size`×`size`.
pub fn preprocess(im: &Image, size: usize) -> Image {
    resize_and_crop(im, size, size)
}

/// Resize so the shortest side is `size` (bicubic), then centre-crop to `crop`×`crop`
/// (`crop` ≤ `size`). Only the cropped window is resampled, from the input rows it reaches:
/// the same values as resizing whole and cropping, in memory bounded by `crop` and the input,
/// whatever the picture's shape (a 1 × 1,000,000 picture would resize to 224 × 224,000,000).
fn resize_and_crop(im: &Image, size: usize, crop: usize) -> Image {
    let (w, h) = (im.width, im.height);
    if w == 0 || h == 0 || size == 0 || crop > size {
        return Image::new(crop, crop);
    }
    let (nw, nh) = resized_size(w, h, size);
    // As transformers' center_crop: the offset rounds down, as for an integer division.
    let (top, left) = ((nh - crop) / 2, (nw - crop) / 2);
    let mut out = Image::new(crop, crop);
    if (nw, nh) == (w, h) {
        for y in 0..crop {
            let src = &im.data[((top + y) * w + left) * 3..][..crop * 3];
            out.data[y * crop * 3..][..crop * 3].copy_from_slice(src);
        }
        return out;
    }
    let xs = taps(w, nw, left..left + crop);
    let ys = taps(h, nh, top..top + crop);
    // The input rows the cropped rows reach.
    let r0 = ys.iter().map(|t| t.0).min().unwrap_or(0);
    let r1 = ys.iter().map(|t| t.0 + t.1.len()).max().unwrap_or(0);
    // Horizontal pass over those rows, cropped columns only: (r1 − r0) × crop.
    let mut horiz = vec![0.0f32; (r1 - r0) * crop * 3];
    for (row, y) in (r0..r1).enumerate() {
        for (x, (lo, ws)) in xs.iter().enumerate() {
            let px = convolve(ws, |j| &im.data[(y * w + lo + j) * 3..][..3]);
            horiz[(row * crop + x) * 3..][..3].copy_from_slice(&px);
        }
    }
    for (y, (lo, ws)) in ys.iter().enumerate() {
        for x in 0..crop {
            let px = convolve(ws, |j| &horiz[((lo + j - r0) * crop + x) * 3..][..3]);
            out.data[(y * crop + x) * 3..][..3].copy_from_slice(&px);
        }
    }
    out
}

/// The picture's size once its shortest side is `size`: as transformers'
/// get_resize_output_image_size, the long side is truncated, not rounded.
fn resized_size(w: usize, h: usize, size: usize) -> (usize, usize) {
    if w <= h {
        (
            size,
            ((size as f64 * h as f64 / w as f64) as usize).max(size),
        )
    } else {
        (
            ((size as f64 * w as f64 / h as f64) as usize).max(size),
            size,
        )
    }
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

/// For each output sample in `range` of an axis resampled from `in_len` to `out_len`: the
/// first input index and the normalized weights of the inputs from there (Pillow's bicubic
/// resampling, widened by the scale when shrinking).
fn taps(in_len: usize, out_len: usize, range: std::ops::Range<usize>) -> Vec<(usize, Vec<f64>)> {
    let scale = in_len as f64 / out_len as f64;
    let filter_scale = scale.max(1.0);
    let support = 2.0 * filter_scale;
    range
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
        .collect()
}

/// One RGB output sample: the weighted sum of the inputs `pixel(j)`, clamped to [0, 1].
fn convolve<'a>(ws: &[f64], pixel: impl Fn(usize) -> &'a [f32]) -> [f32; 3] {
    let mut acc = [0.0f64; 3];
    for (j, wt) in ws.iter().enumerate() {
        let p = pixel(j);
        for c in 0..3 {
            acc[c] += wt * p[c] as f64;
        }
    }
    acc.map(|v| v.clamp(0.0, 1.0) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The whole resize then the crop, written plainly: what the window must equal.
    fn resize_whole_then_crop(im: &Image, size: usize, crop: usize) -> Image {
        let (w, h) = (im.width, im.height);
        let (nw, nh) = resized_size(w, h, size);
        let xs = taps(w, nw, 0..nw);
        let ys = taps(h, nh, 0..nh);
        let mut horiz = vec![0.0f32; nw * h * 3];
        for y in 0..h {
            for (x, (lo, ws)) in xs.iter().enumerate() {
                let px = convolve(ws, |j| &im.data[(y * w + lo + j) * 3..][..3]);
                horiz[(y * nw + x) * 3..][..3].copy_from_slice(&px);
            }
        }
        let (top, left) = ((nh - crop) / 2, (nw - crop) / 2);
        let mut out = Image::new(crop, crop);
        for y in 0..crop {
            let (lo, ws) = &ys[top + y];
            for x in 0..crop {
                let px = convolve(ws, |j| &horiz[((lo + j) * nw + left + x) * 3..][..3]);
                out.data[(y * crop + x) * 3..][..3].copy_from_slice(&px);
            }
        }
        out
    }

    #[test]
    fn the_window_equals_the_whole_resize_bit_for_bit() {
        for (w, h, size, crop) in [
            (300, 200, 224, 224),
            (97, 431, 64, 48),
            (640, 480, 256, 224),
            (5, 3, 32, 32),
        ] {
            let data = (0..w * h * 3)
                .map(|i| ((i * 2654435761usize) % 1000) as f32 / 999.0)
                .collect();
            let im = Image {
                width: w,
                height: h,
                data,
            };
            let a = resize_and_crop(&im, size, crop);
            let b = resize_whole_then_crop(&im, size, crop);
            assert!(
                a.data
                    .iter()
                    .zip(&b.data)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "{w}x{h}"
            );
        }
    }

    /// Pictures of extreme shape resize within memory bounded by the crop and the input.
    #[test]
    fn extreme_shapes_cost_the_window_only() {
        for (w, h) in [(1, 1_000_000), (100_000, 1)] {
            let im = Image::filled(w, h, [0.25, 0.5, 0.75]);
            let t = std::time::Instant::now();
            let out = preprocess(&im, 224);
            assert_eq!((out.width, out.height), (224, 224));
            assert!(out.data.chunks_exact(3).all(|p| (p[1] - 0.5).abs() < 1e-6));
            assert!(
                t.elapsed().as_secs_f64() < 5.0,
                "{w}x{h}: {:?}",
                t.elapsed()
            );
        }
    }

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

    #[test]
    fn preprocessor_config_is_read_and_checked() {
        // OpenAI's file (clip-vit-base-patch32), older int sizes.
        let openai = r#"{"crop_size": 224, "do_center_crop": true, "do_normalize": true,
            "do_resize": true, "feature_extractor_type": "CLIPFeatureExtractor",
            "image_mean": [0.48145466, 0.4578275, 0.40821073],
            "image_std": [0.26862954, 0.26130258, 0.27577711], "resample": 3, "size": 224}"#;
        assert_eq!(
            Preprocessing::from_json(openai, 224).unwrap(),
            Preprocessing::clip(224)
        );
        // Newer dict sizes and other statistics (SigLIP-like: mean = std = 0.5).
        let other = r#"{"crop_size": {"height": 256, "width": 256},
            "size": {"shortest_edge": 288}, "image_mean": [0.5, 0.5, 0.5],
            "image_std": [0.5, 0.5, 0.5]}"#;
        let p = Preprocessing::from_json(other, 256).unwrap();
        assert_eq!(
            (p.mean, p.std, p.resize, p.crop),
            ([0.5; 3], [0.5; 3], 288, 256)
        );
        assert_eq!(p.apply(&Image::new(400, 300)).width, 256);
        // Keys left out keep CLIP's values; no normalisation is mean 0, std 1.
        assert_eq!(
            Preprocessing::from_json("{}", 32).unwrap(),
            Preprocessing::clip(32)
        );
        let p = Preprocessing::from_json(r#"{"do_normalize": false}"#, 32).unwrap();
        assert_eq!((p.mean, p.std), ([0.0; 3], [1.0; 3]));
        for (bad, says) in [
            (r#"{"crop_size": 336}"#, "takes 224x224"),
            (r#"{"image_std": [0.5, 0.0, 0.5]}"#, "positive"),
            (r#"{"image_mean": [0.5, 0.5]}"#, "3 finite numbers"),
            (r#"{"size": {"height": 224, "width": 300}}"#, "square"),
            (r#"{"size": 100}"#, "cannot be cropped"),
            ("[1, 2]", "not a JSON object"),
        ] {
            let e = Preprocessing::from_json(bad, 224).unwrap_err();
            assert!(e.0.contains(says), "{bad}: {e}");
        }
    }
}
