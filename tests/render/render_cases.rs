//! Renderer hard cases, equivalences and behaviour on real data.

use crate::render_util;

use render_util::*;
use t2tf::background;
use t2tf::camera::{Camera, UpAxis};
use t2tf::image::Image;
use t2tf::render::cpu::BrickValues;
use t2tf::render::{self, Backend, CpuBackend, RenderOptions};
use t2tf::tf::Lut;
use t2tf::volume::Volume;

fn flat_lut(n: usize, sigma: f32, rgb: [f32; 3]) -> Lut {
    Lut {
        entries: vec![[sigma, rgb[0], rgb[1], rgb[2]]; n],
    }
}

/// Forward and backward with every option combination; all outputs finite.
fn assert_finite_everywhere(v: &Volume, lut: &Lut, cam: &Camera, what: &str) -> render::Rendered {
    let bg = background::from_name("fourier", 16, 12, 1).unwrap();
    let (wi, wt) = weights(16, 12, 2);
    let mut first = None;
    for (skip, stop, jitter) in [
        (true, 1e-3, None),
        (false, 0.0, Some(4)),
        (true, 0.0, Some(5)),
    ] {
        let opts = RenderOptions {
            skip_empty: skip,
            early_termination: stop,
            jitter_seed: jitter,
            ..RenderOptions::default()
        };
        let r = render::forward(v, lut, cam, &bg, &opts).unwrap();
        assert!(all_finite(&r), "{what}: non-finite image");
        let g = render::backward(v, lut, cam, &bg, &opts, &wi, &wt).unwrap();
        assert!(
            g.entries.iter().flatten().all(|x| x.is_finite()),
            "{what}: non-finite gradient"
        );
        first.get_or_insert(r);
    }
    first.unwrap()
}

/// A uint8 volume is rendered from its 8-bit copy (render::cpu::bricked), a float one from f32:
/// the same values give the same images and gradients, to f32 rounding.
#[test]
fn narrow_storage_renders_like_f32() {
    let narrow = crop_u8_typed("neghip_64x64x64_uint8.raw", [64; 3], [0; 3], [64; 3]);
    let wide = crop_u8("neghip_64x64x64_uint8.raw", [64; 3], [0; 3], [64; 3]);
    assert!(matches!(
        CpuBackend::default().prepare(&narrow, 0).unwrap().values(),
        BrickValues::U8(_)
    ));
    assert!(matches!(
        CpuBackend::default().prepare(&wide, 0).unwrap().values(),
        BrickValues::F32(_)
    ));
    let lut = random_lut(64, 0.0, 80.0, 3);
    let bg = background::from_name("checkerboard", 48, 40, 2).unwrap();
    let (wi, wt) = weights(48, 40, 5);
    for (k, jitter) in [(0, None), (1, Some(9))] {
        let cam = orbit(&narrow, 0.7 + k as f64, 0.2, 2.5);
        let opts = RenderOptions {
            jitter_seed: jitter,
            ..RenderOptions::default()
        };
        let a = render::forward(&narrow, &lut, &cam, &bg, &opts).unwrap();
        let b = render::forward(&wide, &lut, &cam, &bg, &opts).unwrap();
        let diff = a
            .image
            .data
            .iter()
            .zip(&b.image.data)
            .map(|(x, y)| (x - y).abs());
        assert!(diff.fold(0.0f32, f32::max) < 1e-5, "images differ");
        let ga = render::backward_from(&narrow, &lut, &cam, &a, &opts, &wi, &wt).unwrap();
        let gb = render::backward_from(&wide, &lut, &cam, &b, &opts, &wi, &wt).unwrap();
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (x, y) in ga.entries.iter().flatten().zip(gb.entries.iter().flatten()) {
            num += (x - y).powi(2);
            den += y * y;
        }
        assert!(
            den > 0.0 && (num / den).sqrt() < 1e-4,
            "gradients differ: {}",
            (num / den).sqrt()
        );
    }
}

