//! The optimization loop end to end on analytic stand-ins for the renderer, CLIP and the TF
//! parameterization (the real ones are tested in their own modules; this proves the plumbing:
//! gradient flow through every term, averaging over views, SGD, schedule, stop flag,
//! determinism, errors instead of NaN).

use std::sync::atomic::{AtomicBool, Ordering};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use t2tf::image::Image;
use t2tf::optimize::{
    self, schedule, Background, BoxError, ImageEncoder, OptimizeError, Parameterization,
    PhaseTimes, PointGrad, Renderer, Settings, Targets, View,
};
use t2tf::tf::{ControlPoints, Lut, LutGrad};

const SIDE: usize = 6;
const NPIX: usize = SIDE * SIDE;
const LUT_N: usize = 17;
const K: usize = 5;
const D: usize = 8;
/// Extinction scale of the toy: σ = 255 on every entry gives T = exp(−KAPPA·Σ_j w_pj).
const KAPPA: f64 = 2.0;

/// A renderer-shaped analytic model: pixel p sees LUT entry j with weight w_pj(view) > 0;
/// T_p = exp(−κ Σ_j w_pj σ_j / 255); I_pc = (1 − T_p) Σ_j v_pj rgb_jc + T_p B_pc with
/// v = w normalized per pixel. Smooth, monotone in σ, linear in colour — like the real one.
struct Toy {
    base: Vec<Vec<f64>>,
    phase: Vec<Vec<f64>>,
    /// Return NaN pixels from this render call on (counts calls).
    nan_after: Option<usize>,
    calls: std::cell::Cell<usize>,
}

impl Toy {
    fn new(seed: u64) -> Toy {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        let mut m = |lo: f64, hi: f64| -> Vec<Vec<f64>> {
            (0..NPIX)
                .map(|_| (0..LUT_N).map(|_| r.random_range(lo..hi)).collect())
                .collect()
        };
        let base = m(0.05, 1.0);
        let phase = m(0.0, std::f64::consts::TAU);
        Toy {
            base,
            phase,
            nan_after: None,
            calls: 0.into(),
        }
    }

    fn weights(&self, view: &View) -> Vec<Vec<f64>> {
        self.base
            .iter()
            .zip(&self.phase)
            .map(|(b, ph)| {
                b.iter()
                    .zip(ph)
                    .map(|(b, ph)| {
                        b * (1.0 + 0.5 * (view.yaw + ph).sin()) * (1.0 + 0.1 * view.pitch)
                            / view.distance
                            * 3.0
                    })
                    .collect()
            })
            .collect()
    }

    fn background(view: &View) -> Vec<f64> {
        match view.background {
            Background::Gray { level } => vec![level; NPIX * 3],
            Background::Checkerboard { seed }
            | Background::Noise { seed }
            | Background::Fourier { seed } => {
                let mut r = ChaCha8Rng::seed_from_u64(seed);
                (0..NPIX * 3).map(|_| r.random_range(0.0..1.0)).collect()
            }
        }
    }

    /// (T_p, m_pc, w, v, background), all f64.
    #[allow(clippy::type_complexity)]
    fn parts(
        &self,
        lut: &Lut,
        view: &View,
    ) -> (
        Vec<f64>,
        Vec<[f64; 3]>,
        Vec<Vec<f64>>,
        Vec<Vec<f64>>,
        Vec<f64>,
    ) {
        let w = self.weights(view);
        let mut t = Vec::with_capacity(NPIX);
        let mut m = Vec::with_capacity(NPIX);
        let mut v = Vec::with_capacity(NPIX);
        for row in &w {
            let s: f64 = row
                .iter()
                .zip(&lut.entries)
                .map(|(w, e)| w * e[0] as f64)
                .sum();
            t.push((-KAPPA * s / 255.0).exp());
            let total: f64 = row.iter().sum();
            let vr: Vec<f64> = row.iter().map(|x| x / total).collect();
            m.push(std::array::from_fn(|c| {
                vr.iter()
                    .zip(&lut.entries)
                    .map(|(v, e)| v * e[1 + c] as f64)
                    .sum()
            }));
            v.push(vr);
        }
        (t, m, w, v, Toy::background(view))
    }
}

