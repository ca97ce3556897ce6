//! The optimizer: the paper's Algorithm 1.
//!
//! The loop is written against three small traits so that it does not depend on how the
//! renderer, CLIP and the TF parameterization are implemented:
//!
//! - [`Renderer`]: LUT + view → (image, T_N per pixel), and the LUT gradient of a loss;
//! - [`ImageEncoder`]: images → CLIP image embeddings, and the input gradient;
//! - [`Parameterization`]: flat parameters ↔ control points, and the parameter gradient.
//!
//! One step (see [`step_gradient`]): plan (views, backgrounds, negatives, prior, lr) → render
//! every view → encode all views in one batch → contrastive loss per view (+ Beta prior) →
//! CLIP backward → renderer backward → + L1/L2 at the control points → parameter gradient,
//! averaged over views → SGD with momentum.

pub mod adapters;
pub mod captions;
pub mod driver;
mod error;
pub(crate) mod init;
pub mod loss;
pub mod recover;
pub mod report;
pub mod schedule;
pub mod series;
pub mod settings;
pub(crate) mod sgd;
pub mod start;
pub mod tf_plot;

use std::cell::RefCell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

pub use error::{
    BoxError, CaptionError, EmbeddingError, InitError, OptimizeError, TransmittanceError,
};
pub use init::Initialization;
pub use report::{PhaseTimes, StepLog};
pub use schedule::{Background, StepPlan, View};
pub use settings::{Settings, ValidSettings};

use crate::image::Image;
use crate::tf::{ControlPoints, Lut, LutGrad};

/// The volume renderer as the loop sees it (the volume and render options live inside).
pub trait Renderer {
    /// What a forward pass keeps for the backward pass of the same view (e.g. the camera and
    /// the forward's result, so the backward need not march the rays twice; `()` if nothing).
    type Tape;

    /// Render `view` with `lut`: the image (the encoder's input size, RGB in [0, 1]), the
    /// final transmittance T_N of each pixel (row-major, H·W), and the tape.
    fn render(&self, lut: &Lut, view: &View) -> Result<(Image, Vec<f32>, Self::Tape), BoxError>;

    /// Gradient of a loss with respect to the LUT, given d loss / d image (H·W·3) and
    /// d loss / d T_N (H·W) of the view `tape` was rendered for, with the same `lut`.
    // Alike `render::Backend::backward`: the optimizer's view of a renderer (a `View`, boxed
    // errors) over the backend's (a prepared level and a `Shot`); adapters.rs binds the two.
    fn backward(
        &self,
        lut: &Lut,
        view: &View,
        tape: &Self::Tape,
        d_image: &[f32],
        d_transmittance: &[f32],
    ) -> Result<LutGrad, BoxError>;

    /// A picture of `view` for people (preview.png): by default the training render, which
    /// is only as large as the encoder's input (32 px for a tiny model).
    fn render_preview(&self, lut: &Lut, view: &View) -> Result<Image, BoxError> {
        Ok(self.render(lut, view)?.0)
    }

    /// Time steps the renderer holds (`View::time` is below it): 1 for one volume.
    fn time_steps(&self) -> usize {
        1
    }
}

/// The view the initialization measures (paper's V0), at the middle time step of a series.
fn initial_view<R: Renderer>(renderer: &R, settings: &Settings) -> View {
    View {
        time: renderer.time_steps() / 2,
        ..View::initial(settings)
    }
}

/// CLIP's image tower as the loop sees it.
pub trait ImageEncoder {
    /// What the forward pass keeps for the backward pass.
    type Cache;

    /// Embeddings of a batch of images: one vector of the projection dimension per image.
    fn encode(&self, images: &[Image]) -> Result<(Vec<Vec<f32>>, Self::Cache), BoxError>;

    /// d loss / d input pixels for each image, given d loss / d embedding.
    fn backward(
        &self,
        cache: &Self::Cache,
        d_embeddings: &[Vec<f32>],
    ) -> Result<Vec<Image>, BoxError>;

    /// An arbitrary picture (`--reference-image`) brought to the encoder's input, as the
    /// model's own image processor does it (CLIP: `Clip::preprocess`).
    fn prepare(&self, picture: &Image) -> Image;
}

/// Gradient of the terms that act on control points directly (L1 and L2).
#[derive(Clone, Debug, PartialEq)]
pub struct PointGrad {
    /// d loss / d σ_k.
    pub sigma: Vec<f64>,
    /// d loss / d rgb_k.
    pub rgb: Vec<[f64; 3]>,
}

