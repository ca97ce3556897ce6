//! Progress of long work on stderr, in the form the reader can use: a bar on a terminal, a plain
//! line every few seconds in a log or a pipe (batch jobs), or one JSON object per line for
//! programs (the ParaView plugin) with `--progress json`.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// How progress is shown (`--progress`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ProgressMode {
    /// A bar on a terminal, plain lines otherwise.
    Auto,
    /// A bar that redraws in place.
    Bar,
    /// One plain line every few seconds.
    Lines,
    /// One JSON object per line, every step.
    Json,
    /// Nothing.
    None,
}

impl ProgressMode {
    /// `Auto` made concrete for this process's stderr.
    pub fn resolve(self) -> ProgressMode {
        match self {
            ProgressMode::Auto if std::io::stderr().is_terminal() => ProgressMode::Bar,
            ProgressMode::Auto => ProgressMode::Lines,
            m => m,
        }
    }
}

/// One step's numbers.
#[derive(Clone, Debug, Default)]
pub struct StepReport {
    /// Total loss of the step.
    pub loss: f64,
    /// Its contrastive (CLIP) term.
    pub clip: f64,
    /// Softmax probability of the prompt among prompt and negatives.
    pub prompt_probability: f64,
}

/// Progress of a counted task (optimization steps).
pub struct Progress {
    mode: ProgressMode,
    total: usize,
    done: usize,
    start: Instant,
    /// When the first step ended: the ETA uses the rate after it, so one-off work before the
    /// first step (caption embeddings) does not inflate it.
    first_step: Option<Instant>,
    last_line: Option<Instant>,
    bar: Option<indicatif::ProgressBar>,
}

/// Seconds between plain lines.
const LINE_EVERY: Duration = Duration::from_secs(5);

/// The first step whose progress shows an estimate: the first step carries one-off work
/// (caption embeddings, the first touch of the volume), so the rate comes from the steps after
/// it, and one such step alone is too noisy to predict from.
const ETA_FROM_STEP: usize = 3;

/// Seconds left, from the time since the first step ended (`since_first`) over the steps
/// finished since then; `None` before [`ETA_FROM_STEP`].
fn eta(done: usize, total: usize, since_first: f64) -> Option<f64> {
    (done >= ETA_FROM_STEP.max(2))
        .then(|| since_first / (done - 1) as f64 * total.saturating_sub(done) as f64)
}

/// An estimate for a person: "ETA 42 s", or "ETA …" while there is none yet.
fn eta_text(eta: Option<f64>) -> String {
    eta.map_or("ETA …".to_string(), |s| format!("ETA {s:.0} s"))
}