#[test]
fn saturated_density_underflows_t_without_nan() {
    let v = blob([12, 12, 12]);
    let cam = orbit(&v, 0.3, 0.1, 2.0);
    let r = assert_finite_everywhere(&v, &flat_lut(8, 255.0, [0.8, 0.2, 0.1]), &cam, "σ=255");
    // Opaque rays show the TF colour, not the background.
    let centre = r.image.pixel(8, 6);
    assert!(
        (centre[0] - 0.8).abs() < 2e-3 && (centre[2] - 0.1).abs() < 2e-3,
        "{centre:?}"
    );
    assert!(r.transmittance[6 * 16 + 8] < 1e-3);
}

#[test]
fn constant_volume() {
    let v = volume_from([6, 7, 8], [1.0; 3], vec![3.5; 6 * 7 * 8]);
    let cam = orbit(&v, 1.0, 0.0, 2.5);
    let r = assert_finite_everywhere(&v, &random_lut(16, 0.0, 50.0, 1), &cam, "constant");
    assert!(r.transmittance.iter().any(|&t| t < 1.0));
}

#[test]
fn nan_voxels_are_empty() {
    // The +x half is NaN: a σ=255 TF still lets rays through there.
    let dims = [10, 10, 10];
    let vals = (0..1000)
        .map(|i| if i % 10 >= 5 { f64::NAN } else { 0.5 })
        .collect();
    let v = volume_from(dims, [1.0; 3], vals);
    // From +y, looking down -y with z up: +x is on screen left (right = forward × up = -x).
    let cam = orbit(&v, std::f64::consts::FRAC_PI_2, 0.0, 2.0);
    let r = assert_finite_everywhere(&v, &flat_lut(4, 255.0, [1.0; 3]), &cam, "NaN");
    let (left, right) = (r.transmittance[6 * 16 + 6], r.transmittance[6 * 16 + 10]);
    assert!(left == 1.0 && right < 1e-3, "left {left} right {right}");
}

#[test]
fn one_and_two_voxel_thick_volumes() {
    // One point thick: a slab one spacing thick around the points (render::cpu::march's BoxFrame),
    // so a 9 × 9 × 1 image shows, much as the same slice doubled into a two-point-thick volume
    // (whose box is also one spacing thick; only the bounding radius, and so the camera
    // distance, differs by 0.4 %).
    let slice: Vec<f64> = (0..81).map(|i| i as f64).collect();
    let thin = volume_from([9, 9, 1], [1.0; 3], slice.clone());
    let cam = orbit(&thin, 0.4, 0.5, 2.0);
    let lut = random_lut(8, 10.0, 200.0, 3);
    let r = assert_finite_everywhere(&thin, &lut, &cam, "1-thick");
    assert!(
        r.transmittance.iter().any(|&t| t < 0.9),
        "the slab is not seen"
    );
    let doubled = volume_from([9, 9, 2], [1.0; 3], [slice.clone(), slice].concat());
    let r2 = assert_finite_everywhere(&doubled, &lut, &orbit(&doubled, 0.4, 0.5, 2.0), "2-thick");
    let p = psnr(&r.image, &r2.image);
    assert!(p > 25.0, "one-point slab vs doubled slice: {p:.1} dB");
    let two = volume_from([9, 9, 2], [1.0; 3], (0..162).map(|i| i as f64).collect());
    let r = assert_finite_everywhere(&two, &lut, &cam, "2-thick");
    assert!(r.transmittance.iter().any(|&t| t < 1.0));
}

#[test]
fn camera_inside_the_box() {
    let v = blob([12, 12, 12]);
    let c = glam::DVec3::from_array(v.geometry.center());
    let cam = Camera {
        position: c + glam::DVec3::new(1.0, 0.5, 0.2),
        focal_point: c,
        view_up: glam::DVec3::Z,
        view_angle_deg: 45.0,
    };
    let r = assert_finite_everywhere(&v, &random_lut(8, 5.0, 40.0, 4), &cam, "inside");
    // Every ray starts inside, so every ray is attenuated.
    assert!(r.transmittance.iter().all(|&t| t < 1.0));
}

