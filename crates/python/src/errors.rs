//! The library's errors as Python exceptions: `t2tf.Error` and one subclass per kind of
//! problem, each with the library's one-line message and, as attributes, what the library's
//! `Hint` says of it: `kind` (`"invalid_option"`, `"model_unavailable"`, `"memory"`,
//! `"empty_prompt"`, `"volume"`, `"io"`, `"other"`) and `option` (the library's name of the
//! option concerned, or None), the values the command's `--progress json` error line gives.
//! Python words its own advice from them, with keyword names (`model=DIR`, `max_memory`),
//! never by editing the library's text.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::PyTypeInfo;

use t2tf::error::{ErrorKind, Hint};
use t2tf::optimize::OptimizeError;
use t2tf::pipeline::PipelineError;

create_exception!(t2tf, Error, PyException, "Base class of every t2tf error.");
create_exception!(
    t2tf,
    VolumeError,
    Error,
    "A volume that cannot be read or used."
);
create_exception!(
    t2tf,
    ModelError,
    Error,
    "A CLIP model that cannot be found or loaded."
);
create_exception!(
    t2tf,
    SettingsError,
    Error,
    "A setting out of its valid range."
);
create_exception!(
    t2tf,
    FormatError,
    Error,
    "A transfer-function file that cannot be read or written."
);
create_exception!(
    t2tf,
    RenderError,
    Error,
    "A picture that cannot be rendered."
);
create_exception!(
    t2tf,
    OutputError,
    Error,
    "Output files that cannot be written."
);
create_exception!(
    t2tf,
    BudgetError,
    Error,
    "Something that does not fit the memory budget."
);

/// Each class's `kind` where an instance does not set its own (errors this module raises
/// itself).
const CLASS_KINDS: [(&str, &str); 8] = [
    ("Error", "other"),
    ("VolumeError", "volume"),
    ("ModelError", "other"),
    ("SettingsError", "invalid_option"),
    ("FormatError", "other"),
    ("RenderError", "other"),
    ("OutputError", "io"),
    ("BudgetError", "memory"),
];

/// Add the exception classes to the module, each with its default `kind` and `option` None.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("VolumeError", py.get_type::<VolumeError>())?;
    m.add("ModelError", py.get_type::<ModelError>())?;
    m.add("SettingsError", py.get_type::<SettingsError>())?;
    m.add("FormatError", py.get_type::<FormatError>())?;
    m.add("RenderError", py.get_type::<RenderError>())?;
    m.add("OutputError", py.get_type::<OutputError>())?;
    m.add("BudgetError", py.get_type::<BudgetError>())?;
    for (class, kind) in CLASS_KINDS {
        let class = m.getattr(class)?;
        class.setattr("kind", kind)?;
        class.setattr("option", py.None())?;
    }
    Ok(())
}

/// An error's message with its causes, as the CLI prints it: "a: b: c", a cause left out
/// where the message already says it.
pub fn message(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let more = c.to_string();
        if !text.contains(&more) {
            text = format!("{text}: {more}");
        }
        cause = c.source();
    }
    text
}

/// An exception of class `T` for an error of the library: its message with Python's advice,
/// and its kind and option as attributes.
fn raise<T: PyTypeInfo>(e: &(dyn std::error::Error + 'static), hint: Hint) -> PyErr {
    with_hint::<T>(advise(message(e), &hint), &hint)
}

/// An exception of class `T` saying `text`, with `hint`'s kind and option as attributes.
fn with_hint<T: PyTypeInfo>(text: String, hint: &Hint) -> PyErr {
    Python::attach(|py| {
        let err = PyErr::new::<T, _>(text);
        let value = err.value(py);
        // Setting an attribute on a fresh exception cannot fail but for memory; the class's
        // defaults then stand.
        let _ = value.setattr("kind", hint.kind.name());
        let _ = value.setattr("option", hint.option);
        err
    })
}

/// The keyword of each option whose keyword is not its library name.
const KEYWORDS: [(&str, &str); 2] = [("budget", "max_memory"), ("locks", "lock")];

/// The Python keyword for the option the library calls `option`.
pub fn keyword(option: &'static str) -> &'static str {
    KEYWORDS
        .iter()
        .find(|(o, _)| *o == option)
        .map_or(option, |(_, k)| k)
}

/// `text` with Python's advice for `hint`: keywords, never flags; nothing where the message
/// already names the keyword (options are named by the names Python takes).
fn advise(text: String, hint: &Hint) -> String {
    match &hint.kind {
        ErrorKind::ModelUnavailable { repo, offline } => format!(
            "{text}; {}fetch {repo} on a machine with network (`t2tf model fetch {repo}`) and \
             copy the cache here, or pass model=DIR, a local model folder",
            if *offline { "" } else { "or " }
        ),
        ErrorKind::Memory { .. } => {
            format!(
                "{text} (or pass a larger max_memory where the call takes one, e.g. \
                     max_memory=\"16G\")"
            )
        }
        _ => match hint.option {
            Some(o) if keyword(o) != o => format!("{text} (keyword {})", keyword(o)),
            _ => text,
        },
    }
}

/// A pipeline error as the Python exception of its kind.
pub fn pipeline(e: PipelineError) -> PyErr {
    let hint = e.hint();
    match e {
        PipelineError::Volume(v) => volume(v),
        PipelineError::Clip(c) => raise::<ModelError>(&c, hint),
        PipelineError::Memory(m) => raise::<BudgetError>(&m, hint),
        PipelineError::Optimize(o) => optimize(o),
        PipelineError::Job(j) => with_hint::<SettingsError>(j, &hint),
        PipelineError::Image(i) => raise::<SettingsError>(&i, hint),
        PipelineError::Camera(c) => raise::<RenderError>(&c, hint),
        PipelineError::Format(f) => format(f),
        e @ (PipelineError::Output(_) | PipelineError::Fs(_)) => raise::<OutputError>(&e, hint),
        #[allow(unreachable_patterns)]
        e => raise::<Error>(&e, hint),
    }
}

/// A volume error as a `VolumeError`.
pub fn volume(e: t2tf::volume::VolumeError) -> PyErr {
    raise::<VolumeError>(&e, t2tf::hints::volume_hint(&e))
}

/// A `VolumeError` saying `text` about `option` (a keyword of `read_volume`).
pub fn volume_option(text: impl Into<String>, option: &'static str) -> PyErr {
    with_hint::<VolumeError>(text.into(), &Hint::invalid(option))
}

/// A TF file's error: one that could not be read is a `FormatError`, a failed write of an
/// output (a full disk, a folder that refuses files) an `OutputError`.
pub fn format(e: t2tf::formats::FormatError) -> PyErr {
    let hint = e.hint();
    match e {
        t2tf::formats::FormatError::Output(_) => raise::<OutputError>(&e, hint),
        e => raise::<FormatError>(&e, hint),
    }
}

/// An optimizer error: settings (named as the keywords spell them) and the prompt are a
/// `SettingsError`.
pub fn optimize(e: OptimizeError) -> PyErr {
    let hint = e.hint();
    match e {
        OptimizeError::Setting { .. } | OptimizeError::EmptyPrompt => {
            raise::<SettingsError>(&e, hint)
        }
        other => raise::<Error>(&other, hint),
    }
}

/// A render error (a camera, a view) as a `RenderError`.
pub fn render(e: &(dyn std::error::Error + 'static), hint: Hint) -> PyErr {
    raise::<RenderError>(e, hint)
}

/// A settings error with `text`.
pub fn settings(text: impl Into<String>) -> PyErr {
    SettingsError::new_err(text.into())
}