impl Progress {
    /// Start counting `total` steps.
    pub fn new(mode: ProgressMode, total: usize) -> Progress {
        let mode = mode.resolve();
        let bar = (mode == ProgressMode::Bar).then(|| {
            let bar = indicatif::ProgressBar::new(total as u64);
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] step {pos}/{len}  {msg}",
            ) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar
        });
        Progress {
            mode,
            total,
            done: 0,
            start: Instant::now(),
            first_step: None,
            last_line: None,
            bar,
        }
    }

    /// A phase of the work begins (loading, embedding captions, writing): said once, not as
    /// a bar.
    pub fn phase(&self, what: &str) {
        match self.mode {
            ProgressMode::Json => emit(&serde_json::json!({ "event": "phase", "phase": what })),
            ProgressMode::Lines => errln!("t2tf: {what}"),
            _ => {}
        }
    }

    /// One more step is done.
    pub fn step(&mut self, r: &StepReport) {
        self.done += 1;
        let elapsed = self.start.elapsed().as_secs_f64();
        let first = *self.first_step.get_or_insert_with(Instant::now);
        let eta = eta(self.done, self.total, first.elapsed().as_secs_f64());
        match self.mode {
            ProgressMode::Bar => {
                if let Some(bar) = &self.bar {
                    bar.set_message(format!(
                        "loss {:.4} (clip {:.4}, p(prompt) {:.3})  {}",
                        r.loss,
                        r.clip,
                        r.prompt_probability,
                        eta_text(eta)
                    ));
                    bar.inc(1);
                }
            }
            ProgressMode::Lines => {
                let due = self.last_line.is_none_or(|t| t.elapsed() >= LINE_EVERY);
                if due || self.done == self.total {
                    self.last_line = Some(Instant::now());
                    errln!(
                        "t2tf: step {}/{}  loss {:.4}  p(prompt) {:.3}  elapsed {:.0} s  {}",
                        self.done,
                        self.total,
                        r.loss,
                        r.prompt_probability,
                        elapsed,
                        eta_text(eta)
                    );
                }
            }
            ProgressMode::Json => emit(&serde_json::json!({
                "event": "step",
                "step": self.done,
                "steps": self.total,
                "loss": finite(r.loss),
                "clip": finite(r.clip),
                "p_prompt": finite(r.prompt_probability),
                "elapsed_s": elapsed,
                // null until there is an estimate (ETA_FROM_STEP).
                "eta_s": eta.and_then(finite),
            })),
            ProgressMode::Auto | ProgressMode::None => {}
        }
    }

    /// Print with the bar (if any) cleared first and redrawn after.
    pub fn suspend(&self, print: impl FnOnce()) {
        match &self.bar {
            Some(bar) => bar.suspend(print),
            None => print(),
        }
    }

    /// The task ended (finished or stopped): clear the bar.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }

    /// The work's result, for `--progress json` readers: where the files went.
    pub fn done(&self, out: &std::path::Path, files: &[String], interrupted: bool) {
        if self.mode == ProgressMode::Json {
            emit(&serde_json::json!({
                "event": "done",
                "out": out.display().to_string(),
                "files": files,
                "interrupted": interrupted,
            }));
        }
    }
}

/// A failed command's last line for `--progress json` readers: `{"event": "error", "message",
/// "kind", "option"}`, the library's message without the command line's advice, the kind of
/// problem in snake case (`t2tf::error::ErrorKind::name`) and the option it is about by its
/// library field name (`dims`), or null.
pub fn error(message: &str, hint: &crate::error::Hint) {
    errln!("{}", error_event(message, hint));
}

/// The error line, its keys in the order documented (a `json!` object sorts them).
fn error_event(message: &str, hint: &crate::error::Hint) -> String {
    let json = |v: serde_json::Value| v.to_string();
    format!(
        r#"{{"event":"error","message":{},"kind":{},"option":{}}}"#,
        json(message.into()),
        json(hint.kind.name().into()),
        json(hint.option.into())
    )
}

/// JSON has no NaN: a non-finite number is written as null.
fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// One line, written whole, so lines from threads never interleave.
fn emit(v: &serde_json::Value) {
    errln!("{v}");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_is_lines_without_a_terminal() {
        // Test harnesses capture stderr, so it is not a terminal here.
        if !std::io::stderr().is_terminal() {
            assert_eq!(ProgressMode::Auto.resolve(), ProgressMode::Lines);
        }
        assert_eq!(ProgressMode::Json.resolve(), ProgressMode::Json);
        assert_eq!(finite(f64::NAN), None);
    }

    #[test]
    fn the_error_event_has_kind_and_option() {
        let hint = crate::error::Hint::invalid("dims");
        assert_eq!(
            error_event("a.bin: give `dims`", &hint),
            r#"{"event":"error","message":"a.bin: give `dims`","kind":"invalid_option","option":"dims"}"#
        );
        let other: serde_json::Value =
            serde_json::from_str(&error_event("\"x\"\n", &crate::error::Hint::other())).unwrap();
        assert_eq!(other["message"], "\"x\"\n");
        assert_eq!(other["kind"], "other");
        assert_eq!(other["option"], serde_json::Value::Null);
    }

    #[test]
    fn no_estimate_before_the_third_step() {
        assert_eq!(eta(1, 100, 0.0), None);
        assert_eq!(eta(2, 100, 1.0), None);
        // Two steps in 4 s since the first ended: 2 s a step, 97 steps left.
        assert_eq!(eta(3, 100, 4.0), Some(194.0));
        assert_eq!(eta(100, 100, 50.0), Some(0.0));
        assert_eq!(eta_text(None), "ETA …");
        assert_eq!(eta_text(Some(193.6)), "ETA 194 s");
    }
}
