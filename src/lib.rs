//! The `t2tf` command line: flag parsing (clap), progress on stderr, signals, and errors said
//! with the flags that fix them, around the library (`t2tf`). One file per subcommand in
//! `commands/`, each with its clap `Args` and a `run`. A library so that the binary
//! (`src/main.rs`) and the Python wheel's `t2tf` command run the same code ([`main`]).
//!
//! The files name library items as `crate::optimize::…`; the imports below make those paths
//! read the library's modules.

// First, so that its `outln!` and `errln!` reach every module below.
#[macro_use]
mod out;

mod commands;
pub mod download_progress;
mod flags;
mod model_args;
mod preset_args;
mod progress;
mod signals;
mod volume_args;

pub use commands::optimize::OptimizeArgs;
pub use model_args::ModelArgs;
pub use preset_args::PresetFileArgs;
pub use volume_args::{SeriesArgs, VolumeArgs};

use commands::{clip_score, convert, info, model};
#[allow(unused_imports)]
use t2tf::{
    background, camera, clip, error, formats, fs, hints, hub, image, memory, optimize, pipeline,
    render, units, volume,
};

use clap::{Parser, Subcommand};

/// Turn a sentence into a volume-rendering transfer function for ParaView and VisIt.
#[derive(Parser, Debug)]
#[command(name = "t2tf", version, about, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

// Parsed once per process: the size gap between subcommands' flag structs costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Print a volume's dimensions, spacing, origin, type, value range and histogram.
    Info(info::InfoArgs),
    /// Convert a transfer function between ParaView JSON, ParaView XML and VisIt .ct.
    Convert(convert::ConvertArgs),
    /// Render a volume with a transfer function to a PNG.
    Render(commands::render::RenderArgs),
    /// Print the CLIP similarity of an image to captions.
    ClipScore(clip_score::ClipScoreArgs),
    /// Optimize a transfer function so renderings match a text prompt.
    Optimize(commands::optimize::OptimizeArgs),
    /// Download CLIP models into the Hugging Face cache, or list the cached ones.
    Model(model::ModelArgs),
    /// List or clear t2tf's cache of caption embeddings.
    Cache(commands::cache::CacheArgs),
}

/// The thread pool a command runs in: `--threads` (at most the logical CPUs, with a warning
/// when capped), else rayon's default of one per CPU.
pub fn thread_pool(threads: Option<usize>) -> anyhow::Result<rayon::ThreadPool> {
    let w = pipeline::workers(threads).map_err(flags::pipeline)?;
    if let Some((t, n)) = w.capped {
        errln!("t2tf: warning: --threads {t} is more than the {n} logical CPUs; using {n}");
    }
    Ok(w.pool)
}

/// The whole program for `args` (the program name first): parse, run, print an error on one
/// line. Returns the exit code.
pub fn main<I, T>(args: I) -> std::process::ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            // --help and --version print and succeed; usage errors print and fail.
            let _ = e.print();
            return std::process::ExitCode::from(e.exit_code().clamp(0, 255) as u8);
        }
    };
    let fetching = matches!(cli.command, Command::Model(_));
    let json =
        matches!(&cli.command, Command::Optimize(a) if a.progress == progress::ProgressMode::Json);
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // `t2tf … | head -1`: the reader has what it wanted (out.rs).
        Err(err) if out::reader_left(&err) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            // One line: the chain of causes joined, most general first, with the advice the
            // command line words from the error's kind and option.
            let failure = flags::failure(&err, fetching);
            errln!("t2tf: error: {}", failure.line);
            if json {
                // Last, for programs: the library's message, its kind and option.
                progress::error(&failure.message, &failure.hint);
            }
            std::process::ExitCode::FAILURE
        }
    }
}

/// Run the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Render(a) => commands::render::run(a),
        Command::ClipScore(a) => clip_score::run(a),
        Command::Optimize(a) => commands::optimize::run(a),
        Command::Model(a) => model::run(a),
        Command::Cache(a) => commands::cache::run(a),
    }
}
