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
        let text = std::fs::read_to_string(path).map_err(|e| ClipError::Io {
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
/// (`crop` ≤ `size`).
fn resize_and_crop(im: &Image, size: usize, crop: usize) -> Image {
    let (w, h) = (im.width, im.height);
    if w == 0 || h == 0 || size == 0 || crop > size {
        return Image::new(crop, crop);
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
    // As transformers' center_crop: the offset rounds down, as for an integer division.
    let (top, left) = ((nh - crop) / 2, (nw - crop) / 2);
    let mut out = Image::new(crop, crop);
    for y in 0..crop {
        let src = &resized.data[((top + y) * nw + left) * 3..][..crop * 3];
        out.data[y * crop * 3..][..crop * 3].copy_from_slice(src);
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
