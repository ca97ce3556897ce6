//! Which level and step a picture for people needs: `t2tf render`'s defaults and
//! the optimizer's preview.png. Not a timed test: prints a Markdown table.
//!
//! ```text
//! cargo run --release --features bench --example bench_render_defaults [-- --size N]
//! ```
//!
//! Every shared volume (`../shared/data/volumes/`) plus a wide-range 16-bit CT made here
//! ("headsq-wide": headsq scaled into 0..16383 with eight voxels at 65535, so the tissue fills
//! the first quarter of the range, as a CT with metal or padding outliers does). TF: a ramp
//! preset in ParaView terms (opacity 0 → 0.6 per unit distance, the mean spacing, linear in
//! opacity, blue → white) from the 50th to the 99.5th percentile of the non-background values,
//! so every volume shows structure; and a narrow "peak" (a tent over the ramp's 30 %–50 %,
//! opacity 0.98 at its top), which is what the optimizer's dense TFs look like to the sampler
//! (σ up to 255 per box length: α ≈ 0.98 per voxel on a 64³ volume). Two views (the CLI's default yaw 30° pitch 10° distance
//! 2.5, and yaw 120° pitch −20°) at `--size` (default 256) over the CLI's gray:0.3.
//!
//! "PSNR" is against the converged render: level 0, step 1/8 voxel, no early termination.

use std::path::Path;
use std::time::Instant;

use t2tf::camera::{Camera, Orbit, UpAxis};
use t2tf::image::Image;
use t2tf::render::{self, RenderOptions};
use t2tf::tf::{default_unit_distance, opacity_to_sigma, ControlPoints, Lut};
use t2tf::volume::{ByteOrder, ScalarType, TypedBuffer, Volume};

#[path = "common/shared_volumes.rs"]
mod shared_volumes;
use shared_volumes::{SharedVolume, SHARED_VOLUMES};

struct Case {
    name: String,
    volume: Volume,
    /// Raw values (data units) for the percentiles.
    values: Vec<f64>,
}

/// A shared volume, named "aneurism (u8)", with its raw values.
fn load(shared: &SharedVolume) -> anyhow::Result<Case> {
    let bytes = std::fs::read(shared.path())?;
    let u16 = shared.scalar == ScalarType::U16;
    let values: Vec<f64> = if u16 {
        bytes
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]) as f64)
            .collect()
    } else {
        bytes.iter().map(|&b| b as f64).collect()
    };
    Ok(Case {
        name: format!("{} ({})", shared.name(), if u16 { "u16" } else { "u8" }),
        volume: shared.volume(bytes)?,
        values,
    })
}

/// headsq scaled into 0..16383 with eight outliers at 65535.
fn wide(headsq: &Case) -> anyhow::Result<Case> {
    let max = headsq.values.iter().copied().fold(0.0, f64::max);
    let mut values: Vec<f64> = headsq
        .values
        .iter()
        .map(|v| (v * 16383.0 / max).round())
        .collect();
    let n = values.len();
    for k in 0..8 {
        values[(k * 7919 + 13) % n] = 65535.0;
    }
    let bytes: Vec<u8> = values
        .iter()
        .flat_map(|&v| (v as u16).to_le_bytes())
        .collect();
    let volume = Volume::from_buffer(
        Path::new("headsq-wide.raw"),
        headsq.volume.geometry,
        &TypedBuffer::new(ScalarType::U16, ByteOrder::Little, bytes),
    )?;
    Ok(Case {
        name: "headsq-wide (u16)".to_string(),
        volume,
        values,
    })
}

/// A TF of the module docs, as `t2tf render` would read it from a preset: `peak` false is the
/// ramp, true the narrow peak.
pub fn tf(volume: &Volume, values: &[f64], peak: bool) -> ControlPoints {
    let min = values.iter().copied().fold(f64::INFINITY, f64::min);
    let mut v: Vec<f64> = values.iter().copied().filter(|&x| x > min).collect();
    v.sort_by(f64::total_cmp);
    let pct = |p: f64| v[((v.len() - 1) as f64 * p) as usize];
    let [lo, hi] = volume.norm_range;
    let norm = |x: f64| ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    let (a, b) = (norm(pct(0.5)), norm(pct(0.995)));
    let (a, b) = if peak {
        (a + 0.3 * (b - a), a + 0.5 * (b - a))
    } else {
        (a, b)
    };
    let ratio = default_unit_distance(&volume.geometry) / volume.geometry.longest_side();
    // Dense points so σ-linear interpolation follows the opacity-linear ramp.
    let mut x = vec![0.0];
    x.extend((0..=32).map(|i| a + (b - a) * i as f64 / 32.0));
    x.push(1.0);
    x.dedup();
    let t = |x: f64| ((x - a) / (b - a)).clamp(0.0, 1.0);
    let o = |x: f64| {
        if peak {
            0.98 * (1.0 - (2.0 * t(x) - 1.0).abs())
        } else {
            0.6 * t(x)
        }
    };
    ControlPoints {
        sigma: x
            .iter()
            .map(|&x| opacity_to_sigma(o(x), ratio, 1.0))
            .collect(),
        rgb: x
            .iter()
            .map(|&x| {
                let t = t(x);
                [0.2 + 0.8 * t, 0.4 + 0.6 * t, 1.0]
            })
            .collect(),
        x,
    }
}

