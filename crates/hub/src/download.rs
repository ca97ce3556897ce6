//! Moving a blob's bytes into the cache: into `blobs/{etag}.incomplete`, resumed with
//! `Range: bytes=N-` when that file exists, size-checked, sha256-checked for LFS files (64-hex
//! etag), and only then renamed to `blobs/{etag}`. A cut transfer leaves only the `.incomplete`
//! file; a sha mismatch deletes it.
//!
//! Sizes are bounded before and while bytes arrive: a file that is not weights (configs,
//! tokenizers, index files) may have at most [`SMALL_FILE_CAP`] bytes; weights exactly the size
//! the Hub declared (the HEAD's `X-Linked-Size` / `Content-Length`, else the GET's), and a
//! weights file of undeclared size is refused; a body longer than declared is an error. A
//! transfer that gets less than [`STALL_BYTES`] within the stall timeout is retried once from
//! where it stopped, then reported as stalled. The `.incomplete` file is opened without
//! following a symlink (one planted there is replaced, its target untouched).

use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use sha2::{Digest, Sha256};
use t2tf_core::units::human_bytes;

use super::http::{header, Client, Target};
use super::{HubError, HubEvent, HubSettings};

/// Further tries after a transient failure (the HEAD said the file exists; the GET broke).
const RETRIES: u32 = 2;
/// Files below this size download without any output.
const QUIET_BELOW: u64 = 10 << 20;
/// The shortest time between two progress events of a file.
const EVENT_EVERY: Duration = Duration::from_millis(100);
/// The most bytes a file that is not weights may have. Tokenizers are the largest such files
/// (`tokenizer.json` of an XLM-RoBERTa text tower is 17 MB); configs and index files are KBs.
pub(crate) const SMALL_FILE_CAP: u64 = 32 << 20;
/// Bytes a transfer must receive within the stall timeout.
pub(crate) const STALL_BYTES: u64 = 1024;
/// Extensions of weights files, whose size only the Hub's metadata bounds.
const WEIGHTS: [&str; 10] = [
    "safetensors",
    "bin",
    "pt",
    "pth",
    "ckpt",
    "msgpack",
    "h5",
    "onnx",
    "gguf",
    "npz",
];

/// Whether `file` (a name in the repo) holds weights, by its extension.
fn is_weights(file: &str) -> bool {
    file.rsplit_once('.')
        .is_some_and(|(_, ext)| WEIGHTS.iter().any(|w| ext.eq_ignore_ascii_case(w)))
}

/// One blob to fetch.
pub(crate) struct Download<'a> {
    pub client: &'a Client,
    pub target: &'a Target<'a>,
    /// Where the GET goes (after the HEAD's redirects).
    pub url: &'a str,
    pub etag: &'a str,
    /// The size the HEAD announced, if it did.
    pub size: Option<u64>,
    /// Where progress goes (`HubSettings::on_event`).
    pub settings: &'a HubSettings,
}

/// Whether an etag is an LFS sha256 (and so the file's checksum).
pub(crate) fn is_sha256(etag: &str) -> bool {
    etag.len() == 64 && etag.bytes().all(|b| b.is_ascii_hexdigit())
}

