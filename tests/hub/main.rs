//! Integration tests: the Hugging Face Hub client and the CLI's downloads, against a stand-in Hub.
//!
//! One test binary per area (`cargo test --release --test hub`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

#[path = "../hub_server/mod.rs"]
mod hub_server;

mod clip_hub;
mod hub;
mod hub_hostile;
