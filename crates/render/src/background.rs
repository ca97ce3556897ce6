//! Background images composited behind the volume (the `B` of I = Σ Tₙ αₙ cₙ + T_N B).
//!
//! The paper (after Jain et al., "Zero-shot text-guided object generation with Dream Fields")
//! randomizes the background so that CLIP cannot be satisfied by colouring empty space: a
//! constant gray, a checkerboard, noise, and random Fourier feature images. Every kind is a pure
//! function of (kind, size, seed).

use std::f32::consts::TAU;
use std::fmt;
use std::str::FromStr;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use t2tf_core::image::Image;

#[derive(Debug, thiserror::Error)]
/// Why a background could not be made.
pub enum BackgroundError {
    #[error(
        "unknown background `{0}`: expected gray, gray:LEVEL (0..1), white, black, \
         checkerboard, noise, fourier or random"
    )]
    /// The name is not one of the known backgrounds.
    Name(String),
}

/// Background behind one rendered view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Background {
    /// Constant gray of this level in [0, 1].
    Gray {
        /// Gray level in [0, 1].
        level: f64,
    },
    /// Checkerboard with colours, size and phase from `seed`.
    Checkerboard {
        /// Seed of the colours, size and phase.
        seed: u64,
    },
    /// Noise image from `seed`.
    Noise {
        /// Seed of the noise.
        seed: u64,
    },
    /// Random Fourier features from `seed`.
    Fourier {
        /// Seed of the features.
        seed: u64,
    },
}

impl Background {
    /// The kind's name, as `--background` takes it.
    pub fn name(&self) -> &'static str {
        match self {
            Background::Gray { .. } => "gray",
            Background::Checkerboard { .. } => "checkerboard",
            Background::Noise { .. } => "noise",
            Background::Fourier { .. } => "fourier",
        }
    }

    /// Draw it at `width` × `height`: a pure function of the background and the size.
    pub fn draw(&self, width: usize, height: usize) -> Image {
        let rng = |seed: u64| ChaCha8Rng::seed_from_u64(seed);
        match *self {
            Background::Gray { level } => Image::filled(width, height, [level as f32; 3]),
            Background::Checkerboard { seed } => checkerboard(width, height, &mut rng(seed)),
            Background::Noise { seed } => noise(width, height, &mut rng(seed)),
            Background::Fourier { seed } => fourier(width, height, &mut rng(seed)),
        }
    }
}

/// What the user asks for behind the volume (`--background`): a kind, where the seed decides
/// the rest (see `BackgroundKind::resolve`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BackgroundKind {
    /// Constant gray; `None` draws the level uniformly in [0, 1] from the seed.
    Gray(Option<f32>),
    /// Two random colours in random-sized, randomly offset squares.
    Checkerboard,
    /// Random colour noise at a random scale (bilinear between random lattice colours).
    Noise,
    /// Random Fourier features: sines of random projections of pixel coordinates, mixed to RGB.
    Fourier,
    /// One of checkerboard / noise / Fourier, chosen uniformly from the seed (the paper's
    /// choice after its warm-up steps).
    Random,
}

impl FromStr for BackgroundKind {
    type Err = BackgroundError;
    fn from_str(s: &str) -> Result<Self, BackgroundError> {
        let t = s.trim().to_ascii_lowercase();
        let kind = match t.as_str() {
            "gray" | "grey" => BackgroundKind::Gray(None),
            "white" => BackgroundKind::Gray(Some(1.0)),
            "black" => BackgroundKind::Gray(Some(0.0)),
            "checkerboard" | "checker" => BackgroundKind::Checkerboard,
            "noise" => BackgroundKind::Noise,
            "fourier" | "rff" => BackgroundKind::Fourier,
            "random" => BackgroundKind::Random,
            _ => {
                let level = t
                    .strip_prefix("gray:")
                    .or_else(|| t.strip_prefix("grey:"))
                    .and_then(|v| v.parse::<f32>().ok())
                    .filter(|v| (0.0..=1.0).contains(v))
                    .ok_or_else(|| BackgroundError::Name(s.to_string()))?;
                BackgroundKind::Gray(Some(level))
            }
        };
        Ok(kind)
    }
}

impl fmt::Display for BackgroundKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BackgroundKind::Gray(None) => f.write_str("gray"),
            BackgroundKind::Gray(Some(v)) => write!(f, "gray:{v}"),
            BackgroundKind::Checkerboard => f.write_str("checkerboard"),
            BackgroundKind::Noise => f.write_str("noise"),
            BackgroundKind::Fourier => f.write_str("fourier"),
            BackgroundKind::Random => f.write_str("random"),
        }
    }
}

impl BackgroundKind {
    /// The concrete background `seed` picks for this kind.
    pub fn resolve(self, seed: u64) -> Background {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        match self {
            BackgroundKind::Gray(level) => Background::Gray {
                level: level.unwrap_or_else(|| rng.random::<f32>()) as f64,
            },
            BackgroundKind::Checkerboard => Background::Checkerboard { seed },
            BackgroundKind::Noise => Background::Noise { seed },
            BackgroundKind::Fourier => Background::Fourier { seed },
            BackgroundKind::Random => {
                let pick = [
                    BackgroundKind::Checkerboard,
                    BackgroundKind::Noise,
                    BackgroundKind::Fourier,
                ][rng.random_range(0..3)];
                pick.resolve(rng.random())
            }
        }
    }
}