/// The TF parameterization as a flat parameter vector (the paper's: spacings, densities,
/// colours through softplus / tanh; see `crate::tf`).
pub trait Parameterization {
    /// Parameters → control points.
    fn control_points(&self, params: &[f64]) -> Result<ControlPoints, BoxError>;

    /// Entries of the LUT handed to the renderer.
    fn lut_size(&self) -> usize;

    /// Parameters whose control points are (as close as the parameterization allows to) `cp`
    /// (the inverse, for the initialization).
    fn params_for(&self, cp: &ControlPoints) -> Result<Vec<f64>, BoxError>;

    /// d loss / d params, from the LUT gradient (through `to_lut(lut_size)`, positions
    /// included) plus the direct gradient at the control points.
    fn backward(
        &self,
        params: &[f64],
        lut_grad: &LutGrad,
        direct: &PointGrad,
    ) -> Result<Vec<f64>, BoxError>;
}

/// What the images are compared against.
#[derive(Clone, Copy, Debug)]
pub struct Targets<'a> {
    /// The positive class, shape \[D\]: the prompt's text embedding, or the image embedding of
    /// `--reference-image`.
    pub positive: &'a [f32],
    /// Embeddings of the caption pool, indexed by `StepPlan::negatives`.
    pub pool: &'a [Vec<f32>],
    /// Embeddings of the user's negatives, used every step.
    pub user_negatives: &'a [Vec<f32>],
    /// CLIP's logit scale (exp of the stored parameter).
    pub logit_scale: f64,
}

impl Targets<'_> {
    /// Positive first, then the plan's pool negatives, then the user's.
    fn classes(&self, negatives: &[usize]) -> Vec<&[f32]> {
        let mut c = Vec::with_capacity(1 + negatives.len() + self.user_negatives.len());
        c.push(self.positive);
        c.extend(negatives.iter().map(|&i| self.pool[i].as_slice()));
        c.extend(self.user_negatives.iter().map(Vec::as_slice));
        c
    }

    /// Zero negatives make the contrastive loss meaningless: say so before any work. The one
    /// place this rule is checked (the CLI always has the default user negative; the driver
    /// reaches it through [`optimize`]).
    fn check(&self, settings: &Settings) -> Result<(), OptimizeError> {
        let from_pool = settings.negatives_per_step.min(self.pool.len());
        if from_pool + self.user_negatives.len() == 0 {
            return Err(OptimizeError::NoNegatives);
        }
        Ok(())
    }
}

/// What a run optimizes and against what: the components and targets every step shares.
pub struct Problem<'a, R, E, P: ?Sized> {
    /// The volume renderer.
    pub renderer: &'a R,
    /// CLIP's image tower.
    pub encoder: &'a E,
    /// The TF parameterization.
    pub tf: &'a P,
    /// The embeddings the renders are compared against.
    pub targets: Targets<'a>,
    /// The run's settings, checked once where they were made.
    pub settings: &'a ValidSettings,
}

