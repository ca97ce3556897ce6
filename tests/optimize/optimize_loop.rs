//! The optimization loop end to end on analytic stand-ins for the renderer, CLIP and the TF
//! parameterization (the real ones are tested in their own modules; this proves the plumbing:
//! gradient flow through every term, averaging over views, SGD, schedule, stop flag,
//! determinism, errors instead of NaN).

use crate::optimize_toy;

use std::sync::atomic::{AtomicBool, Ordering};

use optimize_toy::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use t2tf::optimize::{
    self, schedule, Background, OptimizeError, Outcome, Parameterization, PhaseTimes, Problem,
    Renderer, Settings, Targets, ValidSettings, View,
};
use t2tf::tf::ControlPoints;

/// The toy problem: the fixture's renderer and encoder, the tanh TF, `targets` and `s`.
fn problem<'a>(
    f: &'a Fixture,
    targets: Targets<'a>,
    s: &'a ValidSettings,
) -> Problem<'a, Toy, LinearEncoder, TanhTf> {
    Problem {
        renderer: &f.toy,
        encoder: &f.enc,
        tf: &TanhTf,
        targets,
        settings: s,
    }
}

/// `optimize::optimize` on the toy problem with the fixture's targets, without progress.
fn run(
    f: &Fixture,
    s: &ValidSettings,
    start: Vec<f64>,
    stop: &AtomicBool,
) -> Result<Outcome, OptimizeError> {
    optimize::optimize(&problem(f, f.targets(), s), start, stop, &mut |_, _| {})
}

fn loss_at(f: &Fixture, s: &ValidSettings, plan: &schedule::StepPlan, p: &[f64]) -> f64 {
    optimize::step_gradient(
        &problem(f, f.targets(), s),
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
    let s = settings().validate().unwrap();
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
        &problem(&f, f.targets(), &s),
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
    let s = settings().validate().unwrap();
    let stop = AtomicBool::new(false);
    let mut seen = 0;
    let out = optimize::optimize(
        &problem(&f, f.targets(), &s),
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

    let again = run(&f, &s, start_params(), &stop).unwrap();
    assert_eq!(out.params, again.params, "same seed must give the same TF");
    let other = Settings {
        seed: 1,
        ..settings()
    }
    .validate()
    .unwrap();
    let third = run(&f, &other, start_params(), &stop).unwrap();
    assert_ne!(out.params, third.params);
}

#[test]
fn stop_flag_returns_the_last_completed_step() {
    let f = Fixture::new();
    let s = settings().validate().unwrap();
    let stop = AtomicBool::new(false);
    let out = optimize::optimize(
        &problem(&f, f.targets(), &s),
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
    }
    .validate()
    .unwrap();
    let out = run(&f, &s, start_params(), &AtomicBool::new(false)).unwrap();
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
    }
    .validate()
    .unwrap();
    let t = Targets {
        user_negatives: &[],
        ..f.targets()
    };
    let e = optimize::optimize(&problem(&f, t, &s0), start_params(), &stop, &mut |_, _| {})
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
    }
    .validate()
    .unwrap();
    let out = run(&f, &s, sat, &stop).unwrap();
    assert!(out.params.iter().all(|p| p.is_finite()));
    assert!(out.steps.iter().all(|l| l.total.is_finite()));
    // A renderer that starts returning NaN: an error naming the problem, never NaN params.
    f.toy.nan_after = Some(f.toy.calls.get() + 4);
    let e = run(&f, &s, start_params(), &stop).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
    // Non-finite starting parameters.
    let mut bad = start_params();
    bad[2] = f64::NAN;
    let e = run(&f, &s, bad, &stop).unwrap_err();
    assert!(
        e.to_string().contains("initial parameter at index 2"),
        "{e}"
    );
}

