//! A small Hugging Face Hub client that behaves like Python's `huggingface_hub.hf_hub_download`:
//! same settings from the environment, same cache layout (a file either tool wrote is found by
//! the other), same HEAD/redirect protocol, plus integrity checks.
//!
//! Why not the `hf-hub` crate (0.5.0, `src/api/sync.rs` and `src/lib.rs`):
//! - `ApiBuilder::from_cache` hard-codes `https://huggingface.co` (sync.rs:268), so `HF_ENDPOINT`
//!   is lost when a cache is given; `Cache::from_env` reads only `HF_HOME` (lib.rs:42-51), not
//!   `HF_HUB_CACHE` or `XDG_CACHE_HOME`; the token comes only from the token file next to the
//!   cache (lib.rs:59-85, sync.rs:263), never `HF_TOKEN`; nothing reads `HF_HUB_OFFLINE`.
//! - `Api::metadata` panics on a redirect without `Location`
//!   (`.expect("location header in redirect")`, sync.rs:562-565).
//! - the download is renamed into `blobs/` with no size or sha256 check (sync.rs:810-817), and a
//!   resumed GET appends whatever comes back without checking for 206 (sync.rs:650-662), so a
//!   server that ignores `Range` corrupts the blob silently.
//! - every HTTP error becomes `RequestError(ureq::Error::StatusCode(..))` with the headers dropped
//!   (sync.rs:476-481, 181): no `X-Error-Code`, so a missing file (404 `EntryNotFound`, which
//!   the loader needs to fall back from `model.safetensors` to `pytorch_model.bin`) looks like a
//!   missing repo or revision; `.no_exist` markers are neither written nor read.
//! - the token goes to the CDN too: its `HeaderAgent` adds `Authorization` to every request
//!   (sync.rs:67-73), including the GET of an absolute redirect's `Location` (sync.rs:568-572).
//!
//! Modules: [`mod@env`] settings, `cache` the layout, `http` requests and redirects, `download`
//! transfer/resume/verify/progress, `list` cached repos.

mod cache;
mod download;
pub mod env;
mod error;
mod http;
mod list;

use std::path::{Path, PathBuf};

pub use error::HubError;
pub use list::{cached_repos, CachedFile, CachedRepo, CachedSnapshot, RepoKind};

use cache::{Cached, RepoCache};
use http::{Client, Head, Metadata, Target};

/// What the client tells its front end while it works (`HubSettings::on_event`): the
/// library draws nothing and prints nothing itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum HubEvent {
    /// A download of at least 10 MiB (or of unknown size) starts; smaller files say nothing.
    Started {
        /// The file's name in the repo.
        file: String,
        /// Its size, where the Hub said.
        total: Option<u64>,
    },
    /// Bytes of it on disk so far (at most every 100 ms).
    Progress {
        /// The file's name in the repo.
        file: String,
        /// Bytes so far, a resumed part included.
        done: u64,
        /// Its size, where known.
        total: Option<u64>,
    },
    /// The download ended: `ok`, or stopped by an error.
    Finished {
        /// The file's name in the repo.
        file: String,
        /// Bytes on disk.
        done: u64,
        /// Whether the file is complete and checked.
        ok: bool,
    },
    /// Something the user should know, e.g. that a cached file is used because the Hub could
    /// not be reached.
    Warning(String),
}

/// Where [`HubEvent`]s go: a front end's function (a progress bar, lines in a log, a Python
/// callback).
#[derive(Clone)]
pub struct EventSink(pub std::sync::Arc<dyn Fn(&HubEvent) + Send + Sync>);

impl EventSink {
    /// A sink calling `f`.
    pub fn new(f: impl Fn(&HubEvent) + Send + Sync + 'static) -> EventSink {
        EventSink(std::sync::Arc::new(f))
    }
}

impl std::fmt::Debug for EventSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("EventSink(..)")
    }
}

impl HubSettings {
    /// Tell the front end `event`, if it listens.
    pub(crate) fn tell(&self, event: HubEvent) {
        if let Some(sink) = &self.on_event {
            (sink.0)(&event);
        }
    }
}

/// How to reach the Hub and where the cache is; [`HubSettings::from_env`] reads them as
/// `huggingface_hub` does.
#[derive(Clone, Debug)]
pub struct HubSettings {
    /// Base URL, no trailing `/` (`HF_ENDPOINT`).
    pub endpoint: String,
    /// The cache root holding `models--owner--name` folders (`HF_HUB_CACHE`).
    pub cache_dir: PathBuf,
    /// Sent as `Authorization: Bearer` to the endpoint, never to other hosts (`HF_TOKEN`).
    pub token: Option<String>,
    /// Answer from the cache only, with no request (`HF_HUB_OFFLINE`).
    pub offline: bool,
    /// Report download progress for large files (`HF_HUB_DISABLE_PROGRESS_BARS` unset).
    pub progress: bool,
    /// The longest a read may wait, and the time a download must get 1 KiB within, on each of
    /// its two tries (`T2TF_HUB_STALL_TIMEOUT`, seconds; 30 s by default).
    pub stall_timeout: std::time::Duration,
    /// Where progress and warnings go; `None`: nowhere.
    pub on_event: Option<EventSink>,
}

