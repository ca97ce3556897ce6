//! Renderer backward against central differences of the forward.
//!
//! The forward is f32; the loss L = Σ w·I + Σ u·T_N (random weights) is summed in f64, and each
//! difference is divided by the perturbation actually stored in the f32 LUT. Central
//! differences with Richardson extrapolation, D = (4 D(h) − D(2h)) / 3, leave an O(h⁴)
//! truncation error, so what remains is f32 rounding: each pixel carries ~1e-6 absolute error
//! (a few ulps per sample over tens of samples), the ~500 weighted terms add up to at most
//! ~3e-5 in L (random signs make it far less), and dividing by 2h = 0.1 bounds the error by
//! ~5e-4 absolute for gradients whose largest entry is ~5, i.e. ~1e-4 relative; measured: ~2e-6.
//! The tolerance 2e-4·max|∇| + 1e-3·|∇ᵢ| sits above that bound and still fails on any missing
//! or mis-weighted term (those are O(|∇ᵢ|); dropping the ∂L/∂T_N term fails three cases).

use crate::render_util;

use render_util::*;
use t2tf::background;
use t2tf::camera::Camera;
use t2tf::image::Image;
use t2tf::render::cpu::BrickValues;
use t2tf::render::{self, Backend, CpuBackend, RenderOptions};
use t2tf::tf::{ControlPoints, Lut};
use t2tf::volume::Volume;

const H: f32 = 0.05;

struct Case<'a> {
    v: &'a Volume,
    cam: Camera,
    bg: Image,
    opts: RenderOptions,
    wi: Vec<f32>,
    wt: Vec<f32>,
}

impl Case<'_> {
    fn loss(&self, lut: &Lut) -> f64 {
        loss(
            self.v, lut, &self.cam, &self.bg, &self.opts, &self.wi, &self.wt,
        )
    }

    fn analytic(&self, lut: &Lut) -> Vec<[f64; 4]> {
        render::backward(
            self.v, lut, &self.cam, &self.bg, &self.opts, &self.wi, &self.wt,
        )
        .unwrap()
        .entries
    }

    /// Richardson-extrapolated central difference for one LUT value.
    fn numeric(&self, lut: &Lut, entry: usize, chan: usize) -> f64 {
        let d = |h: f32| {
            let (mut up, mut dn) = (lut.clone(), lut.clone());
            up.entries[entry][chan] += h;
            dn.entries[entry][chan] -= h;
            let step = up.entries[entry][chan] as f64 - dn.entries[entry][chan] as f64;
            (self.loss(&up) - self.loss(&dn)) / step
        };
        (4.0 * d(H) - d(2.0 * H)) / 3.0
    }

    fn check(&self, lut: &Lut, what: &str) {
        let a = self.analytic(lut);
        let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(
            scale > 1e-3,
            "{what}: gradient is all but zero ({scale}), test is void"
        );
        let mut worst = 0.0f64;
        for (j, entry) in a.iter().enumerate() {
            for (c, &g) in entry.iter().enumerate() {
                let n = self.numeric(lut, j, c);
                let err = (g - n).abs();
                worst = worst.max(err / scale);
                assert!(
                    err <= 2e-4 * scale + 1e-3 * n.abs(),
                    "{what}: entry {j} chan {c}: analytic {g}, numeric {n} (scale {scale})"
                );
            }
        }
        eprintln!("{what}: max |∇| {scale:.3e}, worst error / max |∇| {worst:.2e}");
    }
}

fn smooth_opts() -> RenderOptions {
    // No early stop and no skipping: the loss is smooth in every LUT value, so differences
    // never straddle a change in which samples are taken.
    RenderOptions {
        step: 0.5,
        level: Some(0),
        jitter_seed: Some(11),
        early_termination: 0.0,
        skip_empty: false,
        empty_sigma: 0.0,
    }
}

fn case(v: &Volume, cam: Camera, w: usize, h: usize, opts: RenderOptions, seed: u64) -> Case<'_> {
    let (wi, wt) = weights(w, h, seed);
    Case {
        v,
        cam,
        bg: background::from_name("noise", w, h, seed).unwrap(),
        opts,
        wi,
        wt,
    }
}

#[test]
fn partly_empty_view() {
    // At 1.6 bounding radii the box fills the middle; border rays miss it.
    let v = blob([12, 11, 10]);
    let c = case(&v, orbit(&v, 0.7, 0.2, 1.6), 14, 12, smooth_opts(), 1);
    let r = render::forward(&v, &random_lut(9, 2.0, 30.0, 5), &c.cam, &c.bg, &c.opts).unwrap();
    assert!(r.transmittance.contains(&1.0), "no ray misses the box");
    assert!(
        r.transmittance.iter().any(|&t| t < 0.9),
        "no ray sees the blob"
    );
    c.check(&random_lut(9, 2.0, 30.0, 5), "partly empty");
}