#[test]
fn initialization_reaches_rho_on_a_renderer() {
    let f = Fixture::new();
    let s = settings().validate().unwrap();
    let hist = histogram();
    let (params, found) = optimize::initialize(&f.toy, &TanhTf, &hist, &s).unwrap();
    assert!(found.reached);
    let lut = TanhTf.control_points(&params).unwrap().to_lut(LUT_N);
    let t = optimize::mean_transmittance(&f.toy, &lut, &View::initial(&s), None).unwrap();
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
    let (target, views) = (target(), [target_view()]);
    let classes: Vec<&[f32]> = vec![&f.positive, &f.pool[0], &f.user[0]];
    let images: Vec<_> = views
        .iter()
        .map(|v| f.toy.render(&target.to_lut(LUT_N), v).unwrap().0)
        .collect();
    let sc = optimize::scores(&f.enc, &images, &classes, 100.0).unwrap();
    assert!((sc[0].0 - 1.0).abs() < 1e-6, "{sc:?}");
    assert!((sc[0].1 - 100.0).abs() < 1e-4);
    assert!(sc[1].0 < sc[0].0 && sc[2].0 < sc[0].0);
}

/// The toy with the first half of the pixels outside the volume: T = 1, image = background.
struct HalfMissing(Toy);

impl Renderer for HalfMissing {
    type Tape = ();

    fn render(
        &self,
        lut: &t2tf::tf::Lut,
        view: &View,
    ) -> Result<(t2tf::image::Image, Vec<f32>, ()), optimize::BoxError> {
        let (mut im, mut t, _) = self.0.render(lut, view)?;
        let bg = Toy::background(view);
        for p in 0..NPIX / 2 {
            t[p] = 1.0;
            for c in 0..3 {
                im.data[p * 3 + c] = bg[p * 3 + c] as f32;
            }
        }
        Ok((im, t, ()))
    }

    fn backward(
        &self,
        _: &t2tf::tf::Lut,
        _: &View,
        _: &(),
        _: &[f32],
        _: &[f32],
    ) -> Result<t2tf::tf::LutGrad, optimize::BoxError> {
        unreachable!("initialization renders forward only")
    }
}

#[test]
fn initialization_averages_over_rays_that_see_the_volume() {
    let r = HalfMissing(Toy::new(1));
    let s = settings().validate().unwrap();
    let (params, found) = optimize::initialize(&r, &TanhTf, &[10u64; 256], &s).unwrap();
    assert!(found.reached, "{found:?}");
    let lut = TanhTf.control_points(&params).unwrap().to_lut(LUT_N);
    let v0 = View::initial(&s);
    let all = optimize::mean_transmittance(&r, &lut, &v0, None).unwrap();
    let mask: Vec<bool> = (0..NPIX).map(|p| p >= NPIX / 2).collect();
    let hit = optimize::mean_transmittance(&r, &lut, &v0, Some(&mask)).unwrap();
    assert!((hit - 0.05).abs() <= 0.02 * 0.05 + 1e-6, "{hit}");
    // Over the whole frame the same TF reads (1 + 0.05) / 2: ρ would have been unreachable.
    assert!((all - (1.0 + hit) / 2.0).abs() < 1e-6, "{all}");
    // A view in which nothing is visible is a clear error. (`Blind` is shaped like
    // `HalfMissing` above: both are forward-only renderers for the initialization.)
    struct Blind;
    impl Renderer for Blind {
        type Tape = ();
        fn render(
            &self,
            _: &t2tf::tf::Lut,
            _: &View,
        ) -> Result<(t2tf::image::Image, Vec<f32>, ()), optimize::BoxError> {
            Ok((t2tf::image::Image::new(2, 2), vec![1.0; 4], ()))
        }
        fn backward(
            &self,
            _: &t2tf::tf::Lut,
            _: &View,
            _: &(),
            _: &[f32],
            _: &[f32],
        ) -> Result<t2tf::tf::LutGrad, optimize::BoxError> {
            unreachable!()
        }
    }
    let e = optimize::initialize(&Blind, &TanhTf, &[10u64; 256], &s).unwrap_err();
    assert!(e.to_string().contains("sees the volume"), "{e}");
}