#[test]
fn all_zero_tf_shows_the_background() {
    let v = blob([12, 12, 12]);
    let cam = orbit(&v, 0.0, 0.0, 2.0);
    let bg = background::from_name("checkerboard", 16, 12, 9).unwrap();
    let lut = flat_lut(8, 0.0, [0.5; 3]);
    for skip in [true, false] {
        let opts = RenderOptions {
            skip_empty: skip,
            ..RenderOptions::default()
        };
        let r = render::forward(&v, &lut, &cam, &bg, &opts).unwrap();
        assert_eq!(r.image, bg);
        assert!(r.transmittance.iter().all(|&t| t == 1.0));
        if skip {
            // Every brick is empty: not one sample is taken.
            assert_eq!(r.samples, 0);
        }
    }
    let (wi, wt) = weights(16, 12, 1);
    let opts = RenderOptions {
        skip_empty: false,
        ..RenderOptions::default()
    };
    // Without skipping, σ = 0 still has a gradient (adding density would darken the image).
    let g = render::backward(&v, &lut, &cam, &bg, &opts, &wi, &wt).unwrap();
    assert!(g.entries.iter().any(|e| e[0] != 0.0));
    assert!(g.entries.iter().all(|e| e[1..] == [0.0; 3]));
}

/// neghip with a TF that is zero below 0.25 (the background of the field).
fn neghip_setup() -> (Volume, Lut) {
    let v = load_u8("neghip_64x64x64_uint8.raw", [64; 3]);
    let lut = Lut {
        entries: (0..256)
            .map(|j| {
                let x = j as f32 / 255.0;
                let s = if x < 0.25 {
                    0.0
                } else {
                    60.0 * (x - 0.25) / 0.75
                };
                [s, x, 1.0 - x, 0.5]
            })
            .collect(),
    };
    (v, lut)
}

#[test]
fn real_volume_is_visible_in_its_projected_box() {
    let (v, lut) = neghip_setup();
    let cam = orbit(&v, 0.6, 0.2, 2.0);
    let bg = Image::filled(64, 64, [0.0; 3]);
    let r = render::forward(&v, &lut, &cam, &bg, &RenderOptions::default()).unwrap();
    // The centre of the image shows the molecule's lobes; the corners (outside the box's
    // projection at this distance) show the black background.
    let lit = |x0: usize, y0: usize| {
        (0..8)
            .flat_map(|dy| (0..8).map(move |dx| (x0 + dx, y0 + dy)))
            .filter(|&(x, y)| r.image.pixel(x, y).iter().sum::<f32>() > 0.05)
            .count()
    };
    assert!(lit(28, 28) > 16, "centre is dark");
    for (x, y) in [(0, 0), (56, 0), (0, 56), (56, 56)] {
        assert_eq!(lit(x, y), 0, "corner ({x}, {y}) is lit");
    }
}

