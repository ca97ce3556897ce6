//! The `t2tf` binary: the command line of `t2tf_cli` on this process's arguments.

fn main() -> std::process::ExitCode {
    t2tf_cli::main(std::env::args_os())
}
