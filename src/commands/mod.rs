//! One module per subcommand: its clap `Args` and its `run`.

pub mod cache;
pub mod clip_score;
pub mod convert;
pub mod info;
pub mod model;
pub mod optimize;
pub mod render;
