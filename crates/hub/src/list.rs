//! What the cache holds (for `t2tf model list`), read from Python's layout: one entry per
//! `{kind}s--{owner}--{name}` folder, with its refs, snapshots and the disk space its blobs take.

use std::collections::{BTreeMap, HashSet};
use std::fs;
use std::path::{Path, PathBuf};

use super::HubError;

/// The kind of repo a cache folder belongs to (its `models--` / `datasets--` / `spaces--` prefix).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum RepoKind {
    /// `models--owner--name`.
    Model,
    /// `datasets--owner--name`.
    Dataset,
    /// `spaces--owner--name`.
    Space,
}

/// One cached repo.
#[derive(Clone, Debug)]
pub struct CachedRepo {
    /// `owner/name`.
    pub repo_id: String,
    /// Model, dataset or space.
    pub kind: RepoKind,
    /// The repo's cache folder.
    pub path: PathBuf,
    /// Revision (branch, tag, `refs/pr/N`) → commit, from `refs/`.
    pub refs: BTreeMap<String, String>,
    /// One per `snapshots/{commit}`, by commit.
    pub snapshots: Vec<CachedSnapshot>,
    /// Bytes of the distinct files the snapshots point to (a blob shared by several
    /// snapshots counts once).
    pub size_on_disk: u64,
}

/// One cached commit.
#[derive(Clone, Debug)]
pub struct CachedSnapshot {
    /// The commit hash (the `snapshots/` folder's name).
    pub commit: String,
    /// The files of that commit present in the cache, by name.
    pub files: Vec<CachedFile>,
}

/// One cached file of a snapshot.
#[derive(Clone, Debug)]
pub struct CachedFile {
    /// Name in the repo, with `/` separators.
    pub name: String,
    /// The snapshot path (usually a symlink into `blobs/`).
    pub path: PathBuf,
    /// Its size in bytes (of the blob it points to).
    pub size: u64,
}

/// Every repo cached under `cache_dir` (none when it does not exist), by kind and id.
pub fn cached_repos(cache_dir: &Path) -> Result<Vec<CachedRepo>, HubError> {
    let entries = match fs::read_dir(cache_dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(HubError::io(cache_dir, e)),
    };
    let mut repos = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| HubError::io(cache_dir, e))?;
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if let (Some((kind, repo_id)), true) = (parse_folder(&name), path.is_dir()) {
            repos.push(read_repo(path, kind, repo_id)?);
        }
    }
    repos.sort_by(|a, b| (a.kind, &a.repo_id).cmp(&(b.kind, &b.repo_id)));
    Ok(repos)
}

/// `models--owner--name` → (Model, `owner/name`); other names (`.locks`, `CACHEDIR.TAG`) → None.
fn parse_folder(name: &str) -> Option<(RepoKind, String)> {
    let (prefix, rest) = name.split_once("--")?;
    let kind = match prefix {
        "models" => RepoKind::Model,
        "datasets" => RepoKind::Dataset,
        "spaces" => RepoKind::Space,
        _ => return None,
    };
    let parts: Vec<&str> = rest.split("--").collect();
    (!parts.iter().any(|p| p.is_empty())).then(|| (kind, parts.join("/")))
}

