//! Flags shared by every command that reads a volume (being written: issue 3).

/// How to read a volume file.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct VolumeArgs {}