impl Renderer for Toy {
    fn render(&self, lut: &Lut, view: &View) -> Result<(Image, Vec<f32>), BoxError> {
        let n = self.calls.get();
        self.calls.set(n + 1);
        let (t, m, _, _, bg) = self.parts(lut, view);
        let mut im = Image::new(SIDE, SIDE);
        for p in 0..NPIX {
            for c in 0..3 {
                im.data[p * 3 + c] = ((1.0 - t[p]) * m[p][c] + t[p] * bg[p * 3 + c]) as f32;
            }
        }
        if self.nan_after.is_some_and(|k| n >= k) {
            im.data[5] = f32::NAN;
        }
        Ok((im, t.iter().map(|&x| x as f32).collect()))
    }

    fn backward(
        &self,
        lut: &Lut,
        view: &View,
        d_image: &[f32],
        d_t: &[f32],
    ) -> Result<LutGrad, BoxError> {
        let (t, m, w, v, bg) = self.parts(lut, view);
        let mut g = LutGrad::zeros(LUT_N);
        for p in 0..NPIX {
            let di: [f64; 3] = std::array::from_fn(|c| d_image[p * 3 + c] as f64);
            let dt = d_t[p] as f64
                + (0..3)
                    .map(|c| di[c] * (bg[p * 3 + c] - m[p][c]))
                    .sum::<f64>();
            for j in 0..LUT_N {
                g.entries[j][0] += dt * (-t[p]) * w[p][j] * KAPPA / 255.0;
                for (c, d) in di.iter().enumerate() {
                    g.entries[j][1 + c] += d * (1.0 - t[p]) * v[p][j];
                }
            }
        }
        Ok(g)
    }
}

/// A linear "image encoder": e = M · pixels.
struct LinearEncoder {
    m: Vec<Vec<f64>>,
}

impl LinearEncoder {
    fn new(seed: u64) -> LinearEncoder {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        LinearEncoder {
            m: (0..D)
                .map(|_| (0..NPIX * 3).map(|_| r.random_range(-1.0..1.0)).collect())
                .collect(),
        }
    }
}

impl ImageEncoder for LinearEncoder {
    type Cache = usize;

    fn encode(&self, images: &[Image]) -> Result<(Vec<Vec<f32>>, usize), BoxError> {
        let e = images
            .iter()
            .map(|im| {
                self.m
                    .iter()
                    .map(|row| {
                        row.iter()
                            .zip(&im.data)
                            .map(|(a, &x)| a * x as f64)
                            .sum::<f64>() as f32
                    })
                    .collect()
            })
            .collect();
        Ok((e, images.len()))
    }

    fn backward(&self, n: &usize, d: &[Vec<f32>]) -> Result<Vec<Image>, BoxError> {
        assert_eq!(*n, d.len());
        Ok(d.iter()
            .map(|de| {
                let mut im = Image::new(SIDE, SIDE);
                for (i, v) in im.data.iter_mut().enumerate() {
                    *v = self
                        .m
                        .iter()
                        .zip(de)
                        .map(|(row, &g)| row[i] * g as f64)
                        .sum::<f64>() as f32;
                }
                im
            })
            .collect())
    }
}

/// The paper's σ = 255 (tanh p + 1)/2, rgb = (tanh q + 1)/2 at K fixed, evenly spaced points
/// (positions are not optimized here; their gradient belongs to the TF module's tests).
struct TanhTf;

impl TanhTf {
    fn x() -> Vec<f64> {
        (0..K).map(|k| k as f64 / (K - 1) as f64).collect()
    }
}

impl Parameterization for TanhTf {
    fn control_points(&self, p: &[f64]) -> Result<ControlPoints, BoxError> {
        Ok(ControlPoints {
            x: TanhTf::x(),
            sigma: p[..K]
                .iter()
                .map(|p| 255.0 * (p.tanh() + 1.0) / 2.0)
                .collect(),
            rgb: (0..K)
                .map(|k| std::array::from_fn(|c| (p[K + 3 * k + c].tanh() + 1.0) / 2.0))
                .collect(),
        })
    }

    fn lut_size(&self) -> usize {
        LUT_N
    }

    fn params_for(&self, cp: &ControlPoints) -> Result<Vec<f64>, BoxError> {
        let inv = |y: f64| y.clamp(-1.0 + 1e-9, 1.0 - 1e-9).atanh();
        let mut p: Vec<f64> = cp
            .sigma
            .iter()
            .map(|s| inv(2.0 * s / 255.0 - 1.0))
            .collect();
        for c in &cp.rgb {
            p.extend(c.iter().map(|v| inv(2.0 * v - 1.0)));
        }
        Ok(p)
    }

