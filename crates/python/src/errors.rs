//! The library's errors as Python exceptions: `t2tf.Error` and one subclass per kind of
//! problem, each with the library's one-line message.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

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

/// Add the exception classes to the module.
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

/// A pipeline error as the Python exception of its kind.
pub fn pipeline(e: PipelineError) -> PyErr {
    match e {
        PipelineError::Volume(v) => VolumeError::new_err(message(&v)),
        PipelineError::Clip(c) => ModelError::new_err(model_hint(message(&c))),
        PipelineError::Memory(m) => BudgetError::new_err(message(&m)),
        PipelineError::Optimize(o) => optimize(o),
        PipelineError::Job(j) => SettingsError::new_err(j),
        PipelineError::Image(i) => SettingsError::new_err(message(&i)),
        PipelineError::Camera(c) => RenderError::new_err(message(&c)),
        PipelineError::Format(f) => format(f),
        e @ (PipelineError::Output(_) | PipelineError::Fs(_)) => OutputError::new_err(message(&e)),
    }
}

/// The library's advice for a model the cache lacks ("or use a local `model` folder"), as
/// Python says it: the keyword, and where this wheel's checkout still has them, the
/// repository's test model and tokenizer by absolute path (every stage runs offline with them;
/// its TFs mean nothing).
fn model_hint(text: String) -> String {
    const LOCAL_MODEL: &str = "or use a local `model` folder";
    if !text.contains(LOCAL_MODEL) {
        return text;
    }
    // Cargo gives the manifest's folder (crates/python) as an absolute path.
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let model = repo.join("tests/fixtures/clip/quick_gelu");
    let tokenizer = repo.join("../shared/data/clip/tokenizer.json");
    let hint = match (
        t2tf::platform::canonicalize(&model),
        t2tf::platform::canonicalize(&tokenizer),
    ) {
        (Ok(m), Ok(t)) if m.is_dir() && t.is_file() => format!(
            "or pass model=DIR, a local model folder (offline, the repository's test model \
             runs every stage: model={:?}, tokenizer={:?})",
            m.display().to_string(),
            t.display().to_string()
        ),
        _ => "or pass model=DIR, a local model folder".to_string(),
    };
    text.replace(LOCAL_MODEL, &hint)
}

/// A TF file's error: one that could not be read is a `FormatError`, a failed write of an
/// output (a full disk, a folder that refuses files) an `OutputError`.
pub fn format(e: t2tf::formats::FormatError) -> PyErr {
    match e {
        t2tf::formats::FormatError::Output(_) => OutputError::new_err(message(&e)),
        e => FormatError::new_err(message(&e)),
    }
}

/// An optimizer error: settings are named as the Python keywords spell them.
pub fn optimize(e: OptimizeError) -> PyErr {
    match e {
        OptimizeError::Setting { name, message } => SettingsError::new_err(format!(
            "invalid setting {}: {message}",
            name.replace('-', "_")
        )),
        OptimizeError::EmptyPrompt => {
            SettingsError::new_err("the prompt is empty: say what the renderings should show")
        }
        other => Error::new_err(message(&other)),
    }
}

/// A settings error with `text`.
pub fn settings(text: impl Into<String>) -> PyErr {
    SettingsError::new_err(text.into())
}
