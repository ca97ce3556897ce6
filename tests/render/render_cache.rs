//! Rendering through the LRU brick cache (render::cpu::cache): the images and gradients of a
//! level rendered from a small cache equal those of its whole in-memory copy, bit for bit.

use std::path::Path;

use crate::render_util;

use render_util::*;
use t2tf::background;
use t2tf::camera::Camera;
use t2tf::image::Image;
use t2tf::render::cpu::CpuPrepared;
use t2tf::render::{Backend, CpuBackend, RenderError, RenderOptions, Shot};
use t2tf::tf::Lut;
use t2tf::volume::{ByteOrder, Geometry, ScalarType, TypedBuffer, Volume};

/// A uint16 `.raw` volume from ../shared (x fastest, little-endian), unit spacing.
fn load_u16(name: &str, dims: [usize; 3]) -> Volume {
    let path = shared_volume(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let g = Geometry {
        dims,
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    let buffer = TypedBuffer::new(ScalarType::U16, ByteOrder::Little, bytes);
    Volume::from_buffer(&path, g, &buffer).unwrap()
}

/// A float volume with a one-point x axis and a few NaN (empty) points.
fn one_point_axis() -> Volume {
    let dims = [1, 45, 38];
    let vals = (0..45 * 38)
        .map(|i| {
            let (y, z) = ((i % 45) as f64, (i / 45) as f64);
            if i % 97 == 5 {
                f64::NAN
            } else {
                ((y * 0.21).sin() * (z * 0.17).cos()).abs() + 0.05 * z
            }
        })
        .collect();
    let g = Geometry {
        dims,
        spacing: [1.0, 0.9, 1.1],
        origin: [0.0; 3],
    };
    Volume::from_buffer(Path::new("one-point"), g, &TypedBuffer::from_f64(vals)).unwrap()
}

/// Views from several sides: along an axis, oblique ones, from below.
fn cameras(v: &Volume) -> Vec<Camera> {
    [(0.0, 0.0), (37.0, 21.0), (200.0, -50.0), (123.0, 64.0)]
        .iter()
        .map(|&(yaw, pitch): &(f64, f64)| orbit(v, yaw.to_radians(), pitch.to_radians(), 2.2))
        .collect()
}

/// Option sets: defaults, a final picture's step, and no skipping with jitter and no early
/// termination (every sample visited).
fn option_sets() -> [RenderOptions; 3] {
    [
        RenderOptions::default(),
        RenderOptions {
            step: 0.375,
            ..RenderOptions::default()
        },
        RenderOptions {
            skip_empty: false,
            early_termination: 0.0,
            jitter_seed: Some(11),
            ..RenderOptions::default()
        },
    ]
}

/// One render's bits: image, transmittance, sample count and LUT gradient.
type Bits = (Vec<u32>, Vec<u32>, u64, Vec<u64>);

/// Forward and backward of every view and option set, through `prepared`.
fn render_all(
    prepared: &CpuPrepared,
    lut: &Lut,
    cams: &[Camera],
    bg: &Image,
) -> Result<Vec<Bits>, RenderError> {
    let (wi, wt) = weights(bg.width, bg.height, 3);
    let mut out = Vec::new();
    for cam in cams {
        for opts in &option_sets() {
            let shot = Shot {
                camera: cam,
                background: bg,
                options: opts,
                cast: (bg.width, bg.height),
            };
            let (r, tape) = CpuBackend::default().forward(prepared, lut, &shot)?;
            let g = CpuBackend::default().backward(prepared, lut, &shot, &tape, &wi, &wt)?;
            out.push((
                r.image.data.iter().map(|x| x.to_bits()).collect(),
                r.transmittance.iter().map(|x| x.to_bits()).collect(),
                r.samples,
                g.entries.iter().flatten().map(|x| x.to_bits()).collect(),
            ));
        }
    }
    Ok(out)
}

/// The smallest cache (grown by 1.25× from `start` bytes) that renders every view; its
/// budget and results.
fn smallest_cache(
    v: &Volume,
    lut: &Lut,
    cams: &[Camera],
    bg: &Image,
    start: u64,
) -> (u64, CpuPrepared, Vec<Bits>) {
    let mut budget = start;
    for _ in 0..60 {
        let prepared = match CpuBackend::default().prepare_within(v, 0, budget) {
            Ok(p) => p,
            Err(RenderError::BrickBudget { .. }) => {
                budget += budget / 4;
                continue;
            }
            Err(e) => panic!("{e}"),
        };
        assert!(
            prepared.cache_stats().is_some(),
            "{budget} bytes hold the whole level"
        );
        match render_all(&prepared, lut, cams, bg) {
            Ok(r) => return (budget, prepared, r),
            Err(RenderError::BrickBudget { .. }) => budget += budget / 4,
            Err(e) => panic!("{e}"),
        }
    }
    panic!("no cache below {budget} bytes renders the views")
}

/// Through a cache small enough to evict bricks during every view, forward images,
/// transmittance, sample counts and LUT gradients equal the whole copy's, bit for bit: on
/// 8- and 16-bit shared volumes, a float volume with NaN and a volume with a one-point axis.
#[test]
fn cache_renders_equal_whole_renders_bit_for_bit() {
    let volumes = [
        ("neghip u8", load_u8("neghip_64x64x64_uint8.raw", [64; 3])),
        (
            "walnut u16",
            load_u16("walnut_128x96x114_uint16.raw", [128, 96, 114]),
        ),
        ("blob f32", blob([37, 29, 21])),
        ("one-point axis", one_point_axis()),
    ];
    let lut = random_lut(64, 0.0, 40.0, 7);
    let bg = background::from_name("fourier", 56, 40, 1).unwrap();
    for (name, v) in &volumes {
        let cams = cameras(v);
        let whole = CpuBackend::default().prepare(v, 0).unwrap();
        assert!(whole.cache_stats().is_none());
        let expected = render_all(&whole, &lut, &cams, &bg).unwrap();
        let (budget, cached, got) = smallest_cache(v, &lut, &cams, &bg, 4096);
        let stats = cached.cache_stats().unwrap();
        assert!(
            budget < whole.memory_bytes() as u64,
            "{name}: the cache ({budget} B) must be smaller than the whole copy"
        );
        // Held bytes (arena and tables) within the budget.
        assert!(
            stats.bytes <= budget,
            "{name}: {stats:?} over {budget} bytes"
        );
        assert_eq!(cached.memory_bytes() as u64, stats.bytes);
        assert!(stats.evictions > 0, "{name}: nothing evicted ({stats:?})");
        assert_eq!(got.len(), expected.len());
        for (i, (a, b)) in got.iter().zip(&expected).enumerate() {
            assert_eq!(a.0, b.0, "{name}: image of render {i}");
            assert_eq!(a.1, b.1, "{name}: transmittance of render {i}");
            assert_eq!(a.2, b.2, "{name}: samples of render {i}");
            assert_eq!(a.3, b.3, "{name}: gradient of render {i}");
        }
        // The stored kind follows the level's (8 bits for neghip, 16 for the walnut).
        assert_eq!(
            std::mem::discriminant(&cached.values()),
            std::mem::discriminant(&whole.values()),
            "{name}"
        );
    }
}

/// A budget below one tile's bricks is an error that says what to do; one that holds the
/// whole copy gives the whole copy.
#[test]
fn cache_budget_errors_and_whole_copies() {
    let v = load_u8("neghip_64x64x64_uint8.raw", [64; 3]);
    let lut = random_lut(16, 1.0, 30.0, 2);
    let bg = Image::new(64, 64);
    let cams = cameras(&v);
    match CpuBackend::default().prepare_within(&v, 0, 100) {
        Err(e @ RenderError::BrickBudget { .. }) => {
            assert!(e.to_string().contains("memory `budget`"), "{e}")
        }
        other => panic!("expected a budget error, got {other:?}"),
    }
    let tiny = CpuBackend::default().prepare_within(&v, 0, 20_000).unwrap();
    match render_all(&tiny, &lut, &cams, &bg) {
        Err(e @ RenderError::BrickBudget { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains("tile") && msg.contains("coarser `level`"),
                "{msg}"
            )
        }
        other => panic!("expected a budget error, got {:?}", other.map(|r| r.len())),
    }
    let whole = CpuBackend::default().prepare(&v, 0).unwrap();
    // Room for the copy and the f32 slabs it is built from (one per thread).
    let roomy = CpuBackend::default()
        .prepare_within(&v, 0, 2 * whole.memory_bytes() as u64)
        .unwrap();
    assert!(roomy.cache_stats().is_none());
    assert_eq!(
        render_all(&roomy, &lut, &cams, &bg).unwrap(),
        render_all(&whole, &lut, &cams, &bg).unwrap()
    );
}

/// A volume loaded lazily from its file (level 0 memory-mapped, not materialized): its whole
/// copy and its brick cache are both read in place, level 0 stays unmaterialized, and the
/// renders equal those of the volume built in memory, bit for bit.
#[test]
fn lazy_level_0_is_bricked_and_cached_from_its_file() {
    let name = "walnut_128x96x114_uint16.raw";
    let loaded = t2tf::volume::load(&shared_volume(name), &Default::default()).unwrap();
    assert!(!loaded.levels[0].is_materialized());
    let built = load_u16(name, [128, 96, 114]);
    assert_eq!(loaded.geometry, built.geometry);
    let lut = random_lut(32, 0.0, 25.0, 5);
    let bg = Image::new(48, 48);
    let cams = cameras(&built);
    let expected = render_all(
        &CpuBackend::default().prepare(&built, 0).unwrap(),
        &lut,
        &cams,
        &bg,
    )
    .unwrap();
    let whole = CpuBackend::default().prepare(&loaded, 0).unwrap();
    assert!(whole.cache_stats().is_none());
    assert!(render_all(&whole, &lut, &cams, &bg).unwrap() == expected);
    let (_, cached, got) = smallest_cache(&loaded, &lut, &cams, &bg, 200_000);
    assert!(cached.cache_stats().unwrap().evictions > 0);
    assert!(got == expected, "cached renders differ");
    assert!(
        !loaded.levels[0].is_materialized(),
        "rendering made level 0's f32 samples"
    );
}
