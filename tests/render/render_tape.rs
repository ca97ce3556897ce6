//! The backend's backward replays what its forward recorded (render::cpu::CpuTape): its
//! images and LUT gradients equal those of the front functions, whose backward marches every
//! ray again, bit for bit.

use crate::render_util;

use render_util::*;
use t2tf::background;
use t2tf::camera::Camera;
use t2tf::image::{resize_bilinear_adjoint, Image};
use t2tf::render::{self, Backend, CpuBackend, RenderOptions, Shot};
use t2tf::tf::Lut;
use t2tf::volume::Volume;

/// Option sets: defaults; jitter; a fine step without skipping or early termination; a
/// coarse level.
fn option_sets() -> Vec<RenderOptions> {
    vec![
        RenderOptions::default(),
        RenderOptions {
            jitter_seed: Some(5),
            ..RenderOptions::default()
        },
        RenderOptions {
            step: 0.25,
            skip_empty: false,
            early_termination: 0.0,
            jitter_seed: Some(11),
            ..RenderOptions::default()
        },
        RenderOptions {
            level: Some(1),
            ..RenderOptions::default()
        },
    ]
}

fn cameras(v: &Volume) -> Vec<Camera> {
    [(0.0, 0.0), (37.0, 21.0), (200.0, -50.0)]
        .iter()
        .map(|&(yaw, pitch): &(f64, f64)| orbit(v, yaw.to_radians(), pitch.to_radians(), 2.2))
        .collect()
}

/// Every view and option set of `v` with `lut`: the backend's image, T_N and gradient equal
/// `render::forward` and `render::backward_from`'s, bit for bit, at `side`².
fn check(v: &Volume, lut: &Lut, side: usize, option_sets: &[RenderOptions]) {
    let bg = background::from_name("noise", side, side, 3).unwrap();
    let (wi, wt) = weights(side, side, 9);
    let backend = CpuBackend::default();
    for (c, cam) in cameras(v).iter().enumerate() {
        for (o, opts) in option_sets.iter().enumerate() {
            let level = render::level_for(v, lut, cam, (side, side), opts).unwrap();
            let prepared = backend.prepare(v, level).unwrap();
            let shot = Shot {
                camera: cam,
                background: &bg,
                options: opts,
                cast: (side, side),
            };
            let (r, tape) = backend.forward(&prepared, lut, &shot).unwrap();
            let g = backend
                .backward(&prepared, lut, &shot, &tape, &wi, &wt)
                .unwrap();
            let front = render::forward(v, lut, cam, &bg, opts).unwrap();
            let g_front = render::backward_from(v, lut, cam, &front, opts, &wi, &wt).unwrap();
            let bits = |x: &[f32]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&r.image.data),
                bits(&front.image.data),
                "view {c}, options {o}"
            );
            assert_eq!(bits(&r.transmittance), bits(&front.transmittance));
            for (a, b) in g.entries.iter().zip(&g_front.entries) {
                for k in 0..4 {
                    assert_eq!(a[k].to_bits(), b[k].to_bits(), "view {c}, options {o}");
                }
            }
        }
    }
}

#[test]
fn replayed_backward_equals_marching_again() {
    // Dense: every sample composited, rays end by early termination.
    let options = option_sets();
    check(
        &blob([37, 29, 33]),
        &random_lut(64, 0.0, 900.0, 1),
        40,
        &options,
    );
    // Sparse with empty and uniform bricks (skips and uniform runs on the tape).
    let v = crop_u8_typed(
        "aneurism_256x256x256_uint8.raw",
        [256; 3],
        [96, 96, 96],
        [64, 64, 64],
    );
    let mut lut = random_lut(256, 0.0, 400.0, 2);
    for e in &mut lut.entries[..20] {
        e[0] = 0.0;
    }
    check(&v, &lut, 48, &options);
}

/// Views with more steps than a tape keeps (2²² in all, `cpu::RECORD_STEPS`; here every
/// sample is one): the tiles past the budget are marched again, with the same result.
#[test]
fn tiles_past_the_record_budget_march_again() {
    let opts = RenderOptions {
        step: 1.0 / 64.0,
        early_termination: 0.0,
        ..RenderOptions::default()
    };
    let (v, lut) = (blob([60, 50, 55]), random_lut(64, 0.1, 2.0, 3));
    let bg = Image::new(56, 56);
    for cam in cameras(&v) {
        let samples = render::forward(&v, &lut, &cam, &bg, &opts).unwrap().samples;
        assert!(samples > 1 << 22, "only {samples} samples");
    }
    check(&v, &lut, 56, &[opts]);
}

/// Cast below the output size: the tape is the cast image's, and the gradient equals the
/// front functions' on the cast image.
#[test]
fn upsampled_shots_replay_too() {
    let v = blob([30, 26, 28]);
    let lut = random_lut(32, 0.0, 300.0, 4);
    let bg = background::from_name("checkerboard", 40, 40, 1).unwrap();
    let (wi, wt) = weights(40, 40, 2);
    let backend = CpuBackend::default();
    let cam = orbit(&v, 0.7, 0.2, 2.2);
    let opts = RenderOptions::default();
    let prepared = backend.prepare(&v, 0).unwrap();
    let shot = Shot {
        camera: &cam,
        background: &bg,
        options: &opts,
        cast: (23, 23),
    };
    let (r, tape) = backend.forward(&prepared, &lut, &shot).unwrap();
    let g = backend
        .backward(&prepared, &lut, &shot, &tape, &wi, &wt)
        .unwrap();
    assert_eq!(r.image.width, 40);
    // What the backend computes, through the front functions: the cast image over black, and
    // the gradient through I = up(acc) + up(T) · B and the upsampling's transpose.
    let (s, n) = ((23, 23), (40, 40));
    let cast = render::forward(&v, &lut, &cam, &Image::new(23, 23), &opts).unwrap();
    let d_t: Vec<f32> = (0..40 * 40)
        .map(|p| {
            let from_image: f32 = (0..3).map(|c| wi[3 * p + c] * bg.data[3 * p + c]).sum();
            wt[p] + from_image
        })
        .collect();
    let d_acc_s = resize_bilinear_adjoint(&wi, n, 3, s);
    let d_t_s = resize_bilinear_adjoint(&d_t, n, 1, s);
    let front = render::backward_from(&v, &lut, &cam, &cast, &opts, &d_acc_s, &d_t_s).unwrap();
    for (a, b) in g.entries.iter().zip(&front.entries) {
        for k in 0..4 {
            assert_eq!(a[k].to_bits(), b[k].to_bits());
        }
    }
}
