//! `t2tf model`: download a CLIP model into the Hugging Face cache (`fetch`), and list the CLIP
//! models already there (`list`). For clusters: fetch on a login node, run with
//! `HF_HUB_OFFLINE=1` on compute nodes that share the cache.

use anyhow::{bail, Context, Result};

use crate::clip::load::{looks_like_repo_id, resolve_with, WEIGHT_FILES};
use crate::clip::openclip::{CONFIG as OPEN_CLIP_CONFIG, WEIGHT_FILES as OPEN_CLIP_WEIGHT_FILES};
use crate::clip::{ModelRequest, DEFAULT_MODEL, DEFAULT_REVISION};
use crate::hub::{cached_repos, CachedRepo, Hub, HubSettings, RepoKind};
use crate::units::human_bytes;

/// Download or list CLIP models in the Hugging Face cache.
#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    t2tf model fetch\n  \
    t2tf model fetch laion/CLIP-ViT-H-14-laion2B-s32B-b79K\n  \
    t2tf model list\n\n\
    On a cluster: fetch on a login node, then run with HF_HUB_OFFLINE=1 on compute nodes \
    that share the cache.")]
pub struct ModelArgs {
    #[command(subcommand)]
    pub action: ModelAction,
}

#[derive(clap::Subcommand, Debug)]
pub enum ModelAction {
    /// Download a model (config, tokenizer, weights) into the cache and print where it is.
    #[command(after_help = "Example:\n  t2tf model fetch\n  t2tf model fetch \
                            laion/CLIP-ViT-H-14-laion2B-s32B-b79K\n  t2tf model fetch \
                            openai/clip-vit-base-patch32 --revision refs/pr/15\n\n\
                            The cache is $HF_HUB_CACHE, else $HF_HOME/hub, else \
                            ~/.cache/huggingface/hub (shared with Python's huggingface_hub). \
                            HF_ENDPOINT selects a mirror; HF_TOKEN (or the token file) is sent \
                            for gated or private models.")]
    Fetch(FetchArgs),
    /// List the CLIP models in the cache with their revisions and sizes.
    #[command(
        after_help = "Examples:\n  t2tf model list\n  t2tf model list --all\n\n\
                            The cache is $HF_HUB_CACHE, else $HF_HOME/hub, else \
                            ~/.cache/huggingface/hub."
    )]
    List(ListArgs),
}

#[derive(clap::Args, Debug)]
pub struct FetchArgs {
    /// Hugging Face repo id.
    #[arg(default_value = DEFAULT_MODEL, value_name = "REPO_ID")]
    pub repo: String,
    /// Branch, tag, pull-request ref (refs/pr/N) or commit.
    #[arg(long, default_value = DEFAULT_REVISION, value_name = "REV")]
    pub revision: String,
}

#[derive(clap::Args, Debug)]
pub struct ListArgs {
    /// List every cached model repository, not only CLIP models.
    #[arg(long)]
    pub all: bool,
}

pub fn run(args: ModelArgs) -> Result<()> {
    match args.action {
        ModelAction::Fetch(a) => fetch(a),
        ModelAction::List(a) => list(a),
    }
}

