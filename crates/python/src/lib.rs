//! `t2tf._t2tf`: the Python module around the t2tf library. Volumes come in as NumPy
//! arrays (read in place where their layout allows) or files; transfer functions, previews
//! and renders go out as NumPy arrays; `run::optimize` runs the pipeline with the GIL
//! released; `cli_main` is the `t2tf` command itself (`t2tf_cli::main`), so the wheel's
//! `t2tf` script and the Rust binary are one program.
//!
//! The Python package (`python/t2tf`) re-exports these names with their docs; the type
//! stubs are `python/t2tf/_t2tf.pyi`.

mod errors;
mod events;
mod result;
mod run;
mod series;
mod tf;
mod volume;

use std::ffi::OsString;
use std::process::ExitCode;

use pyo3::prelude::*;

/// Run the `t2tf` command line on `argv` (program name first) and return its exit status.
/// The GIL is released while it runs; an `optimize` run's report.json records `argv`.
#[pyfunction]
#[pyo3(text_signature = "(argv)")]
fn cli_main(py: Python<'_>, argv: Vec<OsString>) -> u8 {
    let code = py.detach(|| {
        t2tf_cli::OptimizeArgs::set_command_line(Some(argv.clone()));
        let code = t2tf_cli::main(argv);
        t2tf_cli::OptimizeArgs::set_command_line(None);
        code
    });
    exit_status(code)
}

/// The number behind an `ExitCode` (std keeps it private; the CLI returns 0 to 255).
fn exit_status(code: ExitCode) -> u8 {
    (0..=u8::MAX)
        .find(|&n| ExitCode::from(n) == code)
        .unwrap_or(1)
}

#[pymodule]
fn _t2tf(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::register(m)?;
    m.add_class::<volume::PyVolume>()?;
    m.add_class::<series::PySeries>()?;
    m.add_class::<tf::PyTransferFunction>()?;
    m.add_class::<run::PyModel>()?;
    m.add_class::<result::OptimizeResult>()?;
    m.add_function(wrap_pyfunction!(volume::read_volume, m)?)?;
    m.add_function(wrap_pyfunction!(series::read_series, m)?)?;
    m.add_function(wrap_pyfunction!(tf::render, m)?)?;
    m.add_function(wrap_pyfunction!(run::load_model, m)?)?;
    m.add_function(wrap_pyfunction!(run::optimize, m)?)?;
    m.add_function(wrap_pyfunction!(cli_main, m)?)?;
    m.add("DEFAULT_MODEL", t2tf::clip::DEFAULT_MODEL)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