fn read_repo(path: PathBuf, kind: RepoKind, repo_id: String) -> Result<CachedRepo, HubError> {
    let mut refs = BTreeMap::new();
    for (name, file) in walk_files(&path.join("refs"))? {
        // Only what a ref file can hold (a commit id), never a symlink's target or a FIFO:
        // a listing must not print another file's contents.
        if let Some(commit) = super::cache::read_ref(&file).map_err(|e| HubError::io(&file, e))? {
            refs.insert(name, commit);
        }
    }
    let mut snapshots = Vec::new();
    let mut seen = HashSet::new();
    let mut size_on_disk = 0;
    for commit_dir in sorted_dirs(&path.join("snapshots"))? {
        let commit = commit_dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut files = Vec::new();
        for (name, file) in walk_files(&commit_dir)? {
            // `metadata` follows the link; a link whose blob is gone is not a cached file.
            let Ok(meta) = fs::metadata(&file) else {
                continue;
            };
            let real = fs::canonicalize(&file).unwrap_or_else(|_| file.clone());
            if seen.insert(real) {
                size_on_disk += meta.len();
            }
            files.push(CachedFile {
                name,
                path: file,
                size: meta.len(),
            });
        }
        snapshots.push(CachedSnapshot { commit, files });
    }
    Ok(CachedRepo {
        repo_id,
        kind,
        path,
        refs,
        snapshots,
        size_on_disk,
    })
}

/// Sub-folders of `dir`, sorted; none when it does not exist.
fn sorted_dirs(dir: &Path) -> Result<Vec<PathBuf>, HubError> {
    let mut dirs = Vec::new();
    match fs::read_dir(dir) {
        Ok(entries) => {
            for entry in entries {
                let path = entry.map_err(|e| HubError::io(dir, e))?.path();
                if path.is_dir() {
                    dirs.push(path);
                }
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(HubError::io(dir, e)),
    }
    dirs.sort();
    Ok(dirs)
}

/// Every non-directory under `dir` (symlinks included, not followed into directories), as
/// (name relative to `dir` with `/`, path), sorted by name; none when `dir` does not exist.
fn walk_files(dir: &Path) -> Result<Vec<(String, PathBuf)>, HubError> {
    let mut out = Vec::new();
    let mut stack = vec![(String::new(), dir.to_path_buf())];
    while let Some((prefix, folder)) = stack.pop() {
        let entries = match fs::read_dir(&folder) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(HubError::io(&folder, e)),
        };
        for entry in entries {
            let entry = entry.map_err(|e| HubError::io(&folder, e))?;
            let name = format!("{prefix}{}", entry.file_name().to_string_lossy());
            let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
            if is_dir {
                stack.push((format!("{name}/"), entry.path()));
            } else {
                out.push((name, entry.path()));
            }
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folder_names() {
        assert_eq!(
            parse_folder("models--o--n"),
            Some((RepoKind::Model, "o/n".into()))
        );
        assert_eq!(
            parse_folder("models--gpt2"),
            Some((RepoKind::Model, "gpt2".into()))
        );
        assert_eq!(
            parse_folder("datasets--o--d"),
            Some((RepoKind::Dataset, "o/d".into()))
        );
        assert_eq!(parse_folder(".locks"), None);
        assert_eq!(parse_folder("CACHEDIR.TAG"), None);
        assert_eq!(parse_folder("models--"), None);
    }

    #[cfg(unix)]
    #[test]
    fn refs_list_only_commit_ids_never_a_linked_files_contents() {
        let dir = tempfile::tempdir().unwrap();
        let repo = dir.path().join("models--o--n");
        std::fs::create_dir_all(repo.join("refs")).unwrap();
        let commit = "0123456789abcdef0123456789abcdef01234567";
        std::fs::write(repo.join("refs/main"), commit).unwrap();
        let victim = dir.path().join("secret.txt");
        std::fs::write(&victim, "a secret line").unwrap();
        std::os::unix::fs::symlink(&victim, repo.join("refs/planted")).unwrap();
        std::fs::write(repo.join("refs/garbage"), "not a commit").unwrap();
        let repos = cached_repos(dir.path()).unwrap();
        assert_eq!(repos.len(), 1);
        let refs = &repos[0].refs;
        assert_eq!(refs.get("main").map(String::as_str), Some(commit));
        assert_eq!(refs.len(), 1, "{refs:?}");
    }

    #[test]
    fn missing_cache_is_empty() {
        let dir = tempfile::tempdir().unwrap();
        assert!(cached_repos(&dir.path().join("nope")).unwrap().is_empty());
    }
}