/// A Hub client.
pub struct Hub {
    settings: HubSettings,
    client: Client,
}

/// One repo at one revision.
pub struct HubRepo<'a> {
    hub: &'a Hub,
    repo_id: String,
    revision: String,
    cache: RepoCache,
}

impl Hub {
    /// A client for `settings` (no request is made until a file is asked for).
    pub fn new(settings: HubSettings) -> Hub {
        let client = Client::new(
            &settings.endpoint,
            settings.token.clone(),
            settings.stall_timeout,
        );
        Hub { settings, client }
    }

    /// The model repo `repo_id` (`owner/name`) at `revision` (branch, tag, `refs/pr/N`, commit).
    pub fn repo(&self, repo_id: &str, revision: &str) -> HubRepo<'_> {
        HubRepo {
            hub: self,
            repo_id: repo_id.to_string(),
            revision: revision.to_string(),
            cache: RepoCache::new(&self.settings.cache_dir, repo_id),
        }
    }

    /// The settings this client was made with.
    pub fn settings(&self) -> &HubSettings {
        &self.settings
    }
}

impl HubRepo<'_> {
    /// Local path of `filename` at this revision, downloading on a miss. Ok(None): the repo has
    /// no such file at that revision (404 EntryNotFound; offline: a `.no_exist` marker).
    pub fn get(&self, filename: &str) -> Result<Option<PathBuf>, HubError> {
        self.validate(filename)?;
        // A commit never changes: what the cache knows about it needs no request.
        if cache::is_commit(&self.revision) {
            let cached = self.cache.lookup(&self.revision, filename);
            if cached != Cached::Unknown {
                return Ok(cached.into_path());
            }
        }
        if self.hub.settings.offline {
            return match self.cached(filename)? {
                Cached::Unknown => Err(self.not_cached(filename)),
                cached => Ok(cached.into_path()),
            };
        }
        let target = self.target(filename);
        let url = self
            .hub
            .client
            .file_url(&self.repo_id, &self.revision, filename);
        let head = match self.hub.client.head(&url, &target) {
            Ok(head) => head,
            Err(e) if !e.allows_cache_fallback() => return Err(e),
            Err(e) => {
                let cached = self.cached(filename)?;
                if cached != Cached::Unknown {
                    self.hub.settings.tell(HubEvent::Warning(format!(
                        "using the cached {filename} of {} at {} ({e})",
                        self.repo_id, self.revision
                    )));
                    return Ok(cached.into_path());
                }
                if !e.is_transient() {
                    return Err(e);
                }
                // Nothing cached to fall back on: worth one more try (as `huggingface_hub`).
                std::thread::sleep(std::time::Duration::from_millis(500));
                self.hub.client.head(&url, &target)?
            }
        };
        match head {
            Head::EntryNotFound { commit } => {
                if let Some(commit) = commit {
                    // Best effort, as in Python: a read-only cache must not turn "absent" into an error.
                    let _ = self.cache.mark_absent(&commit, filename);
                    let _ = self.cache.write_ref(&self.revision, &commit);
                }
                Ok(None)
            }
            Head::Found(meta) => self.fetch(filename, &meta, &target).map(Some),
        }
    }

    /// The repository id (`owner/name`).
    pub fn id(&self) -> &str {
        &self.repo_id
    }

    /// "REPO at revision REV", for messages.
    pub fn describe(&self) -> String {
        format!("{} at revision {}", self.repo_id, self.revision)
    }

    /// Where the cache keeps this repo (for messages).
    pub fn cache_folder(&self) -> PathBuf {
        self.cache.root().to_path_buf()
    }

    /// Link (downloading if need be) the file the HEAD described.
    fn fetch(&self, filename: &str, meta: &Metadata, target: &Target) -> Result<PathBuf, HubError> {
        if let Cached::File(path) = self.cache.lookup(&meta.commit, filename) {
            let _ = self.cache.write_ref(&self.revision, &meta.commit);
            return Ok(path);
        }
        self.cache.write_ref(&self.revision, &meta.commit)?;
        let blob = self.cache.blob(&meta.etag);
        if !blob.is_file() {
            let download = download::Download {
                client: &self.hub.client,
                target,
                url: &meta.location,
                etag: &meta.etag,
                size: meta.size,
                settings: &self.hub.settings,
            };
            download.run(&self.cache.incomplete(&meta.etag), &blob)?;
        }
        self.cache.link(&meta.etag, &meta.commit, filename)
    }

    /// What the cache holds for `filename` at the commit this revision last resolved to.
    fn cached(&self, filename: &str) -> Result<Cached, HubError> {
        Ok(match self.cache.commit_for(&self.revision)? {
            Some(commit) => self.cache.lookup(&commit, filename),
            None => Cached::Unknown,
        })
    }

    /// The offline miss: what is missing, where we looked, what to do.
    fn not_cached(&self, filename: &str) -> HubError {
        HubError::NotCached {
            repo: self.repo_id.clone(),
            revision: self.revision.clone(),
            file: filename.to_string(),
            cache: self.cache.root().to_path_buf(),
        }
    }

    fn target<'t>(&'t self, filename: &'t str) -> Target<'t> {
        Target {
            repo: &self.repo_id,
            revision: &self.revision,
            file: filename,
        }
    }

    /// Names become URL and cache paths: refuse what could escape the repo's folder.
    fn validate(&self, filename: &str) -> Result<(), HubError> {
        let invalid = |what, value: &str, reason| HubError::InvalidName {
            what,
            value: value.to_string(),
            reason,
        };
        let id_ok = |part: &str| {
            !part.is_empty()
                && !part.starts_with(['-', '.'])
                && !part.contains("--")
                && !part.contains("..")
                && part
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        };
        let parts: Vec<&str> = self.repo_id.split('/').collect();
        if parts.len() > 2 || !parts.iter().all(|p| id_ok(p)) {
            return Err(invalid(
                "repo id",
                &self.repo_id,
                "expected owner/name of letters, digits, '-', '_' and '.'",
            ));
        }
        if !is_revision(&self.revision) {
            return Err(invalid(
                "revision",
                &self.revision,
                "expected a branch, tag, refs/pr/N or commit",
            ));
        }
        if !is_relative_name(filename) {
            return Err(invalid(
                "file name",
                filename,
                "expected a path inside the repo, such as config.json or sub/dir/file.bin",
            ));
        }
        Ok(())
    }
}

