//! Python's cache layout (`huggingface_hub`'s `hf_hub_download`), so that a file written by either
//! tool is found by the other:
//!
//! ```text
//! {cache}/models--{owner}--{name}/
//!     blobs/{etag}                      file contents (etag: git sha1, or sha256 for LFS files)
//!     blobs/{etag}.incomplete           a download in progress (ours resume from it)
//!     snapshots/{commit}/{filename}     relative symlink to ../../blobs/{etag} (filename may hold `/`)
//!     refs/{revision}                   the commit a branch or tag pointed at (refs/pr/15 → refs/refs/pr/15)
//!     .no_exist/{commit}/{filename}     empty: the Hub said 404 EntryNotFound for it at that commit
//! ```
//!
//! What the cache holds is read with care, as someone else may have planted it: a snapshot
//! entry counts as cached only when it leads to a file inside the repo's cache folder (a
//! symlink out of it is never read, so no message can quote another file); a ref is read
//! without following a symlink, at most a few bytes, and used only when it is a commit id.
//! Refs and markers are written through `t2tf_core::fs::atomic_replace_bytes` (a random
//! temporary renamed over the name: a symlink there is replaced, its target untouched).

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use super::HubError;

/// Paths and updates inside one repo's cache folder.
#[derive(Clone, Debug)]
pub(crate) struct RepoCache {
    root: PathBuf,
}

/// What the cache knows about a file at a commit.
#[derive(Debug, PartialEq)]
pub(crate) enum Cached {
    /// The snapshot holds it.
    File(PathBuf),
    /// A `.no_exist` marker: the repo has no such file at that commit.
    Absent,
    /// Nothing recorded.
    Unknown,
}

impl Cached {
    /// The path when cached, None otherwise.
    pub(crate) fn into_path(self) -> Option<PathBuf> {
        match self {
            Cached::File(path) => Some(path),
            Cached::Absent | Cached::Unknown => None,
        }
    }
}

/// The folder name Python gives a model repo: `models--owner--name`.
pub(crate) fn folder_name(repo_id: &str) -> String {
    let mut name = String::from("models");
    for part in repo_id.split('/') {
        name.push_str("--");
        name.push_str(part);
    }
    name
}

