//! The cap on transfer-function files read (`--max-preset-size`), shared by every command
//! that reads one: `convert`, `render --tf` and `optimize --init`.

use crate::formats::DEFAULT_MAX_PRESET_SIZE;

/// How large a transfer-function file may be.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct PresetFileArgs {
    /// Largest transfer-function file read (e.g. 256M); a larger one is refused before it is
    /// read.
    #[arg(
        long,
        value_name = "SIZE",
        value_parser = crate::memory::parse_size,
        // `-5M` reaches the parser, which says a size must be positive.
        allow_hyphen_values = true,
        help = format!(
            "Largest transfer-function file read (e.g. 256M); a larger one is refused before \
             it is read [default: {}M]",
            DEFAULT_MAX_PRESET_SIZE >> 20
        )
    )]
    pub max_preset_size: Option<u64>,
}

impl PresetFileArgs {
    /// The cap in bytes.
    pub fn limit(&self) -> u64 {
        self.max_preset_size.unwrap_or(DEFAULT_MAX_PRESET_SIZE)
    }
}