/// Draw a `width` × `height` background of `kind` from `seed`.
pub(crate) fn generate(kind: BackgroundKind, width: usize, height: usize, seed: u64) -> Image {
    kind.resolve(seed).draw(width, height)
}

/// Parse a name and draw it (the CLI's `--background NAME`).
pub fn from_name(
    name: &str,
    width: usize,
    height: usize,
    seed: u64,
) -> Result<Image, BackgroundError> {
    Ok(generate(name.parse()?, width, height, seed))
}

fn random_rgb(rng: &mut ChaCha8Rng) -> [f32; 3] {
    [rng.random(), rng.random(), rng.random()]
}

/// Squares of side 1/16 to 1/4 of the image, two random colours, random offset.
fn checkerboard(width: usize, height: usize, rng: &mut ChaCha8Rng) -> Image {
    let size = width.max(height).max(1) as f32;
    let check = size * rng.random_range(1.0 / 16.0..=0.25);
    let (ox, oy) = (rng.random_range(0.0..check), rng.random_range(0.0..check));
    let (a, b) = (random_rgb(rng), random_rgb(rng));
    let mut im = Image::new(width, height);
    for y in 0..height {
        for x in 0..width {
            let cx = ((x as f32 + ox) / check).floor() as i64;
            let cy = ((y as f32 + oy) / check).floor() as i64;
            im.set_pixel(x, y, if (cx + cy) % 2 == 0 { a } else { b });
        }
    }
    im
}

/// Colours on a random lattice (cell 1 to 16 pixels) interpolated bilinearly: from pixel noise
/// to soft blobs.
fn noise(width: usize, height: usize, rng: &mut ChaCha8Rng) -> Image {
    let cell = rng.random_range(1.0f32..=16.0);
    let gw = (width as f32 / cell).ceil() as usize + 2;
    let gh = (height as f32 / cell).ceil() as usize + 2;
    let grid: Vec<[f32; 3]> = (0..gw * gh).map(|_| random_rgb(rng)).collect();
    let mut im = Image::new(width, height);
    for y in 0..height {
        let fy = y as f32 / cell;
        let (y0, wy) = (fy.floor() as usize, fy.fract());
        for x in 0..width {
            let fx = x as f32 / cell;
            let (x0, wx) = (fx.floor() as usize, fx.fract());
            let at = |i: usize, j: usize| grid[i + gw * j];
            let rgb = std::array::from_fn(|c| {
                let top = at(x0, y0)[c] * (1.0 - wx) + at(x0 + 1, y0)[c] * wx;
                let bot = at(x0, y0 + 1)[c] * (1.0 - wx) + at(x0 + 1, y0 + 1)[c] * wx;
                top * (1.0 - wy) + bot * wy
            });
            im.set_pixel(x, y, rgb);
        }
    }
    im
}

/// Number of random Fourier features mixed into each image.
const FOURIER_FEATURES: usize = 16;

/// A Fourier background's random draws: features (w_k, b_k), their RGB mix and the bias.
struct FourierDraws {
    feats: Vec<([f32; 2], f32)>,
    mix: Vec<[f32; 3]>,
    bias: [f32; 3],
}

