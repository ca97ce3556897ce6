//! A whole run through `optimize::driver` on the analytic stand-ins: text embeddings and
//! their cache, initialization, the loop, final scores, preview, and the files written.

use crate::optimize_toy;

use std::path::Path;
use std::sync::atomic::AtomicBool;

use optimize_toy::*;
use t2tf::image::Image;
use t2tf::optimize::captions::{CacheOutcome, CaptionPool};
use t2tf::optimize::driver::{self, Finished, Job, Models, Positive};
use t2tf::optimize::report::Report;
use t2tf::optimize::tf_plot::{Curve, PlotLabels};
use t2tf::optimize::{OptimizeError, Renderer, Settings};

const PROMPT: &str = "a red and yellow thing";

fn text(f: &Fixture, captions: &CaptionPool) -> ToyText {
    let mut known = vec![
        (PROMPT.to_string(), f.positive.clone()),
        ("a blank image".to_string(), f.user[0].clone()),
    ];
    known.extend(
        captions
            .captions()
            .iter()
            .cloned()
            .zip(f.pool.iter().cloned()),
    );
    ToyText {
        known,
        calls: 0.into(),
        texts: 0.into(),
    }
}

fn pool() -> CaptionPool {
    CaptionPool::parse(
        &(0..40)
            .map(|i| format!("caption {i}\n"))
            .collect::<String>(),
    )
}

/// What every driver test starts from: the toy fixture, a pool of 40 captions, a text
/// encoder that knows them, the prompt and the user's negative, and a histogram with one
/// large empty bin.
struct Setup {
    f: Fixture,
    p: CaptionPool,
    t: ToyText,
    user: Vec<String>,
    hist: Vec<u64>,
}

impl Setup {
    fn new() -> Setup {
        let f = Fixture::new();
        let p = pool();
        let t = text(&f, &p);
        Setup {
            f,
            p,
            t,
            user: vec!["a blank image".to_string()],
            hist: histogram(),
        }
    }

    /// A run with the setup's user negative and histogram.
    fn run(
        &self,
        s: &Settings,
        positive: Positive,
        cache: Option<(&Path, &[u8])>,
    ) -> Result<Finished, OptimizeError> {
        self.run_with(s, positive, &self.user, cache, &self.hist)
    }

    /// A run through `driver::run_job` with these user negatives and this histogram.
    fn run_with(
        &self,
        s: &Settings,
        positive: Positive,
        user: &[String],
        cache: Option<(&Path, &[u8])>,
        hist: &[u64],
    ) -> Result<Finished, OptimizeError> {
        let s = s.validate()?;
        let job = Job {
            settings: &s,
            positive,
            user_negatives: user,
            pool: &self.p,
            cache,
            histogram: hist,
            logit_scale: 100.0,
            preview_views: 4,
            start: None,
        };
        let models = Models {
            renderer: &self.f.toy,
            image_encoder: &self.f.enc,
            text_encoder: &self.t,
            tf: &TanhTf,
        };
        driver::run_job(&job, &models, &AtomicBool::new(false), &mut |_, _| {})
    }
}

#[test]
fn full_run_writes_every_output_and_caches_the_pool() {
    let setup = Setup::new();
    let (f, t, hist) = (&setup.f, &setup.t, &setup.hist);
    let s = settings();
    let cache = tempfile::tempdir().unwrap();
    let key: &[u8] = b"toy weights";

    let zero = Settings {
        steps: 0,
        ..s.clone()
    };
    let before = setup.run(&zero, Positive::Prompt(PROMPT), None).unwrap();
    let done = setup
        .run(&s, Positive::Prompt(PROMPT), Some((cache.path(), key)))
        .unwrap();
    assert!(
        matches!(done.cache, Some(CacheOutcome::Stored(_))),
        "{:?}",
        done.cache
    );
    assert_eq!(done.outcome.steps.len(), s.steps);
    assert!(done.init.reached);
    // On the fixed orbit views the prompt's logit pulled ahead of the user negative's.
    let margin = |r: &Finished| r.scores[0].logit - r.scores[1].logit;
    assert_eq!(done.scores[0].caption, PROMPT);
    assert_eq!(done.scores[1].caption, "a blank image");
    // At the start the blank image wins (its flat render is closer to everything); at the
    // end the prompt does (measured: −0.36 → +0.77 logits).
    let (m0, m1) = (margin(&before), margin(&done));
    assert!(m0 < 0.0 && m1 > 0.0 && m1 > m0 + 0.5, "{m0} → {m1}");
    let d0 = &done.scores[0];
    assert!((d0.logit - 100.0 * d0.cosine).abs() < 1e-9);

    // Second run: the pool comes from the cache; only prompt and user negative are encoded.
    let texts_before = t.texts.get();
    let again = setup
        .run(&s, Positive::Prompt(PROMPT), Some((cache.path(), key)))
        .unwrap();
    assert!(
        matches!(again.cache, Some(CacheOutcome::Hit(_))),
        "{:?}",
        again.cache
    );
    assert_eq!(t.texts.get() - texts_before, 2);
    assert_eq!(
        again.outcome.params, done.outcome.params,
        "same seed, same TF"
    );

    // Outputs.
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("run");
    let mut report = Report::new(s.clone());
    report.prompt = Some(PROMPT.into());
    report.outputs.push("a-red-and-yellow-thing.json".into());
    done.fill_report(&mut report);
    let curve = Curve::Opacity {
        unit_over_length: 0.01,
    };
    let labels = PlotLabels {
        title: PROMPT.into(),
        data_range: [0.0, 255.0],
    };
    driver::write_outputs(&dir, &mut report, &done, hist, curve, &labels).unwrap();
    let tf = Image::load_png(&dir.join("tf.png")).unwrap();
    assert_eq!((tf.width, tf.height), (720, 420));
    let preview = Image::load_png(&dir.join("preview.png")).unwrap();
    assert_eq!((preview.width, preview.height), (2 * SIDE, 2 * SIDE));
    // The preview's first tile is the first orbit view's render of the final TF.
    let lut = done.outcome.control_points.to_lut(LUT_N);
    let v0 = &t2tf::optimize::View::orbit(&s, 4)[0];
    let (im, _, _) = f.toy.render(&lut, v0).unwrap();
    for y in 0..SIDE {
        for x in 0..SIDE {
            let (a, b) = (im.pixel(x, y), preview.pixel(x, y));
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 0.5 / 255.0 + 1e-6);
            }
        }
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["steps"].as_array().unwrap().len(), s.steps);
    assert_eq!(json["steps_run"], s.steps);
    assert_eq!(json["interrupted"], false);
    assert_eq!(json["final_scores"][0]["caption"], PROMPT);
    assert_eq!(json["settings"]["negatives_per_step"], 8);
    assert!(json["initialization"]["reached"].as_bool().unwrap());
    assert!(json["timings"]["render"].as_f64().unwrap() > 0.0);
    assert!(json["timings"]["output"].as_f64().unwrap() > 0.0);
    let outputs: Vec<&str> = json["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(
        outputs,
        [
            "a-red-and-yellow-thing.json",
            "tf.png",
            "preview.png",
            "report.json"
        ]
    );
    let first = json["steps"][0]["total"].as_f64().unwrap();
    assert!(first.is_finite());
    // No partial files left behind.
    for e in std::fs::read_dir(&dir).unwrap() {
        let n = e.unwrap().file_name().into_string().unwrap();
        assert!(!n.ends_with(".partial"), "{n}");
    }
}

