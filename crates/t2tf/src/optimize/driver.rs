//! A whole `t2tf optimize` run on top of the loop: text embeddings (pool cached on disk),
//! initialization, Algorithm 1, final CLIP scores and the preview, then the files this module
//! owns (`tf.png`, `preview.png`, `report.json`). The TF exports (`NAME.json`, …) belong to
//! `crate::formats` and are written by the caller.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use super::captions::{self, CacheOutcome, CaptionPool};
use super::init::Initialization;
use super::report::{InitInfo, PhaseTimes, Report, ReportError, Score, StepLog};
use super::{
    initialize, optimize, scores, start_from, BoxError, ImageEncoder, OptimizeError, Outcome,
    Parameterization, Problem, Renderer, Targets, ValidSettings, View,
};
use crate::image::{Image, ImageError};

/// CLIP's text tower as the driver sees it.
pub trait TextEncoder {
    /// Projected (not normalized) embeddings, one per text. Empty texts and texts longer than
    /// the model's context are the encoder's to reject with a clear error.
    fn encode_text(&self, texts: &[&str]) -> Result<Vec<Vec<f32>>, BoxError>;

    /// The run has all its text embeddings: free what the encoder holds for texts (CLIP's
    /// text tower), which the loop never uses.
    fn texts_done(&self) {}
}

/// What the renders should match.
#[derive(Clone, Copy, Debug)]
pub enum Positive<'a> {
    /// A text prompt.
    Prompt(&'a str),
    /// A picture (any size; prepared like CLIP's image processor).
    Image(&'a Image),
}

/// Everything a run needs besides the models.
#[derive(Clone, Copy, Debug)]
pub struct Job<'a> {
    /// The run's settings, checked once where they were made.
    pub settings: &'a ValidSettings,
    /// What the renders should match.
    pub positive: Positive<'a>,
    /// The user's negatives (already defaulted, see `captions::user_negatives`).
    pub user_negatives: &'a [String],
    /// The caption pool negatives are drawn from.
    pub pool: &'a CaptionPool,
    /// Cache directory and model-weights hash for the pool embeddings; `None`: no cache.
    pub cache: Option<(&'a Path, &'a [u8])>,
    /// The volume's histogram (`Volume::histogram`).
    pub histogram: &'a [u64],
    /// CLIP's logit scale.
    pub logit_scale: f64,
    /// Views in preview.png and in the final scores.
    pub preview_views: usize,
    /// Where the loop starts: `None` for the paper's initialization.
    pub start: Option<Start<'a>>,
}

/// A run's given start: its control points (as many as the parameterization has) and, when
/// they came from the paper's initialization, what that found.
#[derive(Clone, Copy, Debug)]
pub struct Start<'a> {
    /// The TF the loop starts from.
    pub control_points: &'a crate::tf::ControlPoints,
    /// The paper's initialization it came from, if it did.
    pub init: Option<&'a Initialization>,
}

/// The models a run drives: the renderer, CLIP's two towers and the TF parameterization.
pub struct Models<'a, R, E, T, P: ?Sized> {
    /// The volume renderer.
    pub renderer: &'a R,
    /// CLIP's image tower.
    pub image_encoder: &'a E,
    /// CLIP's text tower.
    pub text_encoder: &'a T,
    /// The TF parameterization.
    pub tf: &'a P,
}

/// The result of [`run_job`].
#[derive(Clone, Debug)]
pub struct Finished {
    /// What the loop returned.
    pub outcome: Outcome,
    /// What the density initialization found.
    pub init: Initialization,
    /// Positive first (caption "reference image" in image mode), then the user's negatives.
    pub scores: Vec<Score>,
    /// For a time series, `scores` of each step alone (empty for one volume).
    pub time_scores: Vec<Vec<Score>>,
    /// Phases of the whole run (output time is added by [`write_outputs`]).
    pub times: PhaseTimes,
    /// How the pool embeddings were obtained (`None` when no pool negatives are drawn).
    pub cache: Option<CacheOutcome>,
    /// The final TF from `preview_views` orbit views, tiled.
    pub preview: Image,
}

/// All captions in one call: the text tower shares their common beginnings (a prefix tree,
/// `clip::prefix`) and bounds its own activations, so one call is the fastest (6,000 pool
/// captions: 12.4 s of CPU per thread against 13.4 s in 256-caption calls, bench_clip --pool).
fn encode_all<T: TextEncoder>(
    text: &T,
    captions: &[String],
) -> Result<Vec<Vec<f32>>, OptimizeError> {
    let refs: Vec<&str> = captions.iter().map(String::as_str).collect();
    let out = text.encode_text(&refs).map_err(OptimizeError::Encoder)?;
    if out.len() != refs.len() {
        return Err(OptimizeError::Encoder(
            format!(
                "text encoder returned {} embeddings for {} texts",
                out.len(),
                refs.len()
            )
            .into(),
        ));
    }
    Ok(out)
}

