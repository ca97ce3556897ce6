//! `t2tf render` (being written).

/// Placeholder arguments until the command lands.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {}

pub fn run(_args: RenderArgs) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
