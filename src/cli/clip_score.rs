//! `t2tf clip-score` (being written).

/// Placeholder arguments until the command lands.
#[derive(clap::Args, Debug)]
pub struct ClipScoreArgs {}

pub fn run(_args: ClipScoreArgs) -> anyhow::Result<()> {
    anyhow::bail!("this command is not implemented yet")
}
