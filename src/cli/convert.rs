//! `t2tf convert` (being written).

/// Placeholder arguments until the command lands.
#[derive(clap::Args, Debug)]
pub struct ConvertArgs {}

pub fn run(_args: ConvertArgs) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
