//! `t2tf cache`: the caption-embedding cache that makes every run after the first start fast
//! (`$XDG_CACHE_HOME/t2tf`, else `~/.cache/t2tf`): `list` its files by the model each belongs
//! to, with their sizes, `clear` them. Models live in the Hugging Face cache instead (`t2tf
//! model list`).

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::clip::{ModelRequest, DEFAULT_REVISION};
use crate::hub::{cached_repos, CachedRepo, HubSettings, RepoKind};
use crate::optimize::captions::{
    cache_dir, cache_entries, cache_key, clear_cache, hash_files, model_key, CacheEntry,
    CaptionPool,
};
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
    /// List the cached caption embeddings: the model each belongs to (a Hugging Face cache
    /// model by repo and revision), its size, and the total.
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

/// What `list` says of a file whose model is not a cached Hub model.
const UNKNOWN: &str = "(a model folder, or a run with its own --tokenizer or --negatives-file)";

/// The caption-cache file names (their keys, in hex) of the built-in negative pool under every
/// CLIP model of the Hugging Face cache, each with the model as `list` names it: `REPO@REV`,
/// the revisions that point to the commit, else its first 8 digits; `(bf16)` for a run in
/// bf16. A run keys its file by the model's weights, tokenizer and config
/// (`pipeline::Model`), which a snapshot of the Hub cache holds like a model folder.
/// A Hub cache that cannot be read, or a snapshot whose files cannot, names no model: the
/// listing of t2tf's own cache goes on.
fn hub_models() -> Vec<(String, String)> {
    let settings = HubSettings::from_env();
    let pool = CaptionPool::builtin();
    let mut keys = Vec::new();
    for repo in cached_repos(&settings.cache_dir).unwrap_or_default() {
        if repo.kind != RepoKind::Model || !crate::commands::model::is_clip(&repo) {
            continue;
        }
        for snapshot in &repo.snapshots {
            let folder = repo.path.join("snapshots").join(&snapshot.commit);
            let request = ModelRequest {
                model: folder.to_string_lossy().into_owned(),
                revision: DEFAULT_REVISION.to_string(),
                tokenizer: None,
                hub: settings.clone(),
            };
            // A snapshot without every file a run needs was never a run's model.
            let Ok(files) = crate::clip::load::resolve(&request) else {
                continue;
            };
            let Some(weights) =
                blob_sha256(&files.weights).or_else(|| hash_files(&files.weights).ok())
            else {
                continue;
            };
            let Ok(f32_key) = model_key(&weights, &[files.tokenizer.clone(), files.config.clone()])
            else {
                continue;
            };
            // As `pipeline::Model` keys a run in another precision than f32.
            let bf16_key: [u8; 32] = {
                use sha2::Digest;
                let mut h = sha2::Sha256::new();
                h.update(f32_key);
                h.update(" precision=bf16");
                h.finalize().into()
            };
            let label = format!("{}@{}", repo.repo_id, revisions(&repo, &snapshot.commit));
            for (key, suffix) in [(f32_key, ""), (bf16_key, " (bf16)")] {
                keys.push((
                    hex(&cache_key(&key, pool.captions())),
                    format!("{label}{suffix}"),
                ));
            }
        }
    }
    keys
}

/// The revisions (branches, tags) of `repo` pointing to `commit`, else the commit's first 8
/// digits.
fn revisions(repo: &CachedRepo, commit: &str) -> String {
    let names: Vec<&str> = repo
        .refs
        .iter()
        .filter(|(_, c)| c.as_str() == commit)
        .map(|(name, _)| name.as_str())
        .collect();
    if names.is_empty() {
        commit[..commit.len().min(8)].to_string()
    } else {
        names.join(",")
    }
}

/// The SHA-256 of a single weights file from the name of the Hub cache's blob it links to
/// (the file's LFS id, checked when it was downloaded), so that listing does not read
/// hundreds of megabytes; `None` where it is not such a link.
fn blob_sha256(weights: &[PathBuf]) -> Option<[u8; 32]> {
    let [file] = weights else {
        return None;
    };
    let target = std::fs::read_link(file).ok()?;
    let name = target.file_name()?.to_str()?;
    if name.len() != 64 {
        return None;
    }
    let mut hash = [0u8; 32];
    for (i, byte) in hash.iter_mut().enumerate() {
        *byte = u8::from_str_radix(name.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(hash)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub fn run(args: CacheArgs) -> Result<()> {
    let dir = folder()?;
    match args.action {
        CacheAction::List => {
            let entries = cache_entries(&dir)?;
            let owners = if entries.is_empty() {
                Vec::new()
            } else {
                hub_models()
            };
            for e in &entries {
                let stem = e.path.file_stem().unwrap_or_default().to_string_lossy();
                let model = owners
                    .iter()
                    .find(|(key, _)| *key == stem)
                    .map_or(UNKNOWN, |(_, label)| label.as_str());
                outln!(
                    "{model}  {:>10}  {} captions × {}",
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