#[test]
fn orientation_up_is_up_and_right_is_right() {
    // A small dense block near the +z, +y corner of the box.
    let dims = [16, 16, 16];
    let vals = (0..4096)
        .map(|i| {
            let (y, z) = ((i / 16) % 16, i / 256);
            if y >= 11 && z >= 11 {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    let v = volume_from(dims, [1.0; 3], vals);
    let mut lut = flat_lut(2, 0.0, [1.0; 3]);
    lut.entries[1][0] = 200.0;
    // Camera on +x, z up: screen right is +y, so the block is in the top-right quadrant.
    let cam = orbit(&v, 0.0, 0.0, 2.0);
    let r = render::forward(
        &v,
        &lut,
        &cam,
        &Image::new(32, 32),
        &RenderOptions::default(),
    )
    .unwrap();
    let quadrant = |qx: usize, qy: usize| {
        (0..16)
            .flat_map(|y| (0..16).map(move |x| (x, y)))
            .map(|(x, y)| 1.0 - r.transmittance[(qy * 16 + y) * 32 + qx * 16 + x])
            .sum::<f32>()
    };
    let tr = quadrant(1, 0);
    assert!(tr > 1.0, "top-right is empty");
    for (qx, qy) in [(0, 0), (0, 1), (1, 1)] {
        assert!(quadrant(qx, qy) < 0.1 * tr, "quadrant {qx},{qy} is lit");
    }
    // Up = y instead: the orbit turns around y and +y is now up.
    let cam_y = Camera::orbit(
        &v.geometry,
        t2tf::camera::Orbit {
            yaw: 0.0,
            pitch: 0.0,
            distance: 2.0,
            up: UpAxis::Y,
        },
    )
    .unwrap();
    let r = render::forward(
        &v,
        &lut,
        &cam_y,
        &Image::new(32, 32),
        &RenderOptions::default(),
    )
    .unwrap();
    let top: f32 = r.transmittance[..32 * 16].iter().map(|t| 1.0 - t).sum();
    let bottom: f32 = r.transmittance[32 * 16..].iter().map(|t| 1.0 - t).sum();
    assert!(top > 10.0 * bottom.max(1e-3), "top {top} bottom {bottom}");
    // Up = -z: the block (high z) is now at the bottom.
    let cam_neg = Camera::orbit(
        &v.geometry,
        t2tf::camera::Orbit {
            yaw: 0.3,
            pitch: 0.0,
            distance: 2.0,
            up: UpAxis::NegZ,
        },
    )
    .unwrap();
    let r = render::forward(
        &v,
        &lut,
        &cam_neg,
        &Image::new(32, 32),
        &RenderOptions::default(),
    )
    .unwrap();
    let top: f32 = r.transmittance[..32 * 16].iter().map(|t| 1.0 - t).sum();
    let bottom: f32 = r.transmittance[32 * 16..].iter().map(|t| 1.0 - t).sum();
    assert!(bottom > 10.0 * top.max(1e-3), "top {top} bottom {bottom}");
}

#[test]
fn skipping_is_exact_and_early_termination_is_bounded() {
    let (v, lut) = neghip_setup();
    let cam = orbit(&v, 2.2, -0.2, 2.0);
    let bg = background::from_name("noise", 48, 48, 3).unwrap();
    let base = RenderOptions {
        skip_empty: false,
        early_termination: 0.0,
        ..RenderOptions::default()
    };
    let full = render::forward(&v, &lut, &cam, &bg, &base).unwrap();
    let skipped = render::forward(
        &v,
        &lut,
        &cam,
        &bg,
        &RenderOptions {
            skip_empty: true,
            ..base
        },
    )
    .unwrap();
    // Skipped samples have σ = 0 exactly and positions do not move: the same image.
    assert_eq!(full.image, skipped.image);
    assert!(
        skipped.samples * 2 < full.samples,
        "skipping saved little: {} vs {}",
        skipped.samples,
        full.samples
    );
    // A dense TF makes rays opaque; stopping at T < ε leaves out at most ε·|c − B| ≤ ε.
    let dense = Lut {
        entries: lut
            .entries
            .iter()
            .map(|e| [e[0] * 20.0, e[1], e[2], e[3]])
            .collect(),
    };
    let eps = 1e-3;
    let all = render::forward(&v, &dense, &cam, &bg, &base).unwrap();
    let stop = render::forward(
        &v,
        &dense,
        &cam,
        &bg,
        &RenderOptions {
            early_termination: eps,
            ..base
        },
    )
    .unwrap();
    let worst = all
        .image
        .data
        .iter()
        .zip(&stop.image.data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst <= eps, "early termination changed a pixel by {worst}");
    assert!(stop.samples < all.samples);
}

#[test]
fn backward_is_deterministic_across_thread_counts_and_matches_backward_from() {
    let (v, lut) = neghip_setup();
    let cam = orbit(&v, 1.0, 0.1, 2.5);
    let bg = background::from_name("fourier", 40, 40, 2).unwrap();
    let (wi, wt) = weights(40, 40, 3);
    let opts = RenderOptions {
        jitter_seed: Some(9),
        ..RenderOptions::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render::backward(&v, &lut, &cam, &bg, &opts, &wi, &wt).unwrap())
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(3));
    let r = render::forward(&v, &lut, &cam, &bg, &opts).unwrap();
    let from = render::backward_from(&v, &lut, &cam, &r, &opts, &wi, &wt).unwrap();
    assert_eq!(one, from);
}

#[test]
fn jitter_is_seeded() {
    let v = blob([12, 12, 12]);
    let cam = orbit(&v, 0.5, 0.0, 2.0);
    let bg = Image::new(16, 16);
    let lut = random_lut(8, 5.0, 40.0, 1);
    let with = |seed| {
        let o = RenderOptions {
            jitter_seed: seed,
            ..RenderOptions::default()
        };
        render::forward(&v, &lut, &cam, &bg, &o).unwrap().image
    };
    assert_eq!(with(Some(1)), with(Some(1)));
    assert_ne!(with(Some(1)), with(Some(2)));
    assert_ne!(with(Some(1)), with(None));
}

#[test]
fn level_follows_the_pixel_footprint() {
    let v = blob([64, 64, 64]);
    assert!(v.levels.len() >= 3);
    let cam = orbit(&v, 0.0, 0.0, 2.0);
    let voxel = |l: usize| v.levels[l].spacing.iter().copied().fold(f64::MAX, f64::min);
    // The chosen level's voxels are at most half a pixel at the focal point, the next level's
    // are larger: a pixel, 2·D·tan(22.5°)/H, is 0.43 world units at 224 rows (level 0, spacing
    // 0.8), 6.0 at 16 rows (level 1, 1.63), 11.9 at 8 rows (level 2, 3.36).
    for (h, expect) in [(224, 0), (16, 1), (8, 2)] {
        let l = render::choose_level(&v, &cam, h);
        assert_eq!(l, expect, "{h} rows");
        let half = cam.pixel_footprint(h) / render::VOXELS_PER_PIXEL;
        assert!(l == 0 || voxel(l) <= half);
        assert!(voxel(l + 1) > half);
    }
    let r = render::forward(
        &v,
        &random_lut(4, 1.0, 2.0, 0),
        &cam,
        &Image::new(16, 16),
        &RenderOptions::default(),
    )
    .unwrap();
    assert_eq!(r.level, render::choose_level(&v, &cam, 16));
}

#[test]
fn bad_inputs_are_clear_errors() {
    let v = blob([8, 8, 8]);
    let cam = orbit(&v, 0.0, 0.0, 2.0);
    let bg = Image::new(4, 4);
    let lut = random_lut(4, 1.0, 2.0, 0);
    let err = |o: RenderOptions, l: &Lut| {
        render::forward(&v, l, &cam, &bg, &o)
            .unwrap_err()
            .to_string()
    };
    assert!(err(
        RenderOptions {
            step: 0.0,
            ..Default::default()
        },
        &lut
    )
    .contains("step"));
    assert!(err(
        RenderOptions {
            level: Some(99),
            ..Default::default()
        },
        &lut
    )
    .contains("level 99"));
    assert!(err(
        RenderOptions {
            early_termination: 1.5,
            ..Default::default()
        },
        &lut
    )
    .contains("early"));
    let mut neg = lut.clone();
    neg.entries[2][0] = -1.0;
    assert!(err(RenderOptions::default(), &neg).contains("entry 2"));
    assert!(
        err(RenderOptions::default(), &flat_lut(1, 1.0, [0.0; 3])).contains("2 to 2^24 are needed")
    );
    let e = render::backward(
        &v,
        &lut,
        &cam,
        &bg,
        &RenderOptions::default(),
        &[0.0; 5],
        &[],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("d_image has 5 values; 48 expected"), "{e}");
}

#[test]
fn orbit_sheet_tiles_the_ring_views() {
    let v = blob([12, 12, 12]);
    let cams = Camera::ring(&v.geometry, 5, 0.2, 2.5, UpAxis::Z).unwrap();
    let bg = background::from_name("gray:0.5", 10, 8, 0).unwrap();
    let lut = random_lut(8, 5.0, 40.0, 2);
    let opts = RenderOptions::default();
    let sheet = render::orbit_sheet(&v, &lut, &cams, &bg, &opts).unwrap();
    // 5 views: 3 columns, 2 rows; the sixth cell is background.
    assert_eq!((sheet.width, sheet.height), (30, 16));
    for (i, cam) in cams.iter().enumerate() {
        let one = render::forward(&v, &lut, cam, &bg, &opts).unwrap().image;
        let (cx, cy) = (i % 3, i / 3);
        for y in 0..8 {
            for x in 0..10 {
                assert_eq!(sheet.pixel(cx * 10 + x, cy * 8 + y), one.pixel(x, y));
            }
        }
    }
    assert_eq!(sheet.pixel(25, 12), [0.5; 3]);
    // The ring's views differ (yaw 0, 72°, ...).
    assert_ne!(sheet.pixel(5, 4), sheet.pixel(15, 4));
}