#[test]
fn reference_image_mode_moves_towards_the_picture() {
    let setup = Setup::new();
    let (f, t) = (&setup.f, &setup.t);
    let s = settings();
    // The target's render at twice the size (a user's picture is larger than CLIP's input):
    // the driver has the encoder prepare it (the toy's box filter undoes the doubling).
    let (small, _, _) = f
        .toy
        .render(&target().to_lut(LUT_N), &target_view())
        .unwrap();
    let mut picture = Image::new(2 * SIDE, 2 * SIDE);
    for y in 0..2 * SIDE {
        for x in 0..2 * SIDE {
            picture.set_pixel(x, y, small.pixel(x / 2, y / 2));
        }
    }
    let zero = Settings {
        steps: 0,
        ..s.clone()
    };
    let before = setup.run(&zero, Positive::Image(&picture), None).unwrap();
    let done = setup.run(&s, Positive::Image(&picture), None).unwrap();
    assert_eq!(done.scores[0].caption, "reference image");
    let margin = |r: &Finished| r.scores[0].logit - r.scores[1].logit;
    // At the start the blank image wins (its flat render is closer to everything); at the
    // end the prompt does (measured: −0.36 → +0.77 logits).
    let (m0, m1) = (margin(&before), margin(&done));
    assert!(m0 < 0.0 && m1 > 0.0 && m1 > m0 + 0.5, "{m0} → {m1}");
    // The prompt text is never encoded in this mode.
    assert!(t.known.iter().any(|(k, _)| k == PROMPT));
}

#[test]
fn hard_cases() {
    let setup = Setup::new();
    let s = settings();
    // Empty prompt.
    let e = setup.run(&s, Positive::Prompt("  "), None).unwrap_err();
    assert!(e.to_string().contains("prompt is empty"), "{e}");
    // Zero negatives: no pool draws and no user negatives.
    let s0 = Settings {
        negatives_per_step: 0,
        ..s.clone()
    };
    let e = setup
        .run_with(&s0, Positive::Prompt(PROMPT), &[], None, &setup.hist)
        .unwrap_err();
    assert!(matches!(e, OptimizeError::NoNegatives), "{e}");
    // An empty user negative reaches the text encoder's error, named as the encoder's.
    let e = setup
        .run_with(
            &s,
            Positive::Prompt(PROMPT),
            &[String::new()],
            None,
            &setup.hist,
        )
        .unwrap_err();
    assert!(
        e.to_string().contains("image encoder") || e.to_string().contains("empty"),
        "{e}"
    );
    // A constant volume (every voxel in one bin) and a volume with NaN voxels (they are not in
    // the histogram) both initialize and run to finite results.
    let mut one = vec![0u64; 256];
    one[128] = 4096;
    let short = Settings {
        steps: 10,
        ..s.clone()
    };
    let r = setup
        .run_with(&short, Positive::Prompt(PROMPT), &setup.user, None, &one)
        .unwrap();
    assert!(r.outcome.params.iter().all(|x| x.is_finite()));
    assert!(r.scores.iter().all(|sc| sc.cosine.is_finite()));
    // An empty histogram (all voxels NaN never gets this far, but the driver must not panic).
    let e = setup
        .run_with(
            &short,
            Positive::Prompt(PROMPT),
            &setup.user,
            None,
            &[0; 256],
        )
        .unwrap_err();
    assert!(e.to_string().contains("histogram"), "{e}");
    // Steps = 0: the initialization, scored and previewed.
    let z = setup
        .run(&Settings { steps: 0, ..s }, Positive::Prompt(PROMPT), None)
        .unwrap();
    assert!(z.outcome.steps.is_empty());
    assert_eq!((z.preview.width, z.preview.height), (2 * SIDE, 2 * SIDE));
}