/// A revision as git allows a ref name (`git check-ref-format`), which is what the Hub takes:
/// a relative name without control characters (a newline would make a ref file of that name in
/// the cache), spaces, `~^:?*[`, `@{`, `..` or a component that starts with a dot or ends in
/// `.lock`.
fn is_revision(name: &str) -> bool {
    is_relative_name(name)
        && !name
            .chars()
            .any(|c| c.is_control() || c == ' ' || "~^:?*[".contains(c))
        && !name.contains("@{")
        && !name.contains("..")
        && !name.ends_with('.')
        && name
            .split('/')
            .all(|c| !c.starts_with('.') && !c.ends_with(".lock"))
}

/// A `/`-separated relative name with no empty, `.` or `..` component and no backslash.
fn is_relative_name(name: &str) -> bool {
    !name.is_empty()
        && !name.contains(['\\', '\0'])
        && name
            .split('/')
            .all(|c| !c.is_empty() && c != "." && c != "..")
        && !Path::new(name).is_absolute()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn revisions_are_git_ref_names() {
        for ok in [
            "main",
            "v1.0",
            "refs/pr/15",
            "feature/x-y_z",
            "0123456789abcdef0123456789abcdef01234567",
        ] {
            assert!(is_revision(ok), "{ok} refused");
        }
        for bad in [
            "", "main\n", "a b", "a..b", "../x", "/abs", "x.lock", "a:b", "a@{1}", ".hidden", "x/",
            "tab\t", "nul\0",
        ] {
            assert!(!is_revision(bad), "{bad:?} accepted");
        }
    }

    fn settings(dir: &Path) -> HubSettings {
        HubSettings {
            endpoint: "http://127.0.0.1:9".into(),
            cache_dir: dir.to_path_buf(),
            token: None,
            offline: true,
            progress: false,
            stall_timeout: crate::env::DEFAULT_STALL,
            on_event: None,
        }
    }

    #[test]
    fn names_that_could_escape_the_cache_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let hub = Hub::new(settings(dir.path()));
        for (repo, rev, file) in [
            ("o/n", "main", "../x"),
            ("o/n", "main", "/etc/passwd"),
            ("o/n", "main", "a//b"),
            ("o/n", "main", "a\\b"),
            ("o/n", "../../x", "f"),
            ("o/n/x", "main", "f"),
            ("o/..", "main", "f"),
            ("o--p/n", "main", "f"),
        ] {
            let e = hub.repo(repo, rev).get(file).unwrap_err();
            assert!(
                matches!(e, HubError::InvalidName { .. }),
                "{repo} {rev} {file}: {e}"
            );
        }
    }

    #[test]
    fn offline_miss_says_what_to_do() {
        let dir = tempfile::tempdir().unwrap();
        let hub = Hub::new(settings(dir.path()));
        let repo = hub.repo("o/n", "main");
        let e = repo.get("model.safetensors").unwrap_err().to_string();
        let folder = repo.cache_folder().display().to_string();
        for needle in ["model.safetensors", "o/n", "HF_HUB_OFFLINE", &folder] {
            assert!(e.contains(needle), "{needle} not in: {e}");
        }
        assert!(!e.contains('\n'));
        // What to do instead of the Hub is the front end's to say, from the hint.
        let hint = repo.get("model.safetensors").unwrap_err().hint();
        assert_eq!(
            hint.kind,
            t2tf_core::error::ErrorKind::ModelUnavailable {
                repo: "o/n".into(),
                offline: true
            }
        );
        assert_eq!(hint.option, Some("model"));
    }
}