impl Download<'_> {
    /// Fetch into `incomplete`, check it, and rename it to `blob`.
    pub(crate) fn run(&self, incomplete: &Path, blob: &Path) -> Result<(), HubError> {
        if let Some(dir) = blob.parent() {
            fs::create_dir_all(dir).map_err(|e| HubError::io(dir, e))?;
        }
        if let Some(size) = self.size {
            self.check_size(size)?;
        }
        let mut part = Partial::open(incomplete, is_sha256(self.etag))?;
        let mut expected = self.size;
        if part.len > expected.unwrap_or(self.cap()) {
            part.restart()?;
        }
        let mut progress = Progress::new(self.settings, self.target.file, expected);
        let (mut tries, mut stalls) = (0, 0);
        while expected != Some(part.len) {
            match self.fetch(&mut part, &mut expected, &mut progress) {
                Ok(()) => break,
                Err(e) if e.is_transient() && tries < RETRIES => {
                    tries += 1;
                    std::thread::sleep(Duration::from_millis(300 * u64::from(tries)));
                }
                // One more try from where it stopped: a stall can be one bad connection.
                Err(HubError::Stalled { .. }) if stalls == 0 => stalls += 1,
                Err(e) => {
                    progress.finish(false);
                    return Err(e);
                }
            }
        }
        progress.finish(true);
        let got = part.finish()?;
        if let Some(got) = got.filter(|g| !g.eq_ignore_ascii_case(self.etag)) {
            fs::remove_file(incomplete).map_err(|e| HubError::io(incomplete, e))?;
            return Err(HubError::Integrity {
                file: self.target.file.to_string(),
                url: self.url.to_string(),
                expected: self.etag.to_string(),
                got,
            });
        }
        fs::rename(incomplete, blob).map_err(|e| HubError::io(blob, e))
    }

    /// One GET from `part.len` on; Ok when the body ended with the announced size.
    fn fetch(
        &self,
        part: &mut Partial,
        expected: &mut Option<u64>,
        progress: &mut Progress,
    ) -> Result<(), HubError> {
        let response = self.client.get(self.url, part.len, self.target)?;
        let total = match response.status().as_u16() {
            206 => {
                let range = header(&response, "content-range").unwrap_or_default();
                match parse_content_range(&range) {
                    Some((start, total)) if start == part.len => total,
                    _ => {
                        part.restart()?;
                        return Err(self.cut(format!("bad Content-Range {range:?} for a resume")));
                    }
                }
            }
            200 => {
                // The server ignored the Range: its body starts at byte 0.
                part.restart()?;
                header(&response, "content-length").and_then(|s| s.trim().parse().ok())
            }
            _ => {
                // 416: the partial file does not fit the blob any more.
                part.restart()?;
                return Err(self.cut("the server refused to resume; starting over".into()));
            }
        };
        match (*expected, total) {
            (Some(want), Some(total)) if total != want => {
                part.restart()?;
                return Err(self.too_large(format!(
                    "the Hub declared {want} bytes, the download announces {total}"
                )));
            }
            (None, Some(total)) => self.check_size(total)?,
            (None, None) if is_weights(self.target.file) => {
                return Err(self.too_large(
                    "the Hub declared no size for this weights file, so it cannot be bounded"
                        .into(),
                ))
            }
            _ => {}
        }
        if expected.is_none() {
            *expected = total;
        }
        let limit = expected.unwrap_or(self.cap());
        progress.set(part.len, *expected);
        let mut body = response.into_body().into_reader();
        let mut buf = vec![0u8; 256 << 10];
        // Progress is measured over windows of the stall timeout: each must bring STALL_BYTES.
        let (mut window, mut window_bytes) = (Instant::now(), 0u64);
        loop {
            let n = match body.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) if window.elapsed() >= self.client.stall || is_timeout(&e) => {
                    return Err(self.stalled())
                }
                Err(e) => {
                    return Err(
                        self.cut(format!("{e} after {} bytes; run again to resume", part.len))
                    )
                }
            };
            if part.len + n as u64 > limit {
                part.restart()?;
                return Err(self.too_large(match *expected {
                    Some(want) => format!("the body is longer than the {want} bytes declared"),
                    None => format!(
                        "more than {} arrived, the most a file that is not weights may have",
                        human_bytes(limit as u128)
                    ),
                }));
            }
            part.append(&buf[..n])?;
            progress.set(part.len, *expected);
            window_bytes += n as u64;
            if window_bytes >= STALL_BYTES {
                (window, window_bytes) = (Instant::now(), 0);
            } else if window.elapsed() >= self.client.stall {
                return Err(self.stalled());
            }
        }
        match *expected {
            Some(want) if part.len != want => Err(self.cut(format!(
                "connection closed after {} of {want} bytes; run again to resume",
                part.len
            ))),
            _ => Ok(()),
        }
    }

    /// The most bytes this file may have when the Hub declared no size.
    fn cap(&self) -> u64 {
        if is_weights(self.target.file) {
            u64::MAX
        } else {
            SMALL_FILE_CAP
        }
    }

    /// Refuse a declared size beyond what a file of this kind may have.
    fn check_size(&self, size: u64) -> Result<(), HubError> {
        if size > self.cap() {
            return Err(self.too_large(format!(
                "the Hub declares {}, more than the {} a file that is not weights may have",
                human_bytes(size as u128),
                human_bytes(self.cap() as u128)
            )));
        }
        Ok(())
    }

    fn too_large(&self, reason: String) -> HubError {
        HubError::TooLarge {
            repo: self.target.repo.to_string(),
            file: self.target.file.to_string(),
            url: self.url.to_string(),
            reason,
        }
    }

    fn stalled(&self) -> HubError {
        HubError::Stalled {
            repo: self.target.repo.to_string(),
            file: self.target.file.to_string(),
            url: self.url.to_string(),
            seconds: self.client.stall.as_secs_f64(),
        }
    }

    /// A transfer that broke off (transient: retried, then reported as a network error).
    fn cut(&self, reason: String) -> HubError {
        HubError::Network {
            repo: self.target.repo.to_string(),
            file: self.target.file.to_string(),
            url: self.url.to_string(),
            reason,
        }
    }
}

