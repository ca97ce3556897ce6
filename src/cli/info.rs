//! `t2tf info` (being written).

/// Placeholder arguments until the command lands.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {}

pub fn run(_args: InfoArgs) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