    fn backward(&self, p: &[f64], lut: &LutGrad, direct: &PointGrad) -> Result<Vec<f64>, BoxError> {
        // LUT entry j sits at x_j = j/(n−1), between points k and k+1 with weight w.
        let x = TanhTf::x();
        let mut d_val = [[0.0f64; 4]; K];
        for (j, g) in lut.entries.iter().enumerate() {
            let t = j as f64 / (LUT_N - 1) as f64;
            let k = ((t * (K - 1) as f64) as usize).min(K - 2);
            let w = (t - x[k]) / (x[k + 1] - x[k]);
            for c in 0..4 {
                d_val[k][c] += (1.0 - w) * g[c];
                d_val[k + 1][c] += w * g[c];
            }
        }
        let mut out = vec![0.0; p.len()];
        for k in 0..K {
            let th = p[k].tanh();
            out[k] = (d_val[k][0] + direct.sigma[k]) * 255.0 / 2.0 * (1.0 - th * th);
            for c in 0..3 {
                let th = p[K + 3 * k + c].tanh();
                out[K + 3 * k + c] = (d_val[k][1 + c] + direct.rgb[k][c]) / 2.0 * (1.0 - th * th);
            }
        }
        Ok(out)
    }
}

struct Fixture {
    toy: Toy,
    enc: LinearEncoder,
    positive: Vec<f32>,
    pool: Vec<Vec<f32>>,
    user: Vec<Vec<f32>>,
}

impl Fixture {
    fn new() -> Fixture {
        let toy = Toy::new(1);
        let enc = LinearEncoder::new(2);
        // The positive is the embedding of a target TF's render: reachable by construction.
        let target = ControlPoints {
            x: TanhTf::x(),
            sigma: vec![5.0, 200.0, 20.0, 150.0, 0.0],
            rgb: vec![
                [0.9, 0.1, 0.1],
                [0.8, 0.7, 0.1],
                [0.1, 0.9, 0.2],
                [0.1, 0.2, 0.9],
                [0.5; 3],
            ],
        };
        let v = View {
            yaw: 0.3,
            pitch: 0.0,
            distance: 3.0,
            background: Background::Gray { level: 0.5 },
        };
        let (im, _) = toy.render(&target.to_lut(LUT_N), &v).unwrap();
        let positive = enc.encode(&[im]).unwrap().0.remove(0);
        // Negatives are renders too (random TFs, and a blank one as the user's "a blank
        // image"), so telling the prompt apart takes a TF close to the target.
        let mut r = ChaCha8Rng::seed_from_u64(3);
        let embed = |cp: &ControlPoints| -> Vec<f32> {
            let (im, _) = toy.render(&cp.to_lut(LUT_N), &v).unwrap();
            enc.encode(&[im]).unwrap().0.remove(0)
        };
        let pool = (0..40)
            .map(|_| {
                embed(&ControlPoints {
                    x: TanhTf::x(),
                    sigma: (0..K).map(|_| r.random_range(0.0..255.0)).collect(),
                    rgb: (0..K)
                        .map(|_| std::array::from_fn(|_| r.random_range(0.0..1.0)))
                        .collect(),
                })
            })
            .collect();
        let user = vec![embed(&ControlPoints {
            x: TanhTf::x(),
            sigma: vec![0.0; K],
            rgb: vec![[0.5; 3]; K],
        })];
        Fixture {
            toy,
            enc,
            positive,
            pool,
            user,
        }
    }

    fn targets(&self) -> Targets<'_> {
        Targets {
            positive: &self.positive,
            pool: &self.pool,
            user_negatives: &self.user,
            logit_scale: 100.0,
        }
    }
}

fn settings() -> Settings {
    Settings {
        steps: 80,
        views: 2,
        lr: 0.05,
        prior_start: 40,
        gray_steps: 10,
        negatives_per_step: 8,
        control_points: K,
        ..Settings::default()
    }
}

fn start_params() -> Vec<f64> {
    let cp = ControlPoints {
        x: TanhTf::x(),
        sigma: vec![60.0; K],
        rgb: vec![[0.5, 0.4, 0.6]; K],
    };
    TanhTf.params_for(&cp).unwrap()
}

fn loss_at(f: &Fixture, s: &Settings, plan: &schedule::StepPlan, p: &[f64]) -> f64 {
    optimize::step_gradient(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        s,
        plan,
        p,
        &mut PhaseTimes::default(),
    )
    .unwrap()
    .0
    .total
}