/// Run Algorithm 1 for `job`. `progress` sees every step; raising `stop` ends the run after
/// the current step with the TF of that step (`outcome.interrupted`). Zero negatives are
/// the loop's error ([`OptimizeError::NoNegatives`]), raised before the loop's first render.
pub fn run_job<R: Renderer, E: ImageEncoder, T: TextEncoder, P: Parameterization + ?Sized>(
    job: &Job,
    models: &Models<R, E, T, P>,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(&StepLog, usize),
) -> Result<Finished, OptimizeError> {
    let Models {
        renderer,
        image_encoder,
        tf,
        ..
    } = *models;
    let s = job.settings;
    let mut times = PhaseTimes::default();

    let t0 = Instant::now();
    let Embedded {
        positive,
        user,
        pool,
        cache,
    } = embed_targets(job, models)?;
    models.text_encoder.texts_done();
    times.text = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let (params, init) = match job.start {
        None => initialize(renderer, tf, job.histogram, s)?,
        Some(start) => {
            let (params, given) = start_from(renderer, tf, start.control_points, s)?;
            (params, start.init.cloned().unwrap_or(given))
        }
    };
    times.init = t0.elapsed().as_secs_f64();

    let targets = Targets {
        positive: &positive,
        pool: &pool,
        user_negatives: &user,
        logit_scale: job.logit_scale,
    };
    let problem = Problem {
        renderer,
        encoder: image_encoder,
        tf,
        targets,
        settings: s,
    };
    let outcome = optimize(&problem, params, stop, progress)?;
    let lp = &outcome.times;
    times.render = lp.render;
    times.clip_forward = lp.clip_forward;
    times.clip_backward = lp.clip_backward;
    times.render_backward = lp.render_backward;
    times.other = lp.other;

    // Final scores and the preview from the same fixed orbit.
    let t0 = Instant::now();
    let Evaluated {
        scores,
        time_scores,
        preview,
    } = score_and_preview(job, models, &outcome, &positive, &user)?;
    times.other += t0.elapsed().as_secs_f64();

    Ok(Finished {
        outcome,
        init,
        scores,
        time_scores,
        times,
        cache,
        preview,
    })
}

/// The embeddings a run compares its renders against, and how the pool's were obtained.
struct Embedded {
    positive: Vec<f32>,
    user: Vec<Vec<f32>>,
    pool: Vec<Vec<f32>>,
    cache: Option<CacheOutcome>,
}

/// The one rule for a prompt: it must say something (not empty, not only spaces).
pub fn check_prompt(prompt: &str) -> Result<(), OptimizeError> {
    if prompt.trim().is_empty() {
        return Err(OptimizeError::EmptyPrompt);
    }
    Ok(())
}

/// The text side of a run: the positive (prompt or reference image), the user's negatives
/// and the pool (cached on disk when `job.cache` says where).
fn embed_targets<R, E: ImageEncoder, T: TextEncoder, P: ?Sized>(
    job: &Job,
    models: &Models<R, E, T, P>,
) -> Result<Embedded, OptimizeError> {
    let (image_encoder, text_encoder) = (models.image_encoder, models.text_encoder);
    let s = job.settings;
    let positive = match job.positive {
        Positive::Prompt(p) => {
            check_prompt(p)?;
            encode_all(text_encoder, &[p.to_owned()])?.remove(0)
        }
        Positive::Image(im) => {
            let prepared = image_encoder.prepare(im);
            let (mut e, _) = image_encoder
                .encode(&[prepared])
                .map_err(OptimizeError::Encoder)?;
            if e.len() != 1 {
                return Err(OptimizeError::Encoder(
                    "no embedding for the reference image".into(),
                ));
            }
            e.remove(0)
        }
    };
    let user = encode_all(text_encoder, job.user_negatives)?;
    let (pool, cache) = if s.negatives_per_step == 0 || job.pool.is_empty() {
        (Vec::new(), None)
    } else {
        let (dir, hash) = match job.cache {
            Some((d, h)) => (Some(d), h),
            None => (None, &[][..]),
        };
        if job.cache.is_some() {
            let (e, o) = captions::cached_embeddings(dir, hash, job.pool.captions(), |c| {
                encode_all(text_encoder, c)
            })?;
            (e, Some(o))
        } else {
            (encode_all(text_encoder, job.pool.captions())?, None)
        }
    };
    Ok(Embedded {
        positive,
        user,
        pool,
        cache,
    })
}

