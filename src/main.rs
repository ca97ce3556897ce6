//! The `t2tf` binary: parse flags, call into the library, print errors on one line.
//!
//! The command-line interface (`cli`) belongs to the binary, not to the library's API. Its
//! files name library items as `crate::optimize::…`; the imports below make those paths
//! read the library's modules.

mod cli;

use clap::Parser;
use t2tf::{
    background, camera, clip, formats, fs, hub, image, memory, optimize, pipeline, render, units,
    volume,
};

fn main() -> std::process::ExitCode {
    let cli = cli::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            // One line: the chain of causes joined, most general first.
            eprintln!("t2tf: error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
