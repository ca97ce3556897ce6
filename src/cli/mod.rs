//! Command-line interface: one file per subcommand, each with its clap `Args` and a `run`.

mod clip_score;
mod convert;
mod flags;
mod info;
mod model;
mod model_args;
pub mod optimize;
mod progress;
mod render;
mod signals;
mod volume_args;

pub use model_args::ModelArgs;
pub use volume_args::VolumeArgs;

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
    Render(render::RenderArgs),
    /// Print the CLIP similarity of an image to captions.
    ClipScore(clip_score::ClipScoreArgs),
    /// Optimize a transfer function so renderings match a text prompt.
    Optimize(optimize::OptimizeArgs),
    /// Download CLIP models into the Hugging Face cache, or list the cached ones.
    Model(model::ModelArgs),
}

/// The thread pool a command runs in: `--threads` (at most the logical CPUs, with a warning
/// when capped), else rayon's default of one per CPU.
pub fn thread_pool(threads: Option<usize>) -> anyhow::Result<rayon::ThreadPool> {
    let n = match threads {
        Some(t) => {
            let (n, capped) = crate::memory::thread_count(t);
            if capped {
                eprintln!(
                    "t2tf: warning: --threads {t} is more than the {n} logical CPUs; using {n}"
                );
            }
            n
        }
        None => 0,
    };
    use anyhow::Context;
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .context("--threads: cannot start the thread pool")
}

/// Run the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Render(a) => render::run(a),
        Command::ClipScore(a) => clip_score::run(a),
        Command::Optimize(a) => optimize::run(a),
        Command::Model(a) => model::run(a),
    }
}