#[test]
fn step_gradient_matches_central_differences_through_every_term() {
    let f = Fixture::new();
    let s = settings();
    // A step after gray_steps and prior_start: augmented backgrounds, prior on, L1/L2 on.
    let plan = schedule::plan(&s, f.pool.len(), 50);
    assert!(plan.prior && !matches!(plan.views[0].background, Background::Gray { .. }));
    let mut p = start_params();
    // Spread the parameters so no term is at a symmetric point.
    let mut r = ChaCha8Rng::seed_from_u64(11);
    for v in p.iter_mut() {
        *v += r.random_range(-0.5..0.5);
    }
    let (log, g) = optimize::step_gradient(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        &plan,
        &p,
        &mut PhaseTimes::default(),
    )
    .unwrap();
    assert!(
        log.prior != 0.0 && log.l1 > 0.0 && log.l2 > 0.0 && log.clip > 0.0,
        "{log:?}"
    );
    // The chain passes through f32 (LUT entries, images and embeddings are f32), so the loss
    // carries rounding noise of ~1e-7 relative, ≈ 2e-7 absolute at a loss of ~2. With
    // h = 1e-3 that is ≤ 2e-7 / 1e-3 = 2e-4 in a difference quotient, and the O(h²)
    // truncation (~1e-6 · |f'''|) stays below it (measured worst: 1.3e-4). The smallest
    // gradients (densities) are ~0.012, so 5e-4 absolute + 0.5 % relative still catches a
    // missing factor of 2 (the view average), the prior weight or a dropped term.
    let h = 1e-3;
    let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(gmax > 0.1, "gradient too small to test: {gmax}");
    for i in 0..p.len() {
        let mut a = p.clone();
        a[i] += h;
        let mut b = p.clone();
        b[i] -= h;
        let fd = (loss_at(&f, &s, &plan, &a) - loss_at(&f, &s, &plan, &b)) / (2.0 * h);
        assert!(
            (fd - g[i]).abs() < 5e-4 + 0.005 * fd.abs(),
            "parameter {i}: analytic {} vs fd {fd}",
            g[i]
        );
    }
}

#[test]
fn loss_decreases_and_run_is_deterministic() {
    let f = Fixture::new();
    let s = settings();
    let stop = AtomicBool::new(false);
    let mut seen = 0;
    let out = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        start_params(),
        &stop,
        &mut |log, total| {
            assert_eq!(log.step, seen);
            assert_eq!(total, 80);
            seen += 1;
        },
    )
    .unwrap();
    assert_eq!(out.steps.len(), 80);
    assert!(!out.interrupted);
    assert!(out
        .steps
        .iter()
        .all(|l| l.total.is_finite() && l.grad_norm.is_finite()));
    // On fixed plans (same views, backgrounds and negatives) the final TF beats the first.
    for step in [0, 20, 60] {
        let plan = schedule::plan(&s, f.pool.len(), step);
        let before = loss_at(&f, &s, &plan, &start_params());
        let after = loss_at(&f, &s, &plan, &out.params);
        assert!(
            after < before - 0.05,
            "step {step} plan: {before} → {after}"
        );
    }
    // The prompt wins the softmax more often at the end than at the start.
    let mean_p = |r: std::ops::Range<usize>| {
        r.clone()
            .map(|i| out.steps[i].prompt_probability)
            .sum::<f64>()
            / r.len() as f64
    };
    assert!(
        mean_p(70..80) > mean_p(0..10),
        "{} vs {}",
        mean_p(0..10),
        mean_p(70..80)
    );
    // Timings were measured.
    assert!(
        out.times.render > 0.0 && out.times.clip_forward > 0.0 && out.times.render_backward > 0.0
    );

    let again = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        start_params(),
        &stop,
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(out.params, again.params, "same seed must give the same TF");
    let other = Settings { seed: 1, ..s };
    let third = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &other,
        start_params(),
        &stop,
        &mut |_, _| {},
    )
    .unwrap();
    assert_ne!(out.params, third.params);
}

#[test]
fn stop_flag_returns_the_last_completed_step() {
    let f = Fixture::new();
    let s = settings();
    let stop = AtomicBool::new(false);
    let out = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        start_params(),
        &stop,
        &mut |log, _| {
            if log.step == 3 {
                stop.store(true, Ordering::Relaxed);
            }
        },
    )
    .unwrap();
    assert!(out.interrupted);
    assert_eq!(out.steps.len(), 4);
    assert_ne!(out.params, start_params());
    assert_eq!(
        out.control_points,
        TanhTf.control_points(&out.params).unwrap()
    );
}

