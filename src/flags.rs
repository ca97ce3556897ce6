//! The library's errors say what was wrong and name an option in backticks by its field
//! (`dims`, the `ReadOptions` field; Python takes the same keyword); none names a flag or says
//! what a front end offers. Each error gives a [`Hint`] (its kind and option), and here the
//! command line words its advice from it: the option's flag from [`FLAGS`], the command that
//! fetches a model, the budget's flag. Nothing here reads the message's text.

use crate::error::{ErrorKind, Hint};
use crate::optimize::OptimizeError;
use crate::pipeline::PipelineError;

/// The flag that sets each option a hint may name (`t2tf::error::OPTIONS`, tested), with its
/// value's form where that helps; `None` for an option no command has a flag for.
const FLAGS: [(&str, Option<&str>); 34] = [
    ("dims", Some("--dims")),
    ("dtype", Some("--dtype")),
    ("byte_order", Some("--byte-order")),
    ("array", Some("--array")),
    ("model", Some("--model")),
    ("revision", Some("--revision")),
    ("tokenizer", Some("--tokenizer")),
    ("budget", Some("--max-memory")),
    ("threads", Some("--threads")),
    ("level", Some("--level")),
    ("step_size", Some("--step-size")),
    ("render_size", Some("--render-size")),
    ("prompt", Some("--prompt")),
    ("negatives", Some("--negative")),
    ("negatives_file", Some("--negatives-file")),
    ("reference_image", Some("--reference-image")),
    ("init", Some("--init")),
    ("preset", Some("--preset NAME")),
    ("locks", Some("--lock")),
    ("steps", Some("--steps")),
    ("views", Some("--views")),
    ("lr", Some("--lr")),
    ("momentum", Some("--momentum")),
    ("prior_weight", Some("--prior-weight")),
    ("prior_ab", Some("--prior-ab")),
    ("l1", Some("--l1")),
    ("l2", Some("--l2")),
    ("control_points", Some("--control-points")),
    ("rho", None),
    ("pitch_limit", None),
    ("distance", None),
    ("max_preset_size", Some("--max-preset-size SIZE")),
    ("rescale", Some("--rescale MIN,MAX")),
    ("up", Some("--up")),
];

/// The budget's flag, said after any error of the memory budget.
const MEMORY_ADVICE: &str = "set the budget with --max-memory, e.g. --max-memory 16G";

/// The flag of `option`, if the command line has one.
fn flag(option: &str) -> Option<&'static str> {
    FLAGS
        .iter()
        .find(|(o, _)| *o == option)
        .and_then(|(_, f)| *f)
}

/// `message` with the command line's advice for `hint`. `fetching` is true for `t2tf model`,
/// which takes no `--model` folder.
fn advise(message: &str, hint: &Hint, fetching: bool) -> String {
    let flag = hint.option.and_then(flag);
    match &hint.kind {
        ErrorKind::ModelUnavailable { repo, offline } => {
            let or = if *offline { "" } else { "or " };
            let local = if fetching {
                ""
            } else {
                ", or pass --model DIR"
            };
            format!(
                "{message}; {or}run `t2tf model fetch {repo}` on a machine with network and copy \
                 the cache here{local}"
            )
        }
        ErrorKind::Memory { .. } => match flag {
            Some(f) if f != "--max-memory" => format!("{message} ({f}; or {MEMORY_ADVICE})"),
            _ => format!("{message} (or {MEMORY_ADVICE})"),
        },
        _ => match flag {
            Some(f) => format!("{message} ({f})"),
            None => legacy(message, hint),
        },
    }
}

/// Errors that do not yet carry their option (a volume file's, and a job's from
/// `pipeline::Job::validate`) are said as before: the backticked option names of
/// [`LEGACY_FLAGS`] become flags, and a message from the memory budget gets the budget's flag.
fn legacy(message: &str, hint: &Hint) -> String {
    let untold = matches!(hint.kind, ErrorKind::Volume)
        || (hint.kind == ErrorKind::InvalidOption && hint.option.is_none());
    if !untold {
        return message.to_string();
    }
    let mut m = message.to_string();
    for (option, flag) in LEGACY_FLAGS {
        m = m.replace(option, flag);
    }
    if m.contains(" is available for it") {
        m = format!("{m} (or {MEMORY_ADVICE})");
    }
    m
}

/// The options volume files' and jobs' messages name, and their flags ([`legacy`]).
const LEGACY_FLAGS: [(&str, &str); 7] = [
    ("`dims`", "--dims"),
    ("`dtype`", "--dtype"),
    ("`byte_order`", "--byte-order"),
    ("`array`", "--array"),
    ("`level`", "--level"),
    ("`step_size`", "--step-size"),
    ("`render_size`", "--render-size"),
];

