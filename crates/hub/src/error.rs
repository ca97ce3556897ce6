//! What can go wrong talking to the Hub or its cache: one variant per thing the user can act on,
//! each message one line that names the file or URL and says what to do about the Hub; what a
//! front end offers instead (a local model folder, fetching elsewhere) it says from
//! [`HubError::hint`].

use std::path::PathBuf;

use t2tf_core::error::{ErrorKind, Hint};

/// Errors of [`super::HubRepo::get`] and [`super::cached_repos`].
#[derive(Debug, thiserror::Error)]
pub enum HubError {
    /// The Hub could not be reached (DNS, connection, timeout, cut transfer) and the file is not
    /// in the cache.
    #[error(
        "cannot download {file} of {repo} from {url} ({reason}); check the network and HF_ENDPOINT, \
         or use a cache that holds {repo} offline (HF_HUB_OFFLINE=1)"
    )]
    Network {
        /// The repository id (`owner/name`).
        repo: String,
        /// The file within the repository.
        file: String,
        /// The URL requested.
        url: String,
        /// What went wrong, in words.
        reason: String,
    },
    /// 401/403 without a token: the repo is gated or private.
    #[error(
        "{repo} is gated or private (HTTP {status} from {url}): set HF_TOKEN or log in with \
         `huggingface-cli login`, after accepting its licence on {page} if it is gated"
    )]
    AuthRequired {
        /// The repository id (`owner/name`).
        repo: String,
        /// The URL requested.
        url: String,
        /// The HTTP status code.
        status: u16,
        /// The repository's page on the Hub.
        page: String,
    },
    /// 401/403 although a token was sent: the token's account cannot read the repo.
    #[error(
        "{repo}: the token in use has no access (HTTP {status} from {url}): accept the licence on \
         {page} with the token's account, or use another token (HF_TOKEN, `huggingface-cli login`)"
    )]
    AccessDenied {
        /// The repository id (`owner/name`).
        repo: String,
        /// The URL requested.
        url: String,
        /// The HTTP status code.
        status: u16,
        /// The repository's page on the Hub.
        page: String,
    },
    /// `X-Error-Code: RepoNotFound` (the Hub also answers so for private repos it may not show).
    #[error("repo {repo} not found (HTTP {status} from {url}): check the id; {hint}")]
    RepoNotFound {
        /// The repository id (`owner/name`).
        repo: String,
        /// The URL requested.
        url: String,
        /// The HTTP status code.
        status: u16,
        /// What to check next.
        hint: &'static str,
    },
    /// `X-Error-Code: RevisionNotFound`.
    #[error(
        "revision {revision:?} not found in {repo} (HTTP {status} from {url}): check the branch, tag \
         or commit"
    )]
    RevisionNotFound {
        /// The repository id (`owner/name`).
        repo: String,
        /// The branch, tag or commit asked for.
        revision: String,
        /// The URL requested.
        url: String,
        /// The HTTP status code.
        status: u16,
    },
    /// Any other unexpected HTTP status.
    #[error("{url} answered HTTP {status}{detail}; try again later, or use the cache offline (HF_HUB_OFFLINE=1)")]
    Status {
        /// The URL requested.
        url: String,
        /// The HTTP status code.
        status: u16,
        /// The Hub's own error message, if it sent one.
        detail: String,
    },
    /// The server's answer cannot be used (missing headers, redirect without `Location`, ...).
    #[error("unexpected answer from {url}: {reason}; if HF_ENDPOINT is set, check it points to a Hugging Face Hub")]
    BadResponse {
        /// The URL requested.
        url: String,
        /// What went wrong, in words.
        reason: String,
    },
    /// A downloaded LFS file does not hash to its etag; the partial file was deleted.
    #[error(
        "{file} downloaded from {url} is corrupt: expected sha256 {expected}, got {got}; nothing \
         was kept, run again to download it anew"
    )]
    Integrity {
        /// The file within the repository.
        file: String,
        /// The URL requested.
        url: String,
        /// The sha256 the Hub announced (the etag).
        expected: String,
        /// The sha256 of what arrived.
        got: String,
    },
    /// Offline and the file is not in the cache.
    #[error(
        "{file} of {repo} at revision {revision} is not in the Hugging Face cache {} and offline \
         mode is on (HF_HUB_OFFLINE)",
        cache.display()
    )]
    NotCached {
        /// The repository id (`owner/name`).
        repo: String,
        /// The branch, tag or commit asked for.
        revision: String,
        /// The file within the repository.
        file: String,
        /// The cache folder searched.
        cache: PathBuf,
    },
    /// A repo id, revision or file name that cannot be used as a Hub path or a cache path.
    #[error("invalid {what} {value:?}: {reason}")]
    InvalidName {
        /// Which kind of name (repo id, revision, file).
        what: &'static str,
        /// The name given.
        value: String,
        /// What went wrong, in words.
        reason: &'static str,
    },
    /// A download made no progress: less than 1 KiB within the stall timeout, on two tries.
    #[error(
        "downloading {file} of {repo} from {url} stalled: less than 1 KiB arrived in {seconds} s, \
         twice; check the network and run again (the download resumes), or allow more time with \
         T2TF_HUB_STALL_TIMEOUT=SECONDS"
    )]
    Stalled {
        /// The repository id (`owner/name`).
        repo: String,
        /// The file within the repository.
        file: String,
        /// The URL requested.
        url: String,
        /// The stall timeout in seconds.
        seconds: f64,
    },
    /// A file larger than t2tf accepts for its kind, or longer than the Hub declared.
    #[error("{file} of {repo} from {url}: {reason}; nothing was kept")]
    TooLarge {
        /// The repository id (`owner/name`).
        repo: String,
        /// The file within the repository.
        file: String,
        /// The URL requested.
        url: String,
        /// How large, and what the limit is.
        reason: String,
    },
    /// A cache entry leads outside the repo's cache folder (a symlink someone planted): it is
    /// not read.
    #[error(
        "{}: leads outside the Hugging Face cache folder {}; t2tf does not read it: remove it \
         and run again",
        path.display(),
        root.display()
    )]
    OutsideCache {
        /// The entry.
        path: PathBuf,
        /// The repo's cache folder.
        root: PathBuf,
    },
    /// Writing a ref or marker into the cache failed (the message names the file).
    #[error(transparent)]
    Write(#[from] t2tf_core::fs::FsError),
    /// Reading or writing the cache failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

impl HubError {
    /// What a front end needs to word its advice. A repository that cannot be had (offline and
    /// not cached, or the Hub out of reach) is [`ErrorKind::ModelUnavailable`]: the Hub serves
    /// t2tf its CLIP models, so the option that fixes it is the `model`.
    pub fn hint(&self) -> Hint {
        match self {
            HubError::Network { repo, .. } => Hint::new(ErrorKind::ModelUnavailable {
                repo: repo.clone(),
                offline: false,
            })
            .about("model"),
            HubError::NotCached { repo, .. } => Hint::new(ErrorKind::ModelUnavailable {
                repo: repo.clone(),
                offline: true,
            })
            .about("model"),
            HubError::RepoNotFound { .. } => Hint::invalid("model"),
            HubError::RevisionNotFound { .. } => Hint::invalid("revision"),
            HubError::Io { .. } => Hint::new(ErrorKind::Io),
            HubError::Write(e) => e.hint(),
            _ => Hint::other(),
        }
    }

    /// An I/O error on `path`.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> HubError {
        HubError::Io {
            path: path.into(),
            source,
        }
    }

    /// Worth one more try: the network, or the server saying it is busy or broken for now.
    pub(crate) fn is_transient(&self) -> bool {
        match self {
            HubError::Network { .. } => true,
            HubError::Status { status, .. } => *status == 429 || (500..600).contains(status),
            _ => false,
        }
    }

    /// Whether `huggingface_hub` would fall back to an already cached copy after this error:
    /// everything but a definite "no such revision" and local problems.
    pub(crate) fn allows_cache_fallback(&self) -> bool {
        !matches!(
            self,
            HubError::RevisionNotFound { .. }
                | HubError::Integrity { .. }
                | HubError::InvalidName { .. }
                | HubError::Io { .. }
                | HubError::Write(_)
                | HubError::OutsideCache { .. }
                | HubError::TooLarge { .. }
                | HubError::NotCached { .. }
        )
    }
}
