//! The optimizer's renderer adapter casting rays below CLIP's input size: the upsampled view
//! composited over the full-size background, and its gradient (through the upsampling's
//! transpose and the background term of ∂I/∂T) against central differences, as in
//! tests/render/render_grad.rs (same loss, step and tolerance argument).

use crate::render_util;

use render_util::*;
use t2tf::camera::UpAxis;
use t2tf::optimize::adapters::VolumeRenderer;
use t2tf::optimize::{Background, Renderer, View};
use t2tf::render::RenderOptions;
use t2tf::tf::Lut;

const H: f32 = 0.05;

fn smooth_opts() -> RenderOptions {
    RenderOptions {
        step: 0.5,
        level: Some(0),
        jitter_seed: None,
        early_termination: 0.0,
        skip_empty: false,
        empty_sigma: 0.0,
    }
}

fn loss(r: &VolumeRenderer, lut: &Lut, view: &View, wi: &[f32], wt: &[f32]) -> f64 {
    let (image, t, _) = r.render(lut, view).unwrap();
    let a: f64 = image.data.iter().zip(wi).map(|(x, w)| (x * w) as f64).sum();
    a + t.iter().zip(wt).map(|(x, w)| (x * w) as f64).sum::<f64>()
}

#[test]
fn below_clip_size_gradient_matches_finite_differences() {
    let v = blob([9, 8, 7]);
    let (size, render_size) = (20, 12);
    let r = VolumeRenderer {
        backend: t2tf::render::shared_backend(),
        volume: &v,
        series: None,
        options: smooth_opts(),
        up: UpAxis::Z,
        size,
        render_size,
        jitter: true,
    };
    let view = View {
        yaw: 0.7,
        pitch: 0.15,
        distance: 2.2,
        background: Background::Checkerboard { seed: 3 },
        seed: 5,
        time: 0,
    };
    let (wi, wt) = weights(size, size, 7);
    let lut = random_lut(8, 5.0, 60.0, 2);

    // The view is the full size, and the background shows through sharp where T = 1.
    let (image, t, tape) = r.render(&lut, &view).unwrap();
    assert_eq!(
        (image.width, image.height, t.len()),
        (size, size, size * size)
    );
    let full = VolumeRenderer {
        render_size: size,
        ..r
    };
    let (reference, _, _) = full.render(&lut, &view).unwrap();
    let corner = |im: &t2tf::image::Image| im.pixel(0, 0);
    assert_eq!(
        corner(&image),
        corner(&reference),
        "background pixel must be unchanged"
    );
    assert!(
        psnr(&image, &reference) > 20.0,
        "upsampled view far from the full one"
    );

    let analytic = r.backward(&lut, &view, &tape, &wi, &wt).unwrap().entries;
    let scale = analytic
        .iter()
        .flatten()
        .fold(0.0f64, |m, g| m.max(g.abs()));
    assert!(scale > 1e-3, "gradient is all but zero: test is void");
    for (j, entry) in analytic.iter().enumerate() {
        for (c, &g) in entry.iter().enumerate() {
            let d = |h: f32| {
                let (mut up, mut dn) = (lut.clone(), lut.clone());
                up.entries[j][c] += h;
                dn.entries[j][c] -= h;
                let step = up.entries[j][c] as f64 - dn.entries[j][c] as f64;
                (loss(&r, &up, &view, &wi, &wt) - loss(&r, &dn, &view, &wi, &wt)) / step
            };
            let n = (4.0 * d(H) - d(2.0 * H)) / 3.0;
            assert!(
                (g - n).abs() <= 2e-4 * scale + 1e-3 * n.abs(),
                "entry {j} chan {c}: analytic {g}, numeric {n} (scale {scale})"
            );
        }
    }
}
