//! Finding a model's files: a local directory, or a Hugging Face repo id resolved through the
//! standard Hugging Face cache (`$HF_HOME/hub`, Python's layout) with `hf-hub`, downloading on a
//! cache miss unless `HF_HUB_OFFLINE` is set (hf-hub 0.5 does not read it, so we do).

use std::path::{Path, PathBuf};

use super::ClipError;

/// The default model (`--model` left out).
pub const DEFAULT_MODEL: &str = "openai/clip-vit-base-patch32";

const CONFIG: &str = "config.json";
const WEIGHTS: &str = "model.safetensors";
const TOKENIZER: &str = "tokenizer.json";

/// Paths of the three files a model needs.
#[derive(Clone, Debug)]
pub struct ModelFiles {
    pub config: PathBuf,
    pub weights: PathBuf,
    pub tokenizer: PathBuf,
}

/// Resolve `model` (a directory, or a repo id like `openai/clip-vit-base-patch32`).
/// `tokenizer` overrides where `tokenizer.json` comes from.
pub fn resolve(model: &str, tokenizer: Option<&Path>) -> Result<ModelFiles, ClipError> {
    let path = Path::new(model);
    if path.is_dir() {
        return resolve_dir(path, tokenizer);
    }
    if path.exists() {
        return Err(ClipError::Missing(format!(
            "{model} is a file; a model is a directory holding {CONFIG}, {WEIGHTS} and {TOKENIZER}, \
             or a Hugging Face repo id such as {DEFAULT_MODEL}"
        )));
    }
    if !looks_like_repo_id(model) {
        return Err(ClipError::Missing(format!(
            "{model}: no such directory, and not a Hugging Face repo id (owner/name)"
        )));
    }
    let offline = std::env::var("HF_HUB_OFFLINE")
        .map(|v| matches!(v.to_ascii_lowercase().as_str(), "1" | "true" | "yes" | "on"))
        .unwrap_or(false);
    resolve_repo(model, tokenizer, &hf_hub::Cache::from_env(), offline)
}

fn resolve_dir(dir: &Path, tokenizer: Option<&Path>) -> Result<ModelFiles, ClipError> {
    let files = ModelFiles {
        config: dir.join(CONFIG),
        weights: dir.join(WEIGHTS),
        tokenizer: tokenizer.map_or_else(|| dir.join(TOKENIZER), Path::to_path_buf),
    };
    let missing: Vec<String> = [&files.config, &files.weights, &files.tokenizer]
        .iter()
        .filter(|p| !p.is_file())
        .map(|p| p.display().to_string())
        .collect();
    if missing.is_empty() {
        Ok(files)
    } else {
        Err(ClipError::Missing(format!(
            "model directory {} is incomplete: missing {} (a CLIP model directory holds {CONFIG}, \
             {WEIGHTS} and {TOKENIZER} as on huggingface.co; --tokenizer PATH can point elsewhere \
             for the tokenizer)",
            dir.display(),
            missing.join(", ")
        )))
    }
}

fn looks_like_repo_id(s: &str) -> bool {
    let mut parts = s.split('/');
    let ok = |p: Option<&str>| {
        p.is_some_and(|p| {
            !p.is_empty()
                && p.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        })
    };
    ok(parts.next()) && ok(parts.next()) && parts.next().is_none()
}

/// Repo files from `cache`, fetching the missing ones unless `offline`.
pub fn resolve_repo(
    repo: &str,
    tokenizer: Option<&Path>,
    cache: &hf_hub::Cache,
    offline: bool,
) -> Result<ModelFiles, ClipError> {
    let cached = cache.model(repo.to_string());
    let wanted: Vec<&str> = if tokenizer.is_some() {
        vec![CONFIG, WEIGHTS]
    } else {
        vec![CONFIG, WEIGHTS, TOKENIZER]
    };
    let mut found = Vec::new();
    let mut missing = Vec::new();
    for f in &wanted {
        match cached.get(f) {
            Some(p) => found.push(p),
            None => missing.push(*f),
        }
    }
    let where_to_put =
        format!(
        "download {} from https://huggingface.co/{repo} into a directory and pass --model DIR, \
         or put them in the Hugging Face cache at {}",
        wanted.join(", "),
        cache.path().join(format!("models--{}", repo.replace('/', "--"))).display()
    );
    if !missing.is_empty() {
        if offline {
            return Err(ClipError::Missing(format!(
                "{repo}: {} not in the Hugging Face cache and HF_HUB_OFFLINE is set; {where_to_put}",
                missing.join(", ")
            )));
        }
        let api = hf_hub::api::sync::ApiBuilder::from_cache(cache.clone())
            .with_progress(true)
            .build()
            .map_err(|e| {
                ClipError::Missing(format!(
                    "{repo}: cannot start the download ({e}); {where_to_put}"
                ))
            })?;
        let api_repo = api.model(repo.to_string());
        found.clear();
        for f in &wanted {
            let p = api_repo.get(f).map_err(|e| {
                ClipError::Missing(format!("{repo}: cannot fetch {f} ({e}); {where_to_put}"))
            })?;
            found.push(p);
        }
    }
    Ok(ModelFiles {
        config: found[0].clone(),
        weights: found[1].clone(),
        tokenizer: tokenizer.map_or_else(|| found[2].clone(), Path::to_path_buf),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offline_cache_miss_names_files_and_places() {
        let home = tempfile::tempdir().unwrap();
        let cache = hf_hub::Cache::new(home.path().to_path_buf());
        let e = resolve_repo(DEFAULT_MODEL, None, &cache, true)
            .unwrap_err()
            .to_string();
        for needle in [
            CONFIG,
            WEIGHTS,
            TOKENIZER,
            "HF_HUB_OFFLINE",
            "--model DIR",
            "models--openai--clip-vit-base-patch32",
        ] {
            assert!(e.contains(needle), "{needle} not in: {e}");
        }
    }

    #[test]
    fn cached_files_resolve_without_network() {
        // Python's cache layout: refs/main holds the commit, snapshots/<commit>/<file>.
        let home = tempfile::tempdir().unwrap();
        let repo = home.path().join("models--someone--tiny");
        std::fs::create_dir_all(repo.join("refs")).unwrap();
        std::fs::write(repo.join("refs/main"), "abc123").unwrap();
        let snap = repo.join("snapshots/abc123");
        std::fs::create_dir_all(&snap).unwrap();
        for f in [CONFIG, WEIGHTS, TOKENIZER] {
            std::fs::write(snap.join(f), "x").unwrap();
        }
        let cache = hf_hub::Cache::new(home.path().to_path_buf());
        let files = resolve_repo("someone/tiny", None, &cache, true).unwrap();
        assert_eq!(files.weights, snap.join(WEIGHTS));
        assert_eq!(files.tokenizer, snap.join(TOKENIZER));
    }

    #[test]
    fn incomplete_directory_lists_what_is_missing() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(CONFIG), "{}").unwrap();
        let e = resolve(dir.path().to_str().unwrap(), None)
            .unwrap_err()
            .to_string();
        let path_of = |f: &str| dir.path().join(f).display().to_string();
        assert!(
            e.contains(&path_of(WEIGHTS)) && e.contains(&path_of(TOKENIZER)),
            "{e}"
        );
        assert!(!e.contains(&path_of(CONFIG)), "{e}");
        let e = resolve("not a repo id at all", None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a Hugging Face repo id"), "{e}");
    }
}