/// Loss and gradient of one step at `params`, and the times of its phases (added to `times`).
/// `StepLog::seconds` and `grad_norm` are filled in; `lr` is the plan's.
pub fn step_gradient<R: Renderer, E: ImageEncoder, P: Parameterization + ?Sized>(
    problem: &Problem<R, E, P>,
    plan: &StepPlan,
    params: &[f64],
    times: &mut PhaseTimes,
) -> Result<(StepLog, Vec<f64>), OptimizeError> {
    let Problem {
        renderer,
        encoder,
        tf,
        ref targets,
        settings,
    } = *problem;
    let start = Instant::now();
    let mut clock = Instant::now();
    let mut lap = |slot: &mut f64| {
        let now = Instant::now();
        *slot += (now - clock).as_secs_f64();
        clock = now;
    };
    let cp = tf
        .control_points(params)
        .map_err(OptimizeError::Parameters)?;
    let lut = cp.to_lut(tf.lut_size());
    lap(&mut times.other);

    let (images, trans, tapes) = render_views(renderer, &lut, &plan.views)?;
    lap(&mut times.render);

    let (emb, cache) = encoder.encode(&images).map_err(OptimizeError::Encoder)?;
    same_len(emb.len(), images.len(), || {
        format!(
            "returned {} embeddings for {} images",
            emb.len(),
            images.len()
        )
    })
    .map_err(OptimizeError::Encoder)?;
    lap(&mut times.clip_forward);

    let mut log = StepLog {
        step: plan.step,
        lr: plan.lr,
        ..StepLog::default()
    };
    let (d_emb, d_trans) = view_losses(&emb, &trans, targets, settings, plan, &mut log)?;
    lap(&mut times.other);

    // Each stage's output is checked with `same_len`; the calls read alike, the messages say
    // which stage broke its contract.
    let d_images = encoder
        .backward(&cache, &d_emb)
        .map_err(OptimizeError::Encoder)?;
    same_len(d_images.len(), images.len(), || {
        format!(
            "backward returned {} gradients for {} images",
            d_images.len(),
            images.len()
        )
    })
    .map_err(OptimizeError::Encoder)?;
    for (d, im) in d_images.iter().zip(&images) {
        same_len(d.data.len(), im.data.len(), || {
            format!(
                "backward returned a {}×{} gradient for a {}×{} image",
                d.width, d.height, im.width, im.height
            )
        })
        .map_err(OptimizeError::Encoder)?;
    }
    lap(&mut times.clip_backward);

    let lut_grad = lut_gradient(renderer, &lut, &plan.views, &tapes, &d_images, &d_trans)?;
    lap(&mut times.render_backward);

    let (l1, g1) = loss::density_l1(&cp.sigma, settings.l1);
    let (l2, g2) = loss::colour_l2(&cp.rgb, settings.l2);
    log.l1 = l1;
    log.l2 = l2;
    log.total = log.clip + log.prior + l1 + l2;
    let grad = tf
        .backward(params, &lut_grad, &PointGrad { sigma: g1, rgb: g2 })
        .map_err(OptimizeError::Parameters)?;
    same_len(grad.len(), params.len(), || {
        format!(
            "backward returned {} values for {} parameters",
            grad.len(),
            params.len()
        )
    })
    .map_err(OptimizeError::Parameters)?;
    log.grad_norm = grad.iter().map(|g| g * g).sum::<f64>().sqrt();
    lap(&mut times.other);
    log.seconds = start.elapsed().as_secs_f64();
    Ok((log, grad))
}

/// A component returned `got` items where `want` were due: its error, in its own words.
fn same_len(got: usize, want: usize, what: impl FnOnce() -> String) -> Result<(), BoxError> {
    if got == want {
        Ok(())
    } else {
        Err(what().into())
    }
}

/// Images, transmittances and tapes of every view of a step.
type Renders<T> = (Vec<Image>, Vec<Vec<f32>>, Vec<T>);

fn render_views<R: Renderer>(
    renderer: &R,
    lut: &Lut,
    views: &[View],
) -> Result<Renders<R::Tape>, OptimizeError> {
    let mut out: Renders<R::Tape> = (Vec::new(), Vec::new(), Vec::new());
    for view in views {
        let (im, t, tape) = renderer
            .render(lut, view)
            .map_err(OptimizeError::Renderer)?;
        same_len(t.len(), im.width * im.height, || {
            format!(
                "returned {} transmittances for a {}×{} image",
                t.len(),
                im.width,
                im.height
            )
        })
        .map_err(OptimizeError::Renderer)?;
        out.0.push(im);
        out.1.push(t);
        out.2.push(tape);
    }
    Ok(out)
}

/// d loss / d embedding and d loss / d T_N, per view.
type ViewGrads = (Vec<Vec<f32>>, Vec<Vec<f32>>);

/// The contrastive loss and the Beta prior of each view, averaged over views into `log`.
fn view_losses(
    emb: &[Vec<f32>],
    trans: &[Vec<f32>],
    targets: &Targets,
    settings: &Settings,
    plan: &StepPlan,
    log: &mut StepLog,
) -> Result<ViewGrads, OptimizeError> {
    let classes = targets.classes(&plan.negatives);
    let v = plan.views.len() as f64;
    let mut d_emb = Vec::with_capacity(emb.len());
    let mut d_trans = Vec::with_capacity(emb.len());
    for (e, t) in emb.iter().zip(trans) {
        let c = loss::contrastive(e, &classes, targets.logit_scale)?;
        log.clip += c.loss / v;
        log.prompt_probability += (c.logits[0] - logsumexp(&c.logits)).exp() / v;
        d_emb.push(c.d_image.iter().map(|g| (g / v) as f32).collect());
        log.mean_transmittance +=
            t.iter().map(|&x| x as f64).sum::<f64>() / t.len().max(1) as f64 / v;
        if plan.prior && settings.prior_weight > 0.0 {
            let (p, g) = loss::beta_prior(t, settings.prior_a, settings.prior_b)?;
            log.prior += settings.prior_weight * p / v;
            d_trans.push(
                g.iter()
                    .map(|g| (settings.prior_weight * g / v) as f32)
                    .collect(),
            );
        } else {
            d_trans.push(vec![0.0f32; t.len()]);
        }
    }
    Ok((d_emb, d_trans))
}