#[test]
fn saturated_view() {
    // σ 150–255 per normalized length over a chord of ~1: T ends near e^-200.
    let v = blob([10, 10, 10]);
    let c = case(&v, orbit(&v, 2.0, -0.1, 2.0), 10, 10, smooth_opts(), 2);
    let lut = random_lut(6, 150.0, 255.0, 6);
    let r = render::forward(&v, &lut, &c.cam, &c.bg, &c.opts).unwrap();
    assert!(r.transmittance.iter().any(|&t| t < 1e-20));
    c.check(&lut, "saturated");
}

#[test]
fn one_point_thick_slab() {
    // 1 × 9 × 8 points: rendered as a slab one spacing thick (render::cpu::march's BoxFrame), seen
    // obliquely so that rays cross the slab's two faces and its rim.
    let vals: Vec<f64> = (0..72).map(|i| ((i * 37) % 29) as f64).collect();
    let v = volume_from([1, 9, 8], [1.5, 1.0, 1.0], vals);
    let c = case(&v, orbit(&v, 0.3, 0.25, 1.8), 12, 10, smooth_opts(), 3);
    let lut = random_lut(7, 5.0, 80.0, 8);
    let r = render::forward(&v, &lut, &c.cam, &c.bg, &c.opts).unwrap();
    assert!(
        r.transmittance.iter().any(|&t| t < 0.99),
        "the slab is not seen"
    );
    c.check(&lut, "one point thick");
}

#[test]
fn grazing_a_corner() {
    // Look straight at the box's far corner: the central rays enter and leave within a voxel.
    let v = blob([9, 10, 11]);
    let g = v.geometry;
    let e = g.extent();
    let corner = glam::DVec3::new(g.origin[0] + e[0], g.origin[1] + e[1], g.origin[2] + e[2]);
    let dir = glam::DVec3::new(1.0, 0.8, -0.6).normalize();
    let cam = Camera {
        position: corner + 6.0 * g.bounding_radius() * dir,
        focal_point: corner,
        view_up: (glam::DVec3::Z - glam::DVec3::Z.dot(dir) * dir).normalize(),
        view_angle_deg: 8.0,
    };
    let c = case(&v, cam, 12, 12, smooth_opts(), 3);
    let lut = random_lut(7, 10.0, 80.0, 7);
    let r = render::forward(&v, &lut, &cam, &c.bg, &c.opts).unwrap();
    assert!(r.transmittance.contains(&1.0) && r.transmittance.iter().any(|&t| t < 1.0));
    c.check(&lut, "grazing");
}

#[test]
fn real_volume_crop_with_skipping() {
    // A 16³ crop of neghip; the TF is zero below 0.3, so bricks of low values are skipped, but
    // the zero entries still get their gradient from the bricks that are marched.
    let v = crop_u8("neghip_64x64x64_uint8.raw", [64; 3], [24, 24, 24], [16; 3]);
    let opts = RenderOptions {
        skip_empty: true,
        jitter_seed: None,
        ..smooth_opts()
    };
    let c = case(&v, orbit(&v, 4.0, 0.3, 2.2), 12, 12, opts, 4);
    let mut lut = random_lut(10, 5.0, 60.0, 8);
    for e in &mut lut.entries[..3] {
        e[0] = 0.0;
    }
    // The differences need σ ± 2h ≥ 0: shift the zero entries' check to colours only by
    // checking σ for entries ≥ 3 and all colours.
    let a = c.analytic(&lut);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for (j, entry) in a.iter().enumerate() {
        for (ch, &g) in entry.iter().enumerate() {
            if ch == 0 && j < 3 {
                continue;
            }
            let n = c.numeric(&lut, j, ch);
            assert!(
                (g - n).abs() <= 2e-4 * scale + 1e-3 * n.abs(),
                "neghip crop: entry {j} chan {ch}: analytic {g}, numeric {n}"
            );
        }
    }
}

#[test]
fn real_volume_crop_stored_in_8_bits() {
    // The same crop as above kept as uint8: the renderer interpolates its 8-bit copy
    // (render::cpu::bricked) — through AVX2 gathers where the CPU has them.
    let v = crop_u8_typed("neghip_64x64x64_uint8.raw", [64; 3], [20, 22, 24], [16; 3]);
    assert!(matches!(
        CpuBackend::default().prepare(&v, 0).unwrap().values(),
        BrickValues::U8(_)
    ));
    let c = case(&v, orbit(&v, 2.0, -0.2, 2.4), 12, 10, smooth_opts(), 6);
    c.check(&random_lut(12, 2.0, 50.0, 9), "neghip crop, u8");
}