impl FourierDraws {
    fn new(rng: &mut ChaCha8Rng) -> FourierDraws {
        let bandwidth = rng.random_range(1.0f32..=8.0);
        let gauss = |rng: &mut ChaCha8Rng| {
            // Box–Muller: one standard normal from two uniforms.
            let u1: f32 = rng.random_range(f32::EPSILON..1.0);
            let u2: f32 = rng.random();
            (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
        };
        let feats: Vec<([f32; 2], f32)> = (0..FOURIER_FEATURES)
            .map(|_| {
                let w = [gauss(rng) * bandwidth, gauss(rng) * bandwidth];
                (w, rng.random_range(0.0..TAU))
            })
            .collect();
        let gain = 2.0 / (FOURIER_FEATURES as f32).sqrt();
        let mix: Vec<[f32; 3]> = (0..FOURIER_FEATURES)
            .map(|_| std::array::from_fn(|_| gauss(rng) * gain))
            .collect();
        let bias: [f32; 3] = std::array::from_fn(|_| gauss(rng) * 0.5);
        FourierDraws { feats, mix, bias }
    }
}

/// Random Fourier features: f_k(p) = sin(2π w_k·p + b_k), p in [0, 1]² over the image, w_k
/// Gaussian with a random bandwidth (1 to 8 cycles across the image), b_k uniform phase; RGB is
/// a random linear mix of the features squashed to (0, 1) by a logistic, like a random one-layer
/// Fourier-feature network.
fn fourier(width: usize, height: usize, rng: &mut ChaCha8Rng) -> Image {
    let FourierDraws { feats, mix, bias } = FourierDraws::new(rng);
    let size = width.max(height).max(1) as f32;
    // sin(θx + θy) = sin θx cos θy + cos θx sin θy with θx = 2π w₀ px + b and θy = 2π w₁ py:
    // two sines per feature per column and per row instead of one per pixel and feature: a
    // background is drawn every optimizer step, inside its render phase.
    let axis = |n: usize, freq: f32, phase: f32| -> Vec<(f32, f32)> {
        (0..n)
            .map(|i| (TAU * freq * ((i as f32 + 0.5) / size) + phase).sin_cos())
            .collect()
    };
    let cols: Vec<Vec<(f32, f32)>> = feats.iter().map(|(w, b)| axis(width, w[0], *b)).collect();
    let rows: Vec<Vec<(f32, f32)>> = feats.iter().map(|(w, _)| axis(height, w[1], 0.0)).collect();
    let mut im = Image::new(width, height);
    for y in 0..height {
        for x in 0..width {
            let mut acc = bias;
            for ((col, row), m) in cols.iter().zip(&rows).zip(&mix) {
                let ((sx, cx), (sy, cy)) = (col[x], row[y]);
                let f = sx * cy + cx * sy;
                for c in 0..3 {
                    acc[c] += m[c] * f;
                }
            }
            im.set_pixel(x, y, acc.map(|a| 1.0 / (1.0 + (-a).exp())));
        }
    }
    im
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(im: &Image) -> (f32, f32, f32) {
        let n = im.data.len() as f32;
        let mean = im.data.iter().sum::<f32>() / n;
        let var = im.data.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / n;
        let (lo, hi) = im
            .data
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        (var, lo, hi)
    }

    #[test]
    fn fourier_features_match_a_sine_per_pixel() {
        // The direct formula, f_k(p) = sin(2π w_k·p + b_k) per pixel, from the same draws.
        for seed in 0..4 {
            let (w, h) = (61, 37);
            let fast = fourier(w, h, &mut ChaCha8Rng::seed_from_u64(seed));
            let FourierDraws { feats, mix, bias } =
                FourierDraws::new(&mut ChaCha8Rng::seed_from_u64(seed));
            let size = w.max(h) as f64;
            for y in 0..h {
                for x in 0..w {
                    let p = [(x as f64 + 0.5) / size, (y as f64 + 0.5) / size];
                    let mut acc = bias.map(f64::from);
                    for ((wk, b), m) in feats.iter().zip(&mix) {
                        let arg = std::f64::consts::TAU
                            * (f64::from(wk[0]) * p[0] + f64::from(wk[1]) * p[1])
                            + f64::from(*b);
                        for c in 0..3 {
                            acc[c] += f64::from(m[c]) * arg.sin();
                        }
                    }
                    let want = acc.map(|a| 1.0 / (1.0 + (-a).exp()));
                    let got = fast.pixel(x, y);
                    for c in 0..3 {
                        assert!(
                            (f64::from(got[c]) - want[c]).abs() < 1e-5,
                            "seed {seed} ({x}, {y}) channel {c}: {} against {}",
                            got[c],
                            want[c]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn every_kind_is_seeded_in_range_and_not_flat() {
        for name in ["checkerboard", "noise", "fourier", "random"] {
            let kind: BackgroundKind = name.parse().unwrap();
            let a = generate(kind, 57, 33, 5);
            assert_eq!((a.width, a.height), (57, 33));
            assert_eq!(a, generate(kind, 57, 33, 5), "{name} is not deterministic");
            assert_ne!(a, generate(kind, 57, 33, 6), "{name} ignores the seed");
            let (var, lo, hi) = stats(&a);
            assert!(lo >= 0.0 && hi <= 1.0, "{name}: [{lo}, {hi}]");
            assert!(var > 1e-4, "{name} is flat (var {var})");
        }
    }

    #[test]
    fn gray_levels_and_names() {
        let g = from_name("gray:0.25", 4, 3, 0).unwrap();
        assert!(g.data.iter().all(|&v| v == 0.25));
        let r = from_name("gray", 4, 3, 9).unwrap();
        assert!(r.data.iter().all(|&v| v == r.data[0]) && (0.0..1.0).contains(&r.data[0]));
        assert!(from_name("white", 2, 2, 0)
            .unwrap()
            .data
            .iter()
            .all(|&v| v == 1.0));
        for bad in ["plaid", "gray:2", "gray:x"] {
            let e = from_name(bad, 2, 2, 0).unwrap_err();
            assert!(e.to_string().contains(bad), "{e}");
        }
        assert_eq!(
            "gray:0.5".parse::<BackgroundKind>().unwrap().to_string(),
            "gray:0.5"
        );
    }

    #[test]
    fn checkerboard_has_two_colours_and_tiny_sizes_work() {
        let im = generate(BackgroundKind::Checkerboard, 64, 64, 1);
        let mut colours: Vec<[u8; 3]> = im
            .to_rgb8()
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        colours.sort();
        colours.dedup();
        assert_eq!(colours.len(), 2);
        for kind in ["checkerboard", "noise", "fourier"] {
            let im = from_name(kind, 1, 1, 3).unwrap();
            assert!(im.data.iter().all(|v| v.is_finite()));
        }
    }
}