pub fn cameras(volume: &Volume) -> anyhow::Result<Vec<Camera>> {
    [(30.0f64, 10.0f64), (120.0, -20.0)]
        .iter()
        .map(|&(yaw, pitch)| {
            Ok(Camera::orbit(
                &volume.geometry,
                Orbit {
                    yaw: yaw.to_radians(),
                    pitch: pitch.to_radians(),
                    distance: 2.5,
                    up: UpAxis::Z,
                },
            )?)
        })
        .collect()
}

/// PSNR (dB) of the views pooled: `t2tf::image::psnr` of the views side by side.
fn psnr(a: &[Image], b: &[Image]) -> f64 {
    t2tf::image::psnr(&Image::grid(a, a.len()), &Image::grid(b, b.len()))
}

fn render_all(
    volume: &Volume,
    lut: &Lut,
    cams: &[Camera],
    bg: &Image,
    opts: &RenderOptions,
) -> anyhow::Result<(Vec<Image>, usize, f64)> {
    let t0 = Instant::now();
    let mut images = Vec::new();
    let mut level = 0;
    for c in cams {
        let r = render::forward(volume, lut, c, bg, opts)?;
        level = r.level;
        images.push(r.image);
    }
    Ok((images, level, t0.elapsed().as_secs_f64()))
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let size: usize = args
        .iter()
        .position(|a| a == "--size")
        .and_then(|i| args.get(i + 1))
        .map_or(Ok(256), |s| s.parse())?;
    let mut cases = SHARED_VOLUMES
        .iter()
        .map(load)
        .collect::<anyhow::Result<Vec<_>>>()?;
    let w = wide(&cases[2])?;
    cases.push(w);

    let bg = t2tf::background::from_name("gray:0.3", size, size, 0)?;
    let reference = RenderOptions {
        step: 0.125,
        level: Some(0),
        early_termination: 0.0,
        ..RenderOptions::default()
    };
    // (label, level, step)
    let candidates: [(&str, Option<usize>, f32); 7] = [
        ("auto", None, 1.0),
        ("auto", None, 0.75),
        ("auto", None, 0.5),
        ("auto", None, 0.375),
        ("auto", None, 0.25),
        ("0", Some(0), 0.25),
        ("1", Some(1), 0.5),
    ];
    println!("{size}×{size} px, 2 views; PSNR against level 0, step 1/8, no early termination\n");
    println!("| volume | TF | level | step (voxels) | seconds (2 views) | PSNR (dB) |");
    println!("|---|---|---|---|---|---|");
    for (case, peak) in cases.iter().flat_map(|c| [(c, false), (c, true)]) {
        let tf_name = if peak { "peak" } else { "ramp" };
        let cp = tf(&case.volume, &case.values, peak);
        let lut = cp.to_lut(1024);
        let cams = cameras(&case.volume)?;
        let (refs, _, tref) = render_all(&case.volume, &lut, &cams, &bg, &reference)?;
        println!(
            "| {} | {tf_name} | 0 (reference) | 0.125 | {tref:.2} | — |",
            case.name
        );
        for &(label, level, step) in &candidates {
            if level.is_some_and(|l| l >= case.volume.levels.len()) {
                continue;
            }
            let opts = RenderOptions {
                step,
                level,
                ..RenderOptions::default()
            };
            let (imgs, used, t) = render_all(&case.volume, &lut, &cams, &bg, &opts)?;
            println!(
                "| {} | {tf_name} | {label} → {used} | {step} | {t:.2} | {:.1} |",
                case.name,
                psnr(&imgs, &refs)
            );
        }
    }
    Ok(())
}
