//! RGB images as f32 in [0, 1], row-major from the top row, and PNG input/output.
//!
//! This is the currency between the renderer and CLIP: the renderer writes `Image`s, CLIP's
//! image encoder reads them, and CLIP's backward returns a gradient of the same shape.

use std::io::BufReader;
use std::path::{Path, PathBuf};

use crate::memory::Budget;

/// Why a PNG could not be read or written; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be opened.
    #[error("{}: cannot open", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The header is not a PNG's.
    #[error("{}: not a readable PNG", path.display())]
    NotPng {
        /// The file.
        path: PathBuf,
        /// What the decoder said.
        source: png::DecodingError,
    },
    /// The pixel data does not decode.
    #[error("{}: corrupt PNG data", path.display())]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What the decoder said.
        source: png::DecodingError,
    },
    /// A 0-pixel-wide or -high image.
    #[error("{}: image has no pixels", path.display())]
    NoPixels {
        /// The file.
        path: PathBuf,
    },
    /// The size the header claims does not fit the memory budget.
    #[error(transparent)]
    TooLarge(#[from] crate::memory::MemoryError),
    /// The image could not be encoded as a PNG.
    #[error("{}: writing failed", path.display())]
    Encode {
        /// The file it was meant for.
        path: PathBuf,
        /// What the encoder said.
        source: png::EncodingError,
    },
    /// The encoded file could not be written (`crate::fs`'s error, which names the file).
    #[error(transparent)]
    Write(#[from] crate::fs::FsError),
}

impl ImageError {
    /// What a front end needs to word its advice.
    pub fn hint(&self) -> crate::error::Hint {
        use crate::error::{ErrorKind, Hint};
        match self {
            ImageError::Open { .. } => Hint::new(ErrorKind::Io),
            ImageError::TooLarge(m) => m.hint(),
            ImageError::Write(w) => w.hint(),
            _ => Hint::other(),
        }
    }
}

/// An RGB image: `data[(y * width + x) * 3 + c]`, y = 0 is the top row.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// RGB values, `width · height · 3` of them.
    pub data: Vec<f32>,
}

impl Image {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Image {
        Image {
            width,
            height,
            data: vec![0.0; width * height * 3],
        }
    }

    /// An image of one colour.
    pub fn filled(width: usize, height: usize, rgb: [f32; 3]) -> Image {
        let mut im = Image::new(width, height);
        for px in im.data.chunks_exact_mut(3) {
            px.copy_from_slice(&rgb);
        }
        im
    }

    /// The colour at column `x`, row `y` (0: top).
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        let i = (y * self.width + x) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Set the colour at column `x`, row `y` (0: top).
    #[inline]
    pub fn set_pixel(&mut self, x: usize, y: usize, rgb: [f32; 3]) {
        let i = (y * self.width + x) * 3;
        self.data[i..i + 3].copy_from_slice(&rgb);
    }

    /// `images` in a grid of `cols` columns (rows as needed), cell size that of the first
    /// image; an image of another size leaves its cell black. No images: a 1 × 1 black image.
    pub fn grid(images: &[Image], cols: usize) -> Image {
        let Some(first) = images.first() else {
            return Image::new(1, 1);
        };
        let (w, h) = (first.width, first.height);
        let cols = cols.clamp(1, images.len());
        let rows = images.len().div_ceil(cols);
        let mut out = Image::new(w * cols, h * rows);
        for (i, im) in images.iter().enumerate() {
            if im.width != w || im.height != h {
                continue;
            }
            let (ox, oy) = ((i % cols) * w, (i / cols) * h);
            for y in 0..h {
                let dst = ((oy + y) * out.width + ox) * 3;
                out.data[dst..dst + w * 3].copy_from_slice(&im.data[y * w * 3..(y + 1) * w * 3]);
            }
        }
        out
    }

    /// 8-bit RGB bytes, clamped and rounded; NaN becomes 0.
    pub fn to_rgb8(&self) -> Vec<u8> {
        self.data
            .iter()
            .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect()
    }