#[test]
fn control_points_through_the_lut() {
    // ∂L/∂(σ_k, rgb_k, x_k) = Σ_j ∂L/∂lut_j · ∂lut_j/∂(...), with ∂lut_j/∂(...) from
    // differences of the f64 `ControlPoints::eval` (exact for σ and rgb, which enter linearly;
    // x_k is smooth as long as no LUT sample sits on a control point, true here).
    let v = blob([12, 12, 12]);
    let c = case(&v, orbit(&v, 1.2, 0.1, 2.0), 12, 12, smooth_opts(), 5);
    let cp = ControlPoints {
        x: vec![0.0, 0.325, 0.706, 1.0],
        sigma: vec![5.0, 40.0, 12.0, 25.0],
        rgb: vec![
            [0.2, 0.4, 0.8],
            [0.9, 0.3, 0.1],
            [0.5, 0.8, 0.2],
            [0.3, 0.3, 0.6],
        ],
    };
    let n_lut = 64;
    let lut_grad = c.analytic(&cp.to_lut(n_lut));
    let chain = |perturb: &dyn Fn(&mut ControlPoints, f64)| -> f64 {
        let h = 1e-6;
        (0..n_lut)
            .map(|j| {
                let t = j as f64 / (n_lut - 1) as f64;
                let (mut up, mut dn) = (cp.clone(), cp.clone());
                perturb(&mut up, h);
                perturb(&mut dn, -h);
                let (eu, ed) = (up.eval(t), dn.eval(t));
                (0..4)
                    .map(|ch| lut_grad[j][ch] * (eu[ch] - ed[ch]) / (2.0 * h))
                    .sum::<f64>()
            })
            .sum()
    };
    let numeric = |perturb: &dyn Fn(&mut ControlPoints, f64), h: f64| -> f64 {
        let d = |h: f64| {
            let (mut up, mut dn) = (cp.clone(), cp.clone());
            perturb(&mut up, h);
            perturb(&mut dn, -h);
            (c.loss(&up.to_lut(n_lut)) - c.loss(&dn.to_lut(n_lut))) / (2.0 * h)
        };
        (4.0 * d(h) - d(2.0 * h)) / 3.0
    };
    let mut checked = Vec::new();
    for k in 0..cp.len() {
        checked.push((
            format!("sigma {k}"),
            chain(&|c, h| c.sigma[k] += h),
            numeric(&|c, h| c.sigma[k] += h, 0.05),
        ));
        for ch in 0..3 {
            checked.push((
                format!("rgb {k}.{ch}"),
                chain(&|c, h| c.rgb[k][ch] += h),
                numeric(&|c, h| c.rgb[k][ch] += h, 0.05),
            ));
        }
    }
    for k in 1..cp.len() - 1 {
        // Position steps of 1e-3 move LUT values by ~σ'·1e-3 ≫ f32 resolution, and no LUT
        // sample (multiples of 1/63) lies within 2h = 2e-3 of 0.325 or 0.706 (both ~8e-3 away).
        checked.push((
            format!("x {k}"),
            chain(&|c, h| c.x[k] += h),
            numeric(&|c, h| c.x[k] += h, 1e-3),
        ));
    }
    let scale = checked.iter().fold(0.0f64, |m, (_, a, _)| m.max(a.abs()));
    for (what, a, n) in &checked {
        assert!(
            (a - n).abs() <= 2e-4 * scale + 1e-3 * n.abs(),
            "control point {what}: chained {a}, numeric {n} (scale {scale})"
        );
    }
}

#[test]
fn uniform_regions_stepped_in_one_go() {
    // Piecewise-constant 25³ volume: bricks inside a region are uniform and are crossed in one
    // step; their summed gradient terms must match differences like any other sample.
    let dims = [25usize; 3];
    let vals = (0..25 * 25 * 25)
        .map(|i| {
            let (x, y, z) = (i % 25, (i / 25) % 25, i / 625);
            [0.1, 0.4, 0.7, 1.0][(x > 8) as usize + 2 * (y + z > 24) as usize]
        })
        .collect();
    let v = volume_from(dims, [1.0; 3], vals);
    assert!(v.levels[0].bricks.uniform.iter().any(|&u| u));
    let c = case(&v, orbit(&v, 0.4, 0.25, 2.0), 12, 12, smooth_opts(), 6);
    c.check(&random_lut(5, 2.0, 20.0, 9), "uniform regions");
}