/// Whether a read failed for want of bytes within its timeout.
fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
    )
}

/// `bytes START-END/TOTAL` → (START, TOTAL if known).
fn parse_content_range(value: &str) -> Option<(u64, Option<u64>)> {
    let rest = value.trim().strip_prefix("bytes")?.trim_start();
    let (range, total) = rest.split_once('/')?;
    let start = range.split_once('-')?.0.trim().parse().ok()?;
    Some((start, total.trim().parse().ok()))
}

/// The `.incomplete` file and, for LFS files, the sha256 of what it holds so far.
struct Partial {
    path: PathBuf,
    file: File,
    len: u64,
    hasher: Option<Sha256>,
}

impl Partial {
    /// Open (or create) the partial file; when hashing, hash what an earlier run left. A
    /// symlink, a hard link to another file, or anything not a regular file in its place is
    /// not an earlier run's download: the name is removed (never what it leads to) and the
    /// file made anew.
    fn open(path: &Path, hash: bool) -> Result<Partial, HubError> {
        let io = |e| HubError::io(path, e);
        let mut file = match open_own(path) {
            Ok(Some(file)) => file,
            Ok(None) => {
                remove_name(path)?;
                open_own(path)
                    .map_err(io)?
                    .ok_or_else(|| io(std::io::Error::other("replaced while being opened")))?
            }
            Err(_) if fs::symlink_metadata(path).is_ok_and(|m| m.is_symlink()) => {
                remove_name(path)?;
                open_own(path)
                    .map_err(io)?
                    .ok_or_else(|| io(std::io::Error::other("replaced while being opened")))?
            }
            Err(e) => return Err(io(e)),
        };
        let mut hasher = hash.then(Sha256::new);
        let len = match hasher.as_mut() {
            Some(h) => std::io::copy(&mut file, h).map_err(io)?,
            None => file.metadata().map_err(io)?.len(),
        };
        Ok(Partial {
            path: path.to_path_buf(),
            file,
            len,
            hasher,
        })
    }

    fn append(&mut self, bytes: &[u8]) -> Result<(), HubError> {
        self.file
            .write_all(bytes)
            .map_err(|e| HubError::io(&self.path, e))?;
        if let Some(h) = self.hasher.as_mut() {
            h.update(bytes);
        }
        self.len += bytes.len() as u64;
        Ok(())
    }

    fn restart(&mut self) -> Result<(), HubError> {
        self.file
            .set_len(0)
            .map_err(|e| HubError::io(&self.path, e))?;
        self.len = 0;
        if self.hasher.is_some() {
            self.hasher = Some(Sha256::new());
        }
        Ok(())
    }