    /// Write an 8-bit RGB PNG atomically (temporary file in the same folder, then rename).
    pub fn save_png(&self, path: &Path) -> Result<(), ImageError> {
        // Encoded in memory first (previews and plots are small), so that the file is
        // written by one call whatever `crate::fs`'s writer type is.
        let mut png_bytes = Vec::new();
        self.encode_png(&mut png_bytes)
            .map_err(|source| ImageError::Encode {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(crate::fs::atomic_write_bytes(path, &png_bytes)?)
    }

    /// The 8-bit RGB PNG encoding of the image, appended to `out`.
    fn encode_png(&self, out: &mut Vec<u8>) -> Result<(), png::EncodingError> {
        let mut enc = png::Encoder::new(out, self.width as u32, self.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header()?;
        writer.write_image_data(&self.to_rgb8())?;
        writer.finish()
    }

    /// Read a PNG (gray, gray+alpha, RGB, RGBA; 8 or 16 bit) as RGB in [0, 1]. Alpha is dropped.
    /// Its size is checked against what the system has ([`Budget::system`]).
    pub fn load_png(path: &Path) -> Result<Image, ImageError> {
        Image::load_png_within(path, Budget::system())
    }

    /// [`Image::load_png`], the decoded size checked against `budget` before allocating.
    pub fn load_png_within(path: &Path, budget: Budget) -> Result<Image, ImageError> {
        let file = crate::input::open(path).map_err(|source| ImageError::Open {
            path: path.to_path_buf(),
            source,
        })?;
        let mut decoder = png::Decoder::new(BufReader::new(file));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(|source| ImageError::NotPng {
            path: path.to_path_buf(),
            source,
        })?;
        // The header's size is the file's claim: check it before allocating (a 74-byte file
        // can claim 100000² pixels).
        let (w, h) = reader.info().size();
        budget.check(
            format!("{}: a {w}×{h} image", path.display()),
            crate::memory::product(&[w as usize, h as usize]),
            // the decoded 16-bit RGBA row bytes and the f32 RGB copy
            8 + 12,
            "use a smaller picture",
        )?;
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader
            .next_frame(&mut buf)
            .map_err(|source| ImageError::Corrupt {
                path: path.to_path_buf(),
                source,
            })?;
        let (w, h) = (info.width as usize, info.height as usize);
        let channels = info.color_type.samples();
        let sixteen = info.bit_depth == png::BitDepth::Sixteen;
        let sample = |i: usize| -> f32 {
            if sixteen {
                u16::from_be_bytes([buf[2 * i], buf[2 * i + 1]]) as f32 / 65535.0
            } else {
                buf[i] as f32 / 255.0
            }
        };
        if w == 0 || h == 0 {
            return Err(ImageError::NoPixels {
                path: path.to_path_buf(),
            });
        }
        let mut im = Image::new(w, h);
        for p in 0..w * h {
            let base = p * channels;
            let rgb = match channels {
                1 | 2 => [sample(base); 3],
                _ => [sample(base), sample(base + 1), sample(base + 2)],
            };
            im.data[p * 3..p * 3 + 3].copy_from_slice(&rgb);
        }
        Ok(im)
    }
}

/// The mean squared error [`psnr`] floors at: 1e-20, so its ceiling is 200 dB. Equal images
/// get a finite PSNR, which means over views and report.json (JSON has no infinity) can carry;
/// the ceiling lies far above any two renders that differ at all in their rounding (one f32
/// ulp at 1.0 on every channel is 138 dB), so it never hides a measured difference.
const PSNR_MSE_FLOOR: f64 = 1e-20;

/// The PSNR of t2tf: `a` against `b` in dB, peak 1 (images are RGB in [0, 1]), from the mean
/// squared error over every channel of every pixel, floored at 1e-20: equal images give
/// 200 dB, not infinity, so means over views and JSON stay finite, and no two renders that
/// differ at all come near it (one f32 ulp at 1.0 on every channel is 138 dB). Several views
/// are compared either as the mean of this per view (`optimize::recover::psnr`, the recovery
/// test's measure) or pooled, as the PSNR of the views side by side (`Image::grid(views,
/// views.len())`, what the benchmarks print).
///
/// # Panics
/// If the two images differ in size (a caller's bug, not an input error).
pub fn psnr(a: &Image, b: &Image) -> f64 {
    assert_eq!(
        (a.width, a.height, a.data.len()),
        (b.width, b.height, b.data.len()),
        "psnr: images of different sizes"
    );
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(&x, &y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.data.len().max(1) as f64;
    -10.0 * mse.max(PSNR_MSE_FLOOR).log10()
}

/// Bilinear resampling of a `w`×`h` grid of `channels` interleaved values to `nw`×`nh`, pixel
/// centres aligned (source coordinate (x + ½)·w/nw − ½, clamped at the edges: PyTorch's
/// `interpolate(mode="bilinear", align_corners=False)` without antialiasing). Used to render
/// below CLIP's input size and upsample; [`resize_bilinear_adjoint`] is its exact transpose.
pub fn resize_bilinear(
    src: &[f32],
    (w, h): (usize, usize),
    channels: usize,
    (nw, nh): (usize, usize),
) -> Vec<f32> {
    assert_eq!(src.len(), w * h * channels, "resize_bilinear: source size");
    let mut out = vec![0.0f32; nw * nh * channels];
    for_each_corner((w, h), (nw, nh), |o, s, weight| {
        for c in 0..channels {
            out[o * channels + c] += weight * src[s * channels + c];
        }
    });
    out
}

// Mirrors `resize_bilinear` (the same corners, gathered there and scattered here); kept as two
// functions so each reads as the formula it is.
/// The transpose of [`resize_bilinear`]: the gradient with respect to the `w`×`h` source of
/// a loss whose gradient with respect to the `nw`×`nh` result is `d`.
pub fn resize_bilinear_adjoint(
    d: &[f32],
    (nw, nh): (usize, usize),
    channels: usize,
    (w, h): (usize, usize),
) -> Vec<f32> {
    assert_eq!(
        d.len(),
        nw * nh * channels,
        "resize_bilinear_adjoint: gradient size"
    );
    let mut out = vec![0.0f32; w * h * channels];
    for_each_corner((w, h), (nw, nh), |o, s, weight| {
        for c in 0..channels {
            out[s * channels + c] += weight * d[o * channels + c];
        }
    });
    out
}

/// Every (output pixel, source pixel, weight) term of bilinear resampling from `w`×`h` to
/// `nw`×`nh`: the four corners around each output pixel's source position.
fn for_each_corner(
    (w, h): (usize, usize),
    (nw, nh): (usize, usize),
    mut term: impl FnMut(usize, usize, f32),
) {
    let (tx, ty) = (taps(w, nw), taps(h, nh));
    for (y, &(y0, y1, fy)) in ty.iter().enumerate() {
        for (x, &(x0, x1, fx)) in tx.iter().enumerate() {
            let o = y * nw + x;
            term(o, y0 * w + x0, (1.0 - fy) * (1.0 - fx));
            term(o, y0 * w + x1, (1.0 - fy) * fx);
            term(o, y1 * w + x0, fy * (1.0 - fx));
            term(o, y1 * w + x1, fy * fx);
        }
    }
}

/// Per output index along one axis of `n` → `nn` points: (lower source, upper source, weight
/// of the upper).
fn taps(n: usize, nn: usize) -> Vec<(usize, usize, f32)> {
    (0..nn)
        .map(|i| {
            let x = ((i as f64 + 0.5) * n as f64 / nn as f64 - 0.5).clamp(0.0, (n - 1) as f64);
            let x0 = (x.floor() as usize).min(n - 1);
            let x1 = (x0 + 1).min(n - 1);
            (x0, x1, (x - x0 as f64) as f32)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_is_20_db_for_a_tenth_everywhere_and_200_for_equal_images() {
        let (a, b) = (Image::filled(3, 2, [0.5; 3]), Image::filled(3, 2, [0.6; 3]));
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-5, "{}", psnr(&a, &b));
        assert_eq!(psnr(&a, &a), 200.0);
        // Pooled over views (the benchmarks' measure): one view off by 0.1, one equal.
        let pooled = psnr(
            &Image::grid(&[a.clone(), a.clone()], 2),
            &Image::grid(&[b, a], 2),
        );
        assert!((pooled - 23.0103).abs() < 1e-3, "{pooled}");
    }

    #[test]
    fn png_round_trip_is_exact_at_8_bit() {
        let dir = tempfile::tempdir().unwrap();
        let mut im = Image::new(5, 3);
        for (i, v) in im.data.iter_mut().enumerate() {
            *v = (i * 17 % 256) as f32 / 255.0;
        }
        let p = dir.path().join("a.png");
        im.save_png(&p).unwrap();
        let back = Image::load_png(&p).unwrap();
        assert_eq!(back.width, 5);
        assert_eq!(back.height, 3);
        for (a, b) in im.data.iter().zip(&back.data) {
            assert!((a - b).abs() < 1e-6);
        }
    }

    #[test]
    fn bad_png_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.png");
        std::fs::write(&p, b"not a png").unwrap();
        let e = Image::load_png(&p).unwrap_err();
        assert!(format!("{e:#}").contains("bad.png"));
    }

    #[test]
    fn bilinear_resize_is_exact_on_linear_images_and_its_adjoint_is_the_transpose() {
        // A linear ramp upsamples to the same ramp (away from the clamped border).
        let (w, h, nw, nh) = (6, 5, 14, 11);
        let ramp: Vec<f32> = (0..w * h * 2)
            .map(|i| {
                let (p, c) = (i / 2, i % 2);
                (p % w) as f32 * 0.3 + (p / w) as f32 * 0.2 + c as f32
            })
            .collect();
        let up = resize_bilinear(&ramp, (w, h), 2, (nw, nh));
        for y in 2..nh - 2 {
            for x in 2..nw - 2 {
                let sx = (x as f32 + 0.5) * w as f32 / nw as f32 - 0.5;
                let sy = (y as f32 + 0.5) * h as f32 / nh as f32 - 0.5;
                let want = sx * 0.3 + sy * 0.2 + 1.0;
                assert!((up[(y * nw + x) * 2 + 1] - want).abs() < 1e-5);
            }
        }
        // Same size: the identity.
        assert_eq!(resize_bilinear(&ramp, (w, h), 2, (w, h)), ramp);
        // <U a, b> = <a, Uᵀ b> for arbitrary a, b.
        let a: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 37 % 11) as f32 - 5.0) / 7.0)
            .collect();
        let b: Vec<f32> = (0..nw * nh * 3)
            .map(|i| ((i * 53 % 13) as f32 - 6.0) / 5.0)
            .collect();
        let ua = resize_bilinear(&a, (w, h), 3, (nw, nh));
        let utb = resize_bilinear_adjoint(&b, (nw, nh), 3, (w, h));
        let lhs: f64 = ua
            .iter()
            .zip(&b)
            .map(|(x, y)| (*x as f64) * (*y as f64))
            .sum();
        let rhs: f64 = a
            .iter()
            .zip(&utb)
            .map(|(x, y)| (*x as f64) * (*y as f64))
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-4 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }
}
