//! `t2tf optimize` (being written).

/// Placeholder arguments until the command lands.
#[derive(clap::Args, Debug)]
pub struct OptimizeArgs {}

pub fn run(_args: OptimizeArgs) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
