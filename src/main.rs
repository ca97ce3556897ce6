//! The `t2tf` binary: parse flags, call into the library, print errors on one line.

use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = t2tf::cli::Cli::parse();
    match t2tf::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            // One line: the chain of causes joined, most general first.
            eprintln!("t2tf: error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
