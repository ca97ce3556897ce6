//! `t2tf cache`: the caption-embedding cache that makes every run after the first start fast
//! (`$XDG_CACHE_HOME/t2tf`, else `~/.cache/t2tf`): `list` its files with their sizes, `clear`
//! them. Models live in the Hugging Face cache instead (`t2tf model list`).

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::optimize::captions::{cache_dir, cache_entries, clear_cache, CacheEntry};
use crate::units::human_bytes;

/// List or clear t2tf's cache of caption embeddings.
#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    t2tf cache list\n  \
    t2tf cache clear\n\n\
    The cache is $XDG_CACHE_HOME/t2tf, else ~/.cache/t2tf. It holds the text embeddings of \
    the negative captions per model, so a run after the first skips computing them; a \
    cleared cache is rebuilt by the next run. Models are in the Hugging Face cache \
    (t2tf model list).")]
pub struct CacheArgs {
    #[command(subcommand)]
    pub action: CacheAction,
}

#[derive(clap::Subcommand, Debug)]
pub enum CacheAction {
    /// List the cached caption embeddings with their sizes, and the total.
    #[command(after_help = "Example:\n  t2tf cache list")]
    List,
    /// Remove t2tf's cached caption embeddings (other files in the folder are kept).
    #[command(after_help = "Example:\n  t2tf cache clear")]
    Clear,
}

/// The cache folder, or why there is none.
fn folder() -> Result<PathBuf> {
    cache_dir().context("no cache folder: XDG_CACHE_HOME is not set and the system names no home folder for this user")
}

fn total(entries: &[CacheEntry]) -> String {
    let bytes: u64 = entries.iter().map(|e| e.bytes).sum();
    let files = if entries.len() == 1 { "file" } else { "files" };
    format!("{} {files}, {}", entries.len(), human_bytes(bytes.into()))
}

pub fn run(args: CacheArgs) -> Result<()> {
    let dir = folder()?;
    match args.action {
        CacheAction::List => {
            let entries = cache_entries(&dir)?;
            for e in &entries {
                let name = e.path.file_name().unwrap_or_default().to_string_lossy();
                outln!(
                    "{name}  {:>10}  {} captions × {}",
                    human_bytes(e.bytes.into()),
                    e.captions,
                    e.dim
                )?;
            }
            outln!("total: {} in {}", total(&entries), dir.display())?;
        }
        CacheAction::Clear => {
            let removed = clear_cache(&dir)?;
            outln!("removed {} from {}", total(&removed), dir.display())?;
        }
    }
    Ok(())
}