/// A library error as the command line says it: the message with the command line's advice,
/// and what `--progress json` reports (the library's message, its hint). Made where the
/// error meets the command line ([`pipeline`], [`volume`], [`optimize`]), so the advice stays
/// with the message wherever it is printed.
#[derive(Debug)]
pub struct Said {
    /// The library's message (with its causes).
    message: String,
    /// Its kind and option.
    hint: Hint,
    /// The message with the advice.
    line: String,
}

impl std::fmt::Display for Said {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.line)
    }
}

impl std::error::Error for Said {}

impl Said {
    fn error(e: &(dyn std::error::Error + 'static), hint: Hint) -> anyhow::Error {
        let message = chain_text(e);
        let line = own_words(e, &hint).unwrap_or_else(|| advise(&message, &hint, false));
        anyhow::Error::new(Said {
            message,
            hint,
            line,
        })
    }
}

/// The command line's own words for an error it says better than the library: a setting by
/// its flag ("invalid setting --views: must be at least 1"), an empty `--prompt`. From the
/// error's variant and fields, never its text.
fn own_words(e: &(dyn std::error::Error + 'static), hint: &Hint) -> Option<String> {
    let optimize = match e.downcast_ref::<PipelineError>() {
        Some(PipelineError::Optimize(o)) => o,
        _ => e.downcast_ref::<OptimizeError>()?,
    };
    match optimize {
        OptimizeError::Setting { name, message } => {
            flag(name).map(|f| format!("invalid setting {f}: {message}"))
        }
        OptimizeError::EmptyPrompt if hint.kind == ErrorKind::EmptyPrompt => {
            Some("--prompt is empty: say what the renderings should show".to_string())
        }
        _ => None,
    }
}

/// `e` and its causes on one line, as `anyhow` prints a chain (`{:#}`).
fn chain_text(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        text = format!("{text}: {c}");
        cause = c.source();
    }
    text
}

/// A pipeline error as the command line says it.
pub fn pipeline(e: PipelineError) -> anyhow::Error {
    Said::error(&e, e.hint())
}

/// An optimizer error as the command line says it.
pub fn optimize(e: OptimizeError) -> anyhow::Error {
    Said::error(&e, e.hint())
}

/// A volume error as the command line says it.
pub fn volume(e: crate::volume::VolumeError) -> anyhow::Error {
    Said::error(&e, crate::hints::volume_hint(&e))
}

/// The hint of one error of a chain, where it is one of the library's.
fn library_hint(e: &(dyn std::error::Error + 'static)) -> Option<Hint> {
    use crate::{camera, clip, formats, fs, hub, image, memory, render, volume};
    macro_rules! first {
        ($($t:ty => $f:expr),* $(,)?) => {
            $(if let Some(e) = e.downcast_ref::<$t>() {
                return Some($f(e));
            })*
        };
    }
    first!(
        PipelineError => PipelineError::hint,
        OptimizeError => OptimizeError::hint,
        volume::VolumeError => crate::hints::volume_hint,
        clip::ClipError => clip::ClipError::hint,
        hub::HubError => hub::HubError::hint,
        formats::FormatError => formats::FormatError::hint,
        render::RenderError => render::RenderError::hint,
        camera::CameraError => camera::CameraError::hint,
        memory::MemoryError => memory::MemoryError::hint,
        image::ImageError => image::ImageError::hint,
        fs::FsError => fs::FsError::hint,
    );
    None
}

/// How a failed command ends: the line people read, and for programs (`--progress json`) the
/// library's message without the command line's advice, its kind and option.
#[derive(Debug)]
pub struct Failure {
    /// One line with the command line's advice (after `t2tf: error: `).
    pub line: String,
    /// The chain's messages as the library and the command said them, without advice.
    pub message: String,
    /// The kind and option of the first error in the chain that tells them.
    pub hint: Hint,
}

/// `err` (an error chain, most general first) as the command line ends with it. `fetching` is
/// true for `t2tf model`, which takes no `--model` folder.
pub fn failure(err: &anyhow::Error, fetching: bool) -> Failure {
    let (mut lines, mut messages) = (Vec::new(), Vec::new());
    let mut hint: Option<Hint> = None;
    let mut advised = false;
    for cause in err.chain() {
        let found = if let Some(said) = cause.downcast_ref::<Said>() {
            lines.push(said.line.clone());
            messages.push(said.message.clone());
            advised = true;
            Some(said.hint.clone())
        } else {
            let text = cause.to_string();
            let hint = library_hint(cause);
            match hint.as_ref().and_then(|h| own_words(cause, h)) {
                Some(words) => {
                    lines.push(words);
                    advised = true;
                }
                None => lines.push(text.clone()),
            }
            messages.push(text);
            hint
        };
        if let Some(h) = found {
            if hint.as_ref().is_none_or(|known| !known.is_specific()) {
                hint = Some(h);
            }
        }
    }
    let hint = hint.unwrap_or_else(Hint::other);
    let mut line = lines.join(": ");
    if !advised {
        line = advise(&line, &hint, fetching);
    }
    Failure {
        line,
        message: messages.join(": "),
        hint,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn said(e: anyhow::Error) -> String {
        failure(&e, false).line
    }

    #[test]
    fn every_option_has_a_row() {
        let rows: Vec<&str> = FLAGS.iter().map(|(o, _)| *o).collect();
        assert_eq!(rows, crate::error::OPTIONS, "FLAGS follows OPTIONS");
    }

    #[test]
    fn settings_get_their_flags_from_the_hint() {
        let e = optimize(OptimizeError::Setting {
            name: "views",
            message: "must be at least 1".into(),
        });
        assert_eq!(said(e), "invalid setting --views: must be at least 1");
        let e = optimize(OptimizeError::Setting {
            name: "rho",
            message: "must be in (0, 1)".into(),
        });
        assert_eq!(said(e), "invalid setting `rho`: must be in (0, 1)");
        let e = failure(&optimize(OptimizeError::EmptyPrompt), false);
        assert!(e.line.starts_with("--prompt is empty"), "{}", e.line);
        assert_eq!(e.hint.kind, ErrorKind::EmptyPrompt);
        // Programs get the library's words, and the kind to word their own from.
        assert_eq!(
            e.message,
            "the prompt is empty: say what the renderings should show"
        );
    }

    #[test]
    fn an_unavailable_model_says_how_to_fetch_it() {
        let hint = Hint::new(ErrorKind::ModelUnavailable {
            repo: "o/n".into(),
            offline: true,
        })
        .about("model");
        let m = advise("x is not cached", &hint, false);
        assert_eq!(
            m,
            "x is not cached; run `t2tf model fetch o/n` on a machine with network and copy the \
             cache here, or pass --model DIR"
        );
        let m = advise("x is not cached", &hint, true);
        assert!(
            m.contains("t2tf model fetch o/n") && !m.contains("--model"),
            "{m}"
        );
    }

    #[test]
    fn no_advice_names_a_repository_path() {
        // Every kind with every option: the advice is the command line's, never a path of
        // the checkout this binary was built from (its test model, its fixtures).
        let kinds = [
            ErrorKind::InvalidOption,
            ErrorKind::ModelUnavailable {
                repo: "o/n".into(),
                offline: true,
            },
            ErrorKind::ModelUnavailable {
                repo: "o/n".into(),
                offline: false,
            },
            ErrorKind::Memory {
                needed: 2,
                available: 1,
            },
            ErrorKind::EmptyPrompt,
            ErrorKind::Volume,
            ErrorKind::Io,
            ErrorKind::Other,
        ];
        let checkout = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let options = crate::error::OPTIONS.iter().map(|o| Some(*o));
        for option in options.chain([None]) {
            for kind in &kinds {
                let hint = Hint {
                    kind: kind.clone(),
                    option,
                };
                for fetching in [false, true] {
                    let m = advise("m", &hint, fetching);
                    for bad in [
                        checkout.display().to_string(),
                        "fixtures".to_string(),
                        "quick_gelu".to_string(),
                        "tokenizer.json".to_string(),
                    ] {
                        assert!(!m.contains(&bad), "{hint:?}: {m}");
                    }
                }
            }
        }
    }

    #[test]
    fn memory_errors_name_the_budget_flag() {
        let m = crate::memory::Budget::bytes(1)
            .check("x", Some(2), 1, "ask for less")
            .unwrap_err();
        let f = failure(&pipeline(PipelineError::Memory(m)), false);
        assert!(
            f.line
                .contains("ask for less (or set the budget with --max-memory"),
            "{}",
            f.line
        );
        assert_eq!(f.hint.kind.name(), "memory");
        assert!(!f.message.contains("--max-memory"), "{}", f.message);
        // Found in a chain too, under the command's own context.
        let m = crate::memory::Budget::bytes(1)
            .check("x", Some(2), 1, "render at a coarser `level`")
            .unwrap_err()
            .about("level");
        let e = anyhow::Error::new(m).context("render");
        assert!(said(e).ends_with(
            "`level` (--level; or set the budget with --max-memory, e.g. --max-memory 16G)"
        ),);
    }

    #[test]
    fn a_chain_is_said_most_general_first_with_its_advice_once() {
        let e = optimize(OptimizeError::Setting {
            name: "steps",
            message: "must be at most 1000000, got 2000000".into(),
        })
        .context("vol.raw");
        let f = failure(&e, false);
        assert_eq!(
            f.line,
            "vol.raw: invalid setting --steps: must be at most 1000000, got 2000000"
        );
        assert_eq!(
            f.message,
            "vol.raw: invalid setting `steps`: must be at most 1000000, got 2000000"
        );
        assert_eq!(f.hint, Hint::invalid("steps"));
        // Commands in backticks that are not options stay as they are.
        let e = anyhow::anyhow!("run `t2tf convert --list`");
        assert_eq!(said(e), "run `t2tf convert --list`");
    }
}