fn fetch(a: FetchArgs) -> Result<()> {
    if !looks_like_repo_id(&a.repo) {
        bail!(
            "{}: not a Hugging Face repo id (owner/name); `t2tf model fetch` downloads from the Hub",
            a.repo
        );
    }
    let settings = crate::model_args::hub_settings();
    if settings.offline {
        bail!(
            "HF_HUB_OFFLINE is set, and `t2tf model fetch` needs the network: unset it to download {}",
            a.repo
        );
    }
    let req = ModelRequest {
        model: a.repo.clone(),
        revision: a.revision.clone(),
        tokenizer: None,
        hub: settings.clone(),
    };
    let hub = Hub::new(settings);
    let files = resolve_with(&req, &hub).with_context(|| format!("cannot fetch {}", a.repo))?;
    // Check what was downloaded before telling the user it is ready for offline use.
    let summary = crate::clip::Clip::check(&files)
        .with_context(|| format!("{} was downloaded but does not load", a.repo))?;
    let mut paths = vec![files.config.clone(), files.tokenizer.clone()];
    paths.extend(files.weights.iter().cloned());
    for p in &paths {
        let size = std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
        let name = p.file_name().unwrap_or_default().to_string_lossy();
        outln!("  {name:<40} {:>10}", human_bytes(size.into()))?;
    }
    outln!("  {summary}")?;
    let snapshot = files.config.parent().unwrap_or(&files.config);
    errln!(
        "t2tf: {} at {} is in the cache; use it offline with HF_HUB_OFFLINE=1 and --model {}{}, \
         or --model with the folder below",
        a.repo,
        a.revision,
        a.repo,
        if a.revision == DEFAULT_REVISION {
            String::new()
        } else {
            format!(" --revision {}", a.revision)
        }
    );
    outln!("{}", snapshot.display())?;
    Ok(())
}

fn list(a: ListArgs) -> Result<()> {
    let settings = HubSettings::from_env();
    let repos = cached_repos(&settings.cache_dir)?;
    let shown: Vec<_> = repos
        .iter()
        .filter(|r| r.kind == RepoKind::Model && (a.all || is_clip(r)))
        .collect();
    if shown.is_empty() {
        errln!(
            "t2tf: no {}models in the cache at {} (`t2tf model fetch` downloads one)",
            if a.all { "" } else { "CLIP " },
            settings.cache_dir.display()
        );
        return Ok(());
    }
    outln!("{:<48} {:>10}  {:<20} weights", "repo", "size", "revisions")?;
    for r in shown {
        outln!(
            "{:<48} {:>10}  {:<20} {}",
            r.repo_id,
            human_bytes(r.size_on_disk.into()),
            refs(r),
            weight_files(r).join(", ")
        )?;
    }
    outln!("cache: {}", settings.cache_dir.display())?;
    Ok(())
}

/// A repo is a CLIP model if a cached config.json describes a `CLIPModel` (it has both towers),
/// or a cached open_clip_config.json has a `model_cfg` (OpenCLIP's layout).
pub(crate) fn is_clip(r: &CachedRepo) -> bool {
    r.snapshots.iter().flat_map(|s| &s.files).any(|f| {
        let json = || {
            std::fs::read_to_string(&f.path)
                .ok()
                .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        };
        match f.name.as_str() {
            "config.json" => json().is_some_and(|v| {
                v.get("model_type").and_then(|m| m.as_str()) == Some("clip")
                    || (v.get("text_config").is_some() && v.get("vision_config").is_some())
            }),
            OPEN_CLIP_CONFIG => json().is_some_and(|v| v.get("model_cfg").is_some()),
            _ => false,
        }
    })
}

/// "main, refs/pr/15", or the short commits of snapshots no ref points to.
fn refs(r: &CachedRepo) -> String {
    if r.refs.is_empty() {
        let commits: Vec<&str> = r
            .snapshots
            .iter()
            .map(|s| &s.commit[..s.commit.len().min(8)])
            .collect();
        commits.join(",")
    } else {
        r.refs.keys().cloned().collect::<Vec<_>>().join(",")
    }
}

/// The weight files cached in any snapshot (model.safetensors, pytorch_model.bin, shards,
/// OpenCLIP's open_clip_pytorch_model.bin and its safetensors copies).
fn weight_files(r: &CachedRepo) -> Vec<String> {
    let mut names: Vec<String> = r
        .snapshots
        .iter()
        .flat_map(|s| &s.files)
        .map(|f| f.name.clone())
        .filter(|n| {
            WEIGHT_FILES.iter().any(|w| w.0 == n)
                || OPEN_CLIP_WEIGHT_FILES.iter().any(|w| w.0 == n)
                || ((n.starts_with("model-") || n.starts_with("pytorch_model-"))
                    && (n.ends_with(".safetensors") || n.ends_with(".bin")))
        })
        .collect();
    names.sort();
    names.dedup();
    names
}
