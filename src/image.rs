//! RGB images as f32 in [0, 1], row-major from the top row, and PNG input/output.
//!
//! This is the currency between the renderer and CLIP: the renderer writes `Image`s, CLIP's
//! image encoder reads them, and CLIP's backward returns a gradient of the same shape.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use anyhow::{bail, Context, Result};

/// An RGB image: `data[(y * width + x) * 3 + c]`, y = 0 is the top row.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Image {
    pub fn new(width: usize, height: usize) -> Image {
        Image {
            width,
            height,
            data: vec![0.0; width * height * 3],
        }
    }

    pub fn filled(width: usize, height: usize, rgb: [f32; 3]) -> Image {
        let mut im = Image::new(width, height);
        for px in im.data.chunks_exact_mut(3) {
            px.copy_from_slice(&rgb);
        }
        im
    }

    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        let i = (y * self.width + x) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    #[inline]
    pub fn set_pixel(&mut self, x: usize, y: usize, rgb: [f32; 3]) {
        let i = (y * self.width + x) * 3;
        self.data[i..i + 3].copy_from_slice(&rgb);
    }

    /// 8-bit RGB bytes, clamped and rounded; NaN becomes 0.
    pub fn to_rgb8(&self) -> Vec<u8> {
        self.data
            .iter()
            .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect()
    }

    /// Write an 8-bit RGB PNG atomically (temporary file in the same folder, then rename).
    pub fn save_png(&self, path: &Path) -> Result<()> {
        let bytes = self.to_rgb8();
        crate::formats::atomic_write(path, |w| {
            let mut enc = png::Encoder::new(w, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut writer = enc.write_header()?;
            writer.write_image_data(&bytes)?;
            writer.finish()?;
            Ok(())
        })
    }

    /// Read a PNG (gray, gray+alpha, RGB, RGBA; 8 or 16 bit) as RGB in [0, 1]. Alpha is dropped.
    pub fn load_png(path: &Path) -> Result<Image> {
        let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        let mut decoder = png::Decoder::new(BufReader::new(file));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder
            .read_info()
            .with_context(|| format!("{}: not a readable PNG", path.display()))?;
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader
            .next_frame(&mut buf)
            .with_context(|| format!("{}: corrupt PNG data", path.display()))?;
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
            bail!("{}: image has no pixels", path.display());
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