/// The renderer's backward of every view, summed into one LUT gradient.
fn lut_gradient<R: Renderer>(
    renderer: &R,
    lut: &Lut,
    views: &[View],
    tapes: &[R::Tape],
    d_images: &[Image],
    d_trans: &[Vec<f32>],
) -> Result<LutGrad, OptimizeError> {
    let mut lut_grad = LutGrad::zeros(lut.entries.len());
    for (((view, tape), di), dt) in views.iter().zip(tapes).zip(d_images).zip(d_trans) {
        let g = renderer
            .backward(lut, view, tape, &di.data, dt)
            .map_err(OptimizeError::Renderer)?;
        same_len(g.entries.len(), lut.entries.len(), || {
            format!(
                "backward returned {} LUT entries, expected {}",
                g.entries.len(),
                lut.entries.len()
            )
        })
        .map_err(OptimizeError::Renderer)?;
        lut_grad.add(&g);
    }
    Ok(lut_grad)
}

fn logsumexp(l: &[f64]) -> f64 {
    let m = l.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    m + l.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

/// The result of [`optimize`].
#[derive(Clone, Debug)]
pub struct Outcome {
    /// Parameters after the last completed step.
    pub params: Vec<f64>,
    /// The TF of those parameters.
    pub control_points: ControlPoints,
    /// One log per completed step.
    pub steps: Vec<StepLog>,
    /// Time per phase of the loop.
    pub times: PhaseTimes,
    /// True when `stop` was raised before all steps ran.
    pub interrupted: bool,
}

/// Run `settings.steps` steps of Algorithm 1 from `params`.
///
/// `pool_size`-independent: negatives index `targets.pool`. `progress` is called after every
/// step with its log and the total step count. `stop` is checked before each step: when it
/// is raised (Ctrl-C), the loop returns the TF of the last completed step with
/// `interrupted = true`. A non-finite gradient or parameter is an error (nothing is skipped).
pub fn optimize<R: Renderer, E: ImageEncoder, P: Parameterization + ?Sized>(
    problem: &Problem<R, E, P>,
    mut params: Vec<f64>,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(&StepLog, usize),
) -> Result<Outcome, OptimizeError> {
    let (tf, targets, settings) = (problem.tf, &problem.targets, problem.settings);
    targets.check(settings)?;
    if let Some(i) = params.iter().position(|p| !p.is_finite()) {
        return Err(OptimizeError::NonFinite {
            what: "initial parameter",
            index: i,
            step: 0,
        });
    }
    let mut sgd = sgd::Sgd::new(params.len(), settings.momentum)?;
    let mut times = PhaseTimes::default();
    // Grows with the steps run, never sized by the step count alone.
    let mut steps = Vec::new();
    let mut interrupted = false;
    for step in 0..settings.steps {
        if stop.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        let mut plan = schedule::plan(settings, targets.pool.len(), step);
        schedule::assign_times(&mut plan, problem.renderer.time_steps(), settings.seed);
        let (log, grad) = step_gradient(problem, &plan, &params, &mut times)?;
        if !log.total.is_finite() {
            return Err(OptimizeError::NonFinite {
                what: "loss",
                index: 0,
                step,
            });
        }
        let t = Instant::now();
        sgd.update(&mut params, &grad, plan.lr)
            .map_err(|e| match e {
                OptimizeError::NonFinite { what, index, .. } => {
                    OptimizeError::NonFinite { what, index, step }
                }
                e => e,
            })?;
        times.other += t.elapsed().as_secs_f64();
        progress(&log, settings.steps);
        steps.push(log);
    }
    let control_points = tf
        .control_points(&params)
        .map_err(OptimizeError::Parameters)?;
    Ok(Outcome {
        params,
        control_points,
        steps,
        times,
        interrupted,
    })
}

/// Mean T_N of `view` over the pixels where `mask` is true (all pixels without a mask).
pub fn mean_transmittance<R: Renderer>(
    renderer: &R,
    lut: &Lut,
    view: &View,
    mask: Option<&[bool]>,
) -> Result<f64, OptimizeError> {
    let (_, t, _) = renderer
        .render(lut, view)
        .map_err(OptimizeError::Renderer)?;
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, &x) in t.iter().enumerate() {
        if mask.is_none_or(|m| m.get(i).copied().unwrap_or(false)) {
            sum += x as f64;
            n += 1;
        }
    }
    if n == 0 {
        return Err(OptimizeError::Renderer(
            "rendered an image without pixels".into(),
        ));
    }
    Ok(sum / n as f64)
}