/// A full commit id (what `X-Repo-Commit` carries), as opposed to a branch or tag name.
pub(crate) fn is_commit(revision: &str) -> bool {
    revision.len() == 40
        && revision
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// `filename` (with `/` separators) appended to `dir`, one component at a time.
fn join_relative(dir: &Path, filename: &str) -> PathBuf {
    filename
        .split('/')
        .fold(dir.to_path_buf(), |p, c| p.join(c))
}

impl RepoCache {
    /// The cache folder of `repo_id` under `cache_dir`.
    pub(crate) fn new(cache_dir: &Path, repo_id: &str) -> RepoCache {
        RepoCache {
            root: cache_dir.join(folder_name(repo_id)),
        }
    }

    /// `models--owner--name`.
    pub(crate) fn root(&self) -> &Path {
        &self.root
    }

    /// Where a blob with this etag lives.
    pub(crate) fn blob(&self, etag: &str) -> PathBuf {
        self.root.join("blobs").join(etag)
    }

    /// Where a download of this blob accumulates until it is checked.
    pub(crate) fn incomplete(&self, etag: &str) -> PathBuf {
        self.root.join("blobs").join(format!("{etag}.incomplete"))
    }

    /// `snapshots/{commit}/{filename}`.
    pub(crate) fn snapshot_file(&self, commit: &str, filename: &str) -> PathBuf {
        join_relative(&self.root.join("snapshots").join(commit), filename)
    }

    fn no_exist(&self, commit: &str, filename: &str) -> PathBuf {
        join_relative(&self.root.join(".no_exist").join(commit), filename)
    }

    fn ref_file(&self, revision: &str) -> PathBuf {
        join_relative(&self.root.join("refs"), revision)
    }

    /// The commit `revision` resolves to: itself when it is one, else what `refs/` recorded.
    pub(crate) fn commit_for(&self, revision: &str) -> Result<Option<String>, HubError> {
        if is_commit(revision) {
            return Ok(Some(revision.to_string()));
        }
        let path = self.ref_file(revision);
        match read_ref(&path) {
            Ok(commit) => Ok(commit),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(HubError::io(path, e)),
        }
    }

    /// Whether `path` leads (through any symlinks) to a regular file inside the repo's folder.
    fn holds(&self, path: &Path) -> bool {
        let (Ok(real), Ok(root)) = (fs::canonicalize(path), fs::canonicalize(&self.root)) else {
            return false;
        };
        real.starts_with(root) && real.is_file()
    }

    /// What the cache holds for `filename` at `commit`.
    pub(crate) fn lookup(&self, commit: &str, filename: &str) -> Cached {
        let pointer = self.snapshot_file(commit, filename);
        // A link whose blob was deleted, or one that leads out of the cache, is not cached.
        if self.holds(&pointer) {
            Cached::File(pointer)
        } else if self.no_exist(commit, filename).is_file() {
            Cached::Absent
        } else {
            Cached::Unknown
        }
    }

    /// Record that `revision` points at `commit` (nothing to record when it is the commit).
    /// Written through a temporary file so a reader never sees half a commit id.
    pub(crate) fn write_ref(&self, revision: &str, commit: &str) -> Result<(), HubError> {
        if revision == commit {
            return Ok(());
        }
        let path = self.ref_file(revision);
        if read_ref(&path).is_ok_and(|old| old.as_deref() == Some(commit)) {
            return Ok(());
        }
        create_parent(&path)?;
        Ok(t2tf_core::fs::atomic_replace_bytes(
            &path,
            commit.as_bytes(),
        )?)
    }

    /// Leave a `.no_exist` marker for `filename` at `commit`.
    pub(crate) fn mark_absent(&self, commit: &str, filename: &str) -> Result<(), HubError> {
        let path = self.no_exist(commit, filename);
        create_parent(&path)?;
        Ok(t2tf_core::fs::atomic_replace_bytes(&path, b"")?)
    }

    /// Point `snapshots/{commit}/{filename}` at `blobs/{etag}` and return the snapshot path.
    pub(crate) fn link(
        &self,
        etag: &str,
        commit: &str,
        filename: &str,
    ) -> Result<PathBuf, HubError> {
        let pointer = self.snapshot_file(commit, filename);
        if self.holds(&pointer) {
            return Ok(pointer);
        }
        create_parent(&pointer)?;
        // A dangling link (its blob was deleted), or one leading out of the cache, is replaced.
        if pointer.symlink_metadata().is_ok() {
            fs::remove_file(&pointer).map_err(|e| HubError::io(&pointer, e))?;
        }
        let blob = self.blob(etag);
        place_link(&blob, &link_target(etag, filename), &pointer)?;
        // The blob itself may be a symlink someone left there: never hand out what it leads to.
        if !self.holds(&pointer) {
            return Err(HubError::OutsideCache {
                path: blob,
                root: self.root.clone(),
            });
        }
        Ok(pointer)
    }
}

/// The commit a ref file records: read without following a symlink or waiting on a FIFO, at
/// most 128 bytes, and `None` unless it is a commit id (Python writes the bare commit; a
/// trailing newline from hand edits is tolerated).
pub(crate) fn read_ref(path: &Path) -> std::io::Result<Option<String>> {
    let mut options = fs::OpenOptions::new();
    options.read(true);
    let file = match t2tf_core::platform::no_follow_no_wait(&mut options).open(path) {
        Ok(file) => file,
        // A symlink in a ref's place is not a ref Python or t2tf wrote.
        Err(_) if fs::symlink_metadata(path).is_ok_and(|m| m.is_symlink()) => return Ok(None),
        Err(e) => return Err(e),
    };
    if !file.metadata()?.is_file() {
        return Ok(None);
    }
    let mut text = Vec::new();
    file.take(128).read_to_end(&mut text)?;
    let commit = String::from_utf8_lossy(&text).trim().to_string();
    Ok(is_commit(&commit).then_some(commit))
}

/// The relative target Python writes: one `..` per directory between the link and the repo
/// folder (`snapshots`, the commit, and any folders inside `filename`), then `blobs/{etag}`.
pub(crate) fn link_target(etag: &str, filename: &str) -> PathBuf {
    let ups = filename.split('/').count() + 1;
    let mut target = PathBuf::new();
    for _ in 0..ups {
        target.push("..");
    }
    target.join("blobs").join(etag)
}

#[cfg(unix)]
fn place_link(_blob: &Path, target: &Path, pointer: &Path) -> Result<(), HubError> {
    std::os::unix::fs::symlink(target, pointer).map_err(|e| HubError::io(pointer, e))
}

/// On Windows a symlink needs developer mode or an administrator: where the system refuses
/// one, Python falls back to a copy of the blob, and so do we.
#[cfg(windows)]
fn place_link(blob: &Path, target: &Path, pointer: &Path) -> Result<(), HubError> {
    if std::os::windows::fs::symlink_file(target, pointer).is_ok() && pointer.is_file() {
        return Ok(());
    }
    let _ = fs::remove_file(pointer);
    fs::copy(blob, pointer)
        .map(|_| ())
        .map_err(|e| HubError::io(pointer, e))
}

fn create_parent(path: &Path) -> Result<(), HubError> {
    match path.parent() {
        Some(dir) => fs::create_dir_all(dir).map_err(|e| HubError::io(dir, e)),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const COMMIT: &str = "0123456789abcdef0123456789abcdef01234567";

    #[test]
    fn names_follow_python() {
        assert_eq!(
            folder_name("openai/clip-vit-base-patch32"),
            "models--openai--clip-vit-base-patch32"
        );
        assert_eq!(folder_name("gpt2"), "models--gpt2");
        assert!(is_commit(COMMIT));
        assert!(!is_commit("main"));
        assert!(!is_commit(&COMMIT.to_uppercase()));
        assert_eq!(link_target("e", "config.json"), Path::new("../../blobs/e"));
        assert_eq!(
            link_target("e", "a/b/c.bin"),
            Path::new("../../../../blobs/e")
        );
    }

    #[test]
    fn refs_markers_and_links() {
        let dir = tempfile::tempdir().unwrap();
        let cache = RepoCache::new(dir.path(), "o/n");
        assert_eq!(cache.commit_for("refs/pr/15").unwrap(), None);
        cache.write_ref("refs/pr/15", COMMIT).unwrap();
        assert!(cache.root().join("refs/refs/pr/15").is_file());
        assert_eq!(
            cache.commit_for("refs/pr/15").unwrap().as_deref(),
            Some(COMMIT)
        );
        cache.write_ref(COMMIT, COMMIT).unwrap();
        assert!(!cache.root().join("refs").join(COMMIT).exists());

        assert_eq!(cache.lookup(COMMIT, "sub/w.bin"), Cached::Unknown);
        cache.mark_absent(COMMIT, "sub/w.bin").unwrap();
        assert_eq!(cache.lookup(COMMIT, "sub/w.bin"), Cached::Absent);

        fs::create_dir_all(cache.blob("e").parent().unwrap()).unwrap();
        fs::write(cache.blob("e"), b"data").unwrap();
        let p = cache.link("e", COMMIT, "dir/f.txt").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"data");
        assert_eq!(cache.lookup(COMMIT, "dir/f.txt"), Cached::File(p.clone()));
        #[cfg(unix)]
        assert_eq!(fs::read_link(&p).unwrap(), Path::new("../../../blobs/e"));

        // A link whose blob vanished is not a cached file, and linking again repairs it. (Where
        // the system refused a symlink the entry is a copy, which outlives its blob, as
        // Python's does.)
        if !fs::symlink_metadata(&p).unwrap().file_type().is_symlink() {
            return;
        }
        fs::remove_file(cache.blob("e")).unwrap();
        assert_eq!(cache.lookup(COMMIT, "dir/f.txt"), Cached::Unknown);
        fs::write(cache.blob("e"), b"again").unwrap();
        assert_eq!(
            fs::read(cache.link("e", COMMIT, "dir/f.txt").unwrap()).unwrap(),
            b"again"
        );
    }
}