/// The final TF's CLIP scores (positive first, then the user's negatives) and its preview,
/// from the same `job.preview_views` orbit views.
fn score_and_preview<R: Renderer, E: ImageEncoder, T, P: Parameterization + ?Sized>(
    job: &Job,
    models: &Models<R, E, T, P>,
    outcome: &Outcome,
    positive: &[f32],
    user: &[Vec<f32>],
) -> Result<Evaluated, OptimizeError> {
    let (renderer, image_encoder, tf) = (models.renderer, models.image_encoder, models.tf);
    let lut = outcome.control_points.to_lut(tf.lut_size());
    let orbit = View::orbit(job.settings, job.preview_views.max(1));
    let at = |t: usize| -> Vec<View> {
        orbit
            .iter()
            .map(|v| View {
                time: t,
                ..v.clone()
            })
            .collect()
    };
    let mut classes: Vec<&[f32]> = vec![positive];
    classes.extend(user.iter().map(Vec::as_slice));
    let mut names = vec![match job.positive {
        Positive::Prompt(p) => p.to_owned(),
        Positive::Image(_) => "reference image".to_owned(),
    }];
    names.extend(job.user_negatives.iter().cloned());
    let named = |sc: Vec<(f64, f64)>| -> Vec<Score> {
        names
            .iter()
            .zip(sc)
            .map(|(caption, (cosine, logit))| Score {
                caption: caption.clone(),
                cosine,
                logit,
            })
            .collect()
    };
    // Scores per time step (one for a volume); the run's scores are their mean.
    let times = renderer.time_steps();
    let mut per_time = Vec::with_capacity(times);
    let mut mean = vec![(0.0, 0.0); classes.len()];
    for t in 0..times {
        let mut images = Vec::with_capacity(orbit.len());
        for v in &at(t) {
            images.push(renderer.render(&lut, v).map_err(OptimizeError::Renderer)?.0);
        }
        let sc = scores(image_encoder, &images, &classes, job.logit_scale)?;
        for (m, s) in mean.iter_mut().zip(&sc) {
            m.0 += s.0 / times as f64;
            m.1 += s.1 / times as f64;
        }
        per_time.push(named(sc));
    }
    // One row of the orbit per time step shown (the first, middle and last of a series).
    let shown = super::schedule::preview_times(times);
    let mut pictures = Vec::with_capacity(orbit.len() * shown.len());
    for &t in &shown {
        for v in &at(t) {
            pictures.push(
                renderer
                    .render_preview(&lut, v)
                    .map_err(OptimizeError::Renderer)?,
            );
        }
    }
    let preview = if times == 1 {
        tile(&pictures)
    } else {
        Image::grid(&pictures, orbit.len())
    };
    let overall = if times == 1 {
        per_time.pop().expect("one time step")
    } else {
        named(mean)
    };
    Ok(Evaluated {
        scores: overall,
        time_scores: if times == 1 { Vec::new() } else { per_time },
        preview,
    })
}

/// The final TF's scores and preview ([`score_and_preview`]).
struct Evaluated {
    scores: Vec<Score>,
    time_scores: Vec<Vec<Score>>,
    preview: Image,
}

/// Images side by side in rows of ⌈√n⌉ (see `Image::grid`).
pub(crate) fn tile(images: &[Image]) -> Image {
    let cols = (images.len() as f64).sqrt().ceil() as usize;
    Image::grid(images, cols)
}

impl Finished {
    /// Copy the run's results into `report` (steps, scores, timings, initialization).
    pub fn fill_report(&self, report: &mut Report) {
        report.steps = self.outcome.steps.clone();
        report.steps_run = self.outcome.steps.len();
        report.interrupted = self.outcome.interrupted;
        report.final_scores = self.scores.clone();
        report.timings = self.times.clone();
        report.initialization = InitInfo {
            scale: self.init.scale,
            mean_transmittance: self.init.mean_transmittance,
            evaluations: self.init.evaluations,
            reached: self.init.reached,
        };
    }
}

/// Write `tf.png`, `preview.png` and (last) `report.json` into `dir` (created if missing),
/// each atomically. `report.outputs` gets these names appended (keep the caller's TF files
/// listed before calling) and `timings.output` the time spent here. `curve`: what tf.png
/// plots (opacity for the exported unit distance, so it matches ParaView).
pub fn write_outputs(
    dir: &Path,
    report: &mut Report,
    finished: &Finished,
    histogram: &[u64],
    curve: super::tf_plot::Curve,
    labels: &super::tf_plot::PlotLabels,
) -> Result<(), OutputError> {
    let t0 = Instant::now();
    std::fs::create_dir_all(dir).map_err(|source| OutputError::Folder {
        path: dir.to_path_buf(),
        source,
    })?;
    let cp = &finished.outcome.control_points;
    super::tf_plot::save(&dir.join("tf.png"), cp, histogram, curve, labels)?;
    finished.preview.save_png(&dir.join("preview.png"))?;
    report
        .outputs
        .extend(["tf.png", "preview.png", "report.json"].map(String::from));
    report.timings.output += t0.elapsed().as_secs_f64();
    Ok(report.write(&dir.join("report.json"))?)
}

/// Why [`write_outputs`] could not write the run's files.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The output folder could not be created.
    #[error("{}: cannot create the output folder", path.display())]
    Folder {
        /// The folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// preview.png.
    #[error(transparent)]
    Image(#[from] ImageError),
    /// tf.png.
    #[error(transparent)]
    Plot(#[from] super::tf_plot::PlotError),
    /// report.json.
    #[error(transparent)]
    Report(#[from] ReportError),
}