/// A ray counts as seeing the volume when σ = 255 everywhere leaves it below this T.
/// One sample step through σ = 255 gives T = exp(−255 δ/L) ≤ 0.78 even for a 1024-voxel box at
/// half-voxel steps, so only rays that miss the box (or cross nothing but NaN voxels) stay
/// above.
const HIT_T: f32 = 0.999;

/// The paper's initialization on a renderer: evenly spaced control points, colours from the
/// seed, densities from `histogram` scaled so the mean T_N of [`View::initial`] is ρ; returns
/// the parameters and what the search found.
///
/// The mean is over the rays of V0 that see the volume (T < `HIT_T` = 0.999 with σ = 255
/// everywhere), not over the whole frame: at the paper's distances the box fills only part of
/// a 45° view, and rays that miss it keep T = 1 whatever the TF, so over all rays ρ = 0.05
/// would be unreachable for most volumes (measured: 0.68 at best for the 41³ nucleon at 3
/// radii) and the search would saturate every density.
pub fn initialize<R: Renderer, P: Parameterization + ?Sized>(
    renderer: &R,
    tf: &P,
    histogram: &[u64],
    settings: &ValidSettings,
) -> Result<(Vec<f64>, init::Initialization), OptimizeError> {
    use rand::SeedableRng;
    let k = settings.control_points;
    let x: Vec<f64> = (0..k).map(|i| i as f64 / (k - 1) as f64).collect();
    // The colours get their own stream so they do not shift when the schedule changes.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed);
    rng.set_stream(u64::MAX);
    let view = initial_view(renderer, settings);
    let dense = ControlPoints {
        x: x.clone(),
        sigma: vec![255.0; k],
        rgb: vec![[0.5; 3]; k],
    };
    let (_, t, _) = renderer
        .render(&dense.to_lut(tf.lut_size()), &view)
        .map_err(OptimizeError::Renderer)?;
    let mask: Vec<bool> = t.iter().map(|&v| v < HIT_T).collect();
    if !mask.contains(&true) {
        return Err(InitError::NoRayHits.into());
    }
    let failure: RefCell<Option<OptimizeError>> = RefCell::new(None);
    let result =
        init::initialize(
            &x,
            histogram,
            settings.rho,
            &mut rng,
            |cp| match mean_transmittance(renderer, &cp.to_lut(tf.lut_size()), &view, Some(&mask)) {
                Ok(t) => t,
                Err(e) => {
                    failure.borrow_mut().get_or_insert(e);
                    f64::NAN
                }
            },
        );
    if let Some(e) = failure.into_inner() {
        return Err(e);
    }
    let found = result?;
    let params = tf
        .params_for(&found.control_points)
        .map_err(OptimizeError::Parameters)?;
    Ok((params, found))
}

/// Start from the given control points instead of the paper's initialization: their
/// parameters, and what [`initialize`] would report (mean T_N of V0 measured once).
pub fn start_from<R: Renderer, P: Parameterization + ?Sized>(
    renderer: &R,
    tf: &P,
    cp: &ControlPoints,
    settings: &ValidSettings,
) -> Result<(Vec<f64>, init::Initialization), OptimizeError> {
    let params = tf.params_for(cp).map_err(OptimizeError::Parameters)?;
    let lut = cp.to_lut(tf.lut_size());
    let mean = mean_transmittance(renderer, &lut, &initial_view(renderer, settings), None)?;
    let found = init::Initialization {
        control_points: cp.clone(),
        scale: 1.0,
        mean_transmittance: mean,
        evaluations: 1,
        reached: true,
    };
    Ok((params, found))
}

/// Mean cosine similarity (and logit) over `images` with each class: the final CLIP scores
/// of `report.json`.
pub fn scores<E: ImageEncoder>(
    encoder: &E,
    images: &[Image],
    classes: &[&[f32]],
    logit_scale: f64,
) -> Result<Vec<(f64, f64)>, OptimizeError> {
    let (emb, _) = encoder.encode(images).map_err(OptimizeError::Encoder)?;
    let mut out = vec![(0.0, 0.0); classes.len()];
    let n = emb.len().max(1) as f64;
    for e in &emb {
        for (k, c) in classes.iter().enumerate() {
            let cos = loss::cosine(e, c)?;
            out[k].0 += cos / n;
            out[k].1 += logit_scale * cos / n;
        }
    }
    Ok(out)
}