#[test]
fn zero_steps_returns_the_initialization() {
    let f = Fixture::new();
    let s = Settings {
        steps: 0,
        ..settings()
    };
    let out = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        start_params(),
        &AtomicBool::new(false),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(out.params, start_params());
    assert!(out.steps.is_empty() && !out.interrupted);
}

#[test]
fn hard_cases_are_errors_or_finite() {
    let mut f = Fixture::new();
    let calls = f.toy.calls.get();
    let stop = AtomicBool::new(false);
    // Zero negatives: a clear error before any rendering.
    let s0 = Settings {
        negatives_per_step: 0,
        ..settings()
    };
    let t = Targets {
        user_negatives: &[],
        ..f.targets()
    };
    let e = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &t,
        &s0,
        start_params(),
        &stop,
        &mut |_, _| {},
    )
    .unwrap_err();
    assert!(matches!(e, OptimizeError::NoNegatives), "{e}");
    assert_eq!(f.toy.calls.get(), calls);
    // Saturated densities (σ = 255 everywhere, tanh flat): finite steps.
    let sat = TanhTf
        .params_for(&ControlPoints {
            x: TanhTf::x(),
            sigma: vec![255.0; K],
            rgb: vec![[1.0, 0.0, 1.0]; K],
        })
        .unwrap();
    let s = Settings {
        steps: 5,
        ..settings()
    };
    let out = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        sat,
        &stop,
        &mut |_, _| {},
    )
    .unwrap();
    assert!(out.params.iter().all(|p| p.is_finite()));
    assert!(out.steps.iter().all(|l| l.total.is_finite()));
    // A renderer that starts returning NaN: an error naming the problem, never NaN params.
    f.toy.nan_after = Some(f.toy.calls.get() + 4);
    let e = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        start_params(),
        &stop,
        &mut |_, _| {},
    )
    .unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
    // Non-finite starting parameters.
    let mut bad = start_params();
    bad[2] = f64::NAN;
    let e = optimize::optimize(
        &f.toy,
        &f.enc,
        &TanhTf,
        &f.targets(),
        &s,
        bad,
        &stop,
        &mut |_, _| {},
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("initial parameter at index 2"),
        "{e}"
    );
}

#[test]
fn initialization_reaches_rho_on_a_renderer() {
    let f = Fixture::new();
    let s = settings();
    let mut hist = vec![100u64; 256];
    hist[0] = 50_000;
    let (params, found) = optimize::initialize(&f.toy, &TanhTf, &hist, &s).unwrap();
    assert!(found.reached);
    let lut = TanhTf.control_points(&params).unwrap().to_lut(LUT_N);
    let t = optimize::mean_transmittance(&f.toy, &lut, &View::initial(&s)).unwrap();
    // The tanh round trip moves σ by ~1e-9 relative: the measured T stays within the 2 %.
    assert!((t - 0.05).abs() <= 0.02 * 0.05 + 1e-6, "{t}");
    // Colours from the seed, in [0.3, 0.7]; density lowest where the histogram peaks.
    let cp = TanhTf.control_points(&params).unwrap();
    assert!(cp
        .rgb
        .iter()
        .flatten()
        .all(|c| (0.3 - 1e-9..=0.7 + 1e-9).contains(c)));
    assert!(cp.sigma[0] < cp.sigma[2]);
    let (again, _) = optimize::initialize(&f.toy, &TanhTf, &hist, &s).unwrap();
    assert_eq!(params, again);
}

#[test]
fn final_scores_rank_the_target_first() {
    let f = Fixture::new();
    let s = settings();
    let target = ControlPoints {
        x: TanhTf::x(),
        sigma: vec![5.0, 200.0, 20.0, 150.0, 0.0],
        rgb: vec![
            [0.9, 0.1, 0.1],
            [0.8, 0.7, 0.1],
            [0.1, 0.9, 0.2],
            [0.1, 0.2, 0.9],
            [0.5; 3],
        ],
    };
    let views = vec![View {
        yaw: 0.3,
        pitch: 0.0,
        distance: 3.0,
        background: Background::Gray { level: 0.5 },
    }];
    let classes: Vec<&[f32]> = vec![&f.positive, &f.pool[0], &f.user[0]];
    let sc = optimize::scores(
        &f.toy,
        &f.enc,
        &target.to_lut(LUT_N),
        &views,
        &classes,
        100.0,
    )
    .unwrap();
    assert!((sc[0].0 - 1.0).abs() < 1e-6, "{sc:?}");
    assert!((sc[0].1 - 100.0).abs() < 1e-4);
    assert!(sc[1].0 < sc[0].0 && sc[2].0 < sc[0].0);
    let _ = s;
}
