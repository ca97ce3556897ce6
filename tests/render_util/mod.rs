//! Helpers shared by the renderer's integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use t2tf::camera::{Camera, Orbit, UpAxis};
use t2tf::image::Image;
use t2tf::render::{self, RenderOptions};
use t2tf::tf::Lut;
use t2tf::volume::{ByteOrder, Geometry, ScalarType, TypedBuffer, Volume};

/// `../shared/data/volumes/NAME` relative to the repository root.
pub fn shared_volume(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/volumes")
        .join(name)
}

/// Read a uint8 `.raw` volume (x fastest) with unit spacing.
pub fn load_u8(name: &str, dims: [usize; 3]) -> Volume {
    let path = shared_volume(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let g = Geometry {
        dims,
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    Volume::from_buffer(
        &path,
        g,
        &TypedBuffer::new(ScalarType::U8, ByteOrder::Little, bytes),
    )
    .expect("valid volume")
}

/// The values of a sub-box of a uint8 raw volume, x fastest.
fn crop_bytes(name: &str, dims: [usize; 3], lo: [usize; 3], size: [usize; 3]) -> Vec<u8> {
    let path = shared_volume(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut vals = Vec::with_capacity(size.iter().product());
    for k in 0..size[2] {
        for j in 0..size[1] {
            for i in 0..size[0] {
                let (x, y, z) = (lo[0] + i, lo[1] + j, lo[2] + k);
                vals.push(bytes[x + dims[0] * (y + dims[1] * z)]);
            }
        }
    }
    vals
}

/// A sub-box of a uint8 raw volume as a new (float) volume.
pub fn crop_u8(name: &str, dims: [usize; 3], lo: [usize; 3], size: [usize; 3]) -> Volume {
    let vals = crop_bytes(name, dims, lo, size);
    volume_from(size, [1.0; 3], vals.into_iter().map(f64::from).collect())
}

/// The same sub-box, kept as uint8 (so the renderer stores it in 8 bits, render::cpu::bricked).
pub fn crop_u8_typed(name: &str, dims: [usize; 3], lo: [usize; 3], size: [usize; 3]) -> Volume {
    let g = Geometry {
        dims: size,
        spacing: [1.0; 3],
        origin: [-3.0, 1.0, 2.0],
    };
    let buffer = TypedBuffer::new(
        ScalarType::U8,
        ByteOrder::Little,
        crop_bytes(name, dims, lo, size),
    );
    Volume::from_buffer(Path::new("crop"), g, &buffer).unwrap()
}

pub fn volume_from(dims: [usize; 3], spacing: [f64; 3], vals: Vec<f64>) -> Volume {
    let g = Geometry {
        dims,
        spacing,
        origin: [-3.0, 1.0, 2.0],
    };
    Volume::from_buffer(Path::new("synthetic"), g, &TypedBuffer::from_f64(vals)).unwrap()
}

/// A smooth blob plus a ramp on an anisotropic grid: every value in (0, 1) occurs.
pub fn blob(dims: [usize; 3]) -> Volume {
    let mut vals = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = [i, j, k].map(|v| v as f64);
                let c: [f64; 3] = std::array::from_fn(|a| 0.5 * (dims[a] - 1) as f64);
                let r2: f64 = (0..3)
                    .map(|a| ((p[a] - c[a]) / (0.35 * dims[a] as f64)).powi(2))
                    .sum();
                vals.push((-r2).exp() + 0.15 * p[0] / dims[0] as f64);
            }
        }
    }
    volume_from(dims, [1.0, 0.8, 1.3], vals)
}

/// A LUT with σ in [lo, hi] and colours in [0.1, 0.9], from a seed.
pub fn random_lut(n: usize, lo: f32, hi: f32, seed: u64) -> Lut {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    Lut {
        entries: (0..n)
            .map(|_| {
                [
                    rng.random_range(lo..=hi),
                    rng.random_range(0.1..0.9),
                    rng.random_range(0.1..0.9),
                    rng.random_range(0.1..0.9),
                ]
            })
            .collect(),
    }
}

pub fn orbit(v: &Volume, yaw: f64, pitch: f64, distance: f64) -> Camera {
    Camera::orbit(
        &v.geometry,
        Orbit {
            yaw,
            pitch,
            distance,
            up: UpAxis::Z,
        },
    )
    .unwrap()
}

/// Random loss weights: L = Σ w·I + Σ u·T_N.
pub fn weights(w: usize, h: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let wi = (0..w * h * 3)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let wt = (0..w * h).map(|_| rng.random_range(-1.0..1.0)).collect();
    (wi, wt)
}

/// The loss in f64 from one forward.
pub fn loss(
    v: &Volume,
    lut: &Lut,
    cam: &Camera,
    bg: &Image,
    opts: &RenderOptions,
    wi: &[f32],
    wt: &[f32],
) -> f64 {
    let r = render::forward(v, lut, cam, bg, opts).unwrap();
    let a: f64 = r
        .image
        .data
        .iter()
        .zip(wi)
        .map(|(&x, &w)| x as f64 * w as f64)
        .sum();
    let b: f64 = r
        .transmittance
        .iter()
        .zip(wt)
        .map(|(&x, &w)| x as f64 * w as f64)
        .sum();
    a + b
}

pub fn all_finite(r: &render::Rendered) -> bool {
    r.image
        .data
        .iter()
        .chain(&r.transmittance)
        .all(|v| v.is_finite())
}

/// The library's PSNR (200 dB for equal images), under the name the render tests import.
pub use t2tf::image::psnr;