    /// Flush to disk; the sha256 (hex) when hashing.
    fn finish(self) -> Result<Option<String>, HubError> {
        self.file
            .sync_all()
            .map_err(|e| HubError::io(&self.path, e))?;
        Ok(self
            .hasher
            .map(|h| h.finalize().iter().map(|b| format!("{b:02x}")).collect()))
    }
}

/// Open (or create) `path` for appending without following a symlink or waiting on a FIFO;
/// `None` when what is there is not a regular file with this one name.
fn open_own(path: &Path) -> std::io::Result<Option<File>> {
    let mut options = OpenOptions::new();
    options.read(true).append(true).create(true);
    let file = t2tf_core::platform::no_follow_no_wait(&mut options).open(path)?;
    let meta = file.metadata()?;
    if t2tf_core::platform::hard_links(&file, &meta) > 1 {
        return Ok(None);
    }
    Ok(meta.is_file().then_some(file))
}

/// Remove the name `path` (a symlink itself, or one name of a hard-linked file).
fn remove_name(path: &Path) -> Result<(), HubError> {
    match fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(HubError::io(path, e)),
        _ => Ok(()),
    }
}

/// A download's progress as events for the front end (`HubSettings::on_event`): nothing for
/// small files, or where progress is not wanted.
struct Progress<'a> {
    settings: Option<&'a HubSettings>,
    file: String,
    total: Option<u64>,
    done: u64,
    last: Instant,
}

impl<'a> Progress<'a> {
    fn new(settings: &'a HubSettings, file: &str, total: Option<u64>) -> Progress<'a> {
        let quiet = !settings.progress || total.is_some_and(|t| t < QUIET_BELOW);
        let progress = Progress {
            settings: (!quiet).then_some(settings),
            file: file.to_string(),
            total,
            done: 0,
            last: Instant::now(),
        };
        if let Some(s) = progress.settings {
            s.tell(HubEvent::Started {
                file: progress.file.clone(),
                total,
            });
        }
        progress
    }

    fn set(&mut self, done_now: u64, total: Option<u64>) {
        self.done = done_now;
        self.total = total.or(self.total);
        if let Some(s) = self.settings {
            if self.last.elapsed() >= EVENT_EVERY {
                self.last = Instant::now();
                s.tell(HubEvent::Progress {
                    file: self.file.clone(),
                    done: done_now,
                    total: self.total,
                });
            }
        }
    }

    fn finish(&mut self, ok: bool) {
        if let Some(s) = self.settings {
            s.tell(HubEvent::Finished {
                file: self.file.clone(),
                done: self.done,
                ok,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_range_and_sha_etags() {
        assert_eq!(
            parse_content_range("bytes 10-99/100"),
            Some((10, Some(100)))
        );
        assert_eq!(parse_content_range("bytes 10-99/*"), Some((10, None)));
        assert_eq!(parse_content_range("items 1-2/3"), None);
        assert!(is_sha256(&"a".repeat(64)));
        assert!(!is_sha256(&"a".repeat(40)));
        for w in [
            "model.safetensors",
            "pytorch_model.bin",
            "open_clip_model.PT",
            "sub/x.pth",
        ] {
            assert!(is_weights(w), "{w}");
        }
        for other in [
            "config.json",
            "tokenizer.json",
            "merges.txt",
            "model.safetensors.index.json",
        ] {
            assert!(!is_weights(other), "{other}");
        }
    }

    #[test]
    fn partial_hash_survives_reopen_and_restart() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.incomplete");
        let mut p = Partial::open(&path, true).unwrap();
        p.append(b"hello ").unwrap();
        drop(p);
        let mut p = Partial::open(&path, true).unwrap();
        assert_eq!(p.len, 6);
        p.append(b"world").unwrap();
        let want: String = Sha256::digest(b"hello world")
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        assert_eq!(p.finish().unwrap(), Some(want));
        let mut p = Partial::open(&path, false).unwrap();
        assert_eq!(p.len, 11);
        p.restart().unwrap();
        p.append(b"ab").unwrap();
        assert_eq!(p.finish().unwrap(), None);
        assert_eq!(fs::read(&path).unwrap(), b"ab");
    }
}
