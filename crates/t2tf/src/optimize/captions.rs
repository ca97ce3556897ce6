//! The negative-caption pool and the on-disk cache of its text embeddings.
//!
//! The paper samples 128 negatives per step from LAION captions, which cannot ship; the pool
//! built into the binary is the project's own (`data/captions.txt`, written by
//! `data/make_captions.py`). `--negatives-file` replaces it. The embeddings of the whole pool
//! are computed once per model and caption list and cached under the user cache directory.

use std::collections::HashSet;
use std::io::Read;
use std::path::{Path, PathBuf};

use rand::Rng;
use sha2::{Digest, Sha256};

use super::{CaptionError, OptimizeError};

/// The project's caption pool, one caption per line.
pub(crate) const BUILTIN_CAPTIONS: &str = include_str!("../../../../data/captions.txt");

/// The user negative used when none is given (the paper's "a blank image").
pub(crate) const DEFAULT_USER_NEGATIVE: &str = "a blank image";

/// A deduplicated list of captions to draw negatives from.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptionPool {
    captions: Vec<String>,
}

impl CaptionPool {
    /// The pool shipped with t2tf.
    pub fn builtin() -> CaptionPool {
        CaptionPool::parse(BUILTIN_CAPTIONS)
    }

    /// Captions from text: one per line, surrounding space trimmed, blank lines skipped,
    /// duplicates dropped (first occurrence kept, so the order of the file is kept).
    pub fn parse(text: &str) -> CaptionPool {
        let mut seen = HashSet::new();
        let captions = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && seen.insert(*l))
            .map(str::to_owned)
            .collect();
        CaptionPool { captions }
    }

    /// Read a caption file (`--negatives-file`). An unreadable, non-UTF-8 or empty file is an
    /// error naming the file.
    pub fn from_file(path: &Path) -> Result<CaptionPool, OptimizeError> {
        let path_buf = || path.to_path_buf();
        let bytes = crate::input::read(path).map_err(|error| CaptionError::Read {
            path: path_buf(),
            error,
        })?;
        let text = String::from_utf8(bytes).map_err(|e| CaptionError::NotUtf8 {
            path: path_buf(),
            offset: e.utf8_error().valid_up_to(),
        })?;
        let pool = CaptionPool::parse(&text);
        if pool.is_empty() {
            return Err(CaptionError::Empty { path: path_buf() }.into());
        }
        Ok(pool)
    }

    /// The captions, in the order of the source.
    pub fn captions(&self) -> &[String] {
        &self.captions
    }

    /// How many captions.
    pub fn len(&self) -> usize {
        self.captions.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.captions.is_empty()
    }
}

/// `k` distinct indices into a pool of `n`, uniformly without replacement (all of them,
/// shuffled, when k ≥ n). Deterministic for a seeded `rng`.
pub(crate) fn sample_indices(n: usize, k: usize, rng: &mut impl Rng) -> Vec<usize> {
    rand::seq::index::sample(rng, n, k.min(n)).into_vec()
}

/// The user's negatives, or the default one when none were given. Blank ones are an error
/// (an empty prompt has no meaning to compare against).
pub fn user_negatives(given: &[String]) -> Result<Vec<String>, OptimizeError> {
    if given.is_empty() {
        return Ok(vec![DEFAULT_USER_NEGATIVE.to_owned()]);
    }
    given
        .iter()
        .map(|s| {
            let t = s.trim();
            if t.is_empty() {
                Err(OptimizeError::Setting {
                    name: "negatives",
                    message: "a negative prompt is empty".into(),
                })
            } else {
                Ok(t.to_owned())
            }
        })
        .collect()
}

/// The cache directory of t2tf as the front ends (the CLI, the Python module) find it in the
/// environment: `$XDG_CACHE_HOME/t2tf` where that is set (on every system, as `huggingface_hub`
/// honours it), else the platform's per-user cache folder
/// ([`t2tf_core::platform::cache_dir`]: `~/.cache/t2tf` on Linux, `~/Library/Caches/t2tf` on
/// macOS, `%LOCALAPPDATA%\t2tf\cache` on Windows). The library itself reads no variable:
/// [`crate::pipeline::Job::new`] takes the platform's folder, and a front end sets
/// `Job::caption_cache` to this.
pub fn cache_dir() -> Option<PathBuf> {
    cache_dir_from(std::env::var_os("XDG_CACHE_HOME"))
}

/// [`cache_dir`] for a value of `XDG_CACHE_HOME` (empty counts as unset).
pub fn cache_dir_from(xdg: Option<std::ffi::OsString>) -> Option<PathBuf> {
    match xdg.filter(|v| !v.is_empty()) {
        Some(x) => Some(PathBuf::from(x).join("t2tf")),
        None => t2tf_core::platform::cache_dir(),
    }
}

/// Why the caption cache could not be listed or cleared. The system's error is part of the
/// message and not a `source`: the CLI prints the cause chain, which would say it twice.
#[derive(Debug, thiserror::Error)]
#[error("{}: {action}: {error}", path.display())]
pub struct CacheError {
    /// The file or folder.
    pub path: PathBuf,
    /// What was being done ("cannot list", "cannot remove").
    pub action: &'static str,
    /// What the system said.
    pub error: std::io::Error,
}

/// One file of the caption-embedding cache.
#[derive(Clone, Debug, PartialEq)]
pub struct CacheEntry {
    /// The file.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Captions it holds embeddings of, and their dimension, as its header says.
    pub captions: u64,
    /// Embedding dimension.
    pub dim: u64,
}

/// Folder of the embedding files inside the cache directory.
const EMBEDDINGS: &str = "text-embeddings";

/// The embedding files t2tf wrote in the cache directory `dir` (see [`cache_dir`]), by name.
/// Only files named as t2tf names them (`text-embeddings/<64 hex digits>.bin`) and starting
/// with t2tf's magic count, so [`clear_cache`] never touches a file that is not ours. A
/// missing folder is an empty cache.
pub fn cache_entries(dir: &Path) -> Result<Vec<CacheEntry>, CacheError> {
    let folder = dir.join(EMBEDDINGS);
    let list = match std::fs::read_dir(&folder) {
        Ok(list) => list,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(error) => {
            return Err(CacheError {
                path: folder,
                action: "cannot list",
                error,
            })
        }
    };
    let mut entries = Vec::new();
    for e in list.flatten() {
        let name = e.file_name();
        let Some(stem) = name.to_str().and_then(|n| n.strip_suffix(".bin")) else {
            continue;
        };
        if stem.len() != 64 || !stem.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')) {
            continue;
        }
        let path = e.path();
        // Only the header is read: a cache file may be many megabytes.
        let mut header = [0u8; 56];
        let read = std::fs::File::open(&path).and_then(|mut f| f.read_exact(&mut header));
        let (Ok(()), Ok(meta)) = (read, e.metadata()) else {
            continue;
        };
        // Any version of t2tf's format ("T2TFEMB" and a version digit).
        if !meta.is_file() || header[..7] != MAGIC[..7] {
            continue;
        }
        let word = |at: usize| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&header[at..at + 8]);
            u64::from_le_bytes(w)
        };
        entries.push(CacheEntry {
            path,
            bytes: meta.len(),
            captions: word(40),
            dim: word(48),
        });
    }
    entries.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(entries)
}

/// Remove t2tf's embedding files from the cache directory `dir` (those [`cache_entries`]
/// lists), then the folders they leave empty; anything else there stays. Returns what was
/// removed.
pub fn clear_cache(dir: &Path) -> Result<Vec<CacheEntry>, CacheError> {
    let entries = cache_entries(dir)?;
    for e in &entries {
        match std::fs::remove_file(&e.path) {
            Ok(()) => {}
            // Removed meanwhile (another clear): what was asked for is done.
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => {}
            Err(error) => {
                return Err(CacheError {
                    path: e.path.clone(),
                    action: "cannot remove",
                    error,
                })
            }
        }
    }
    // `remove_dir` removes only an empty folder: a file that is not ours keeps its folder.
    let _ = std::fs::remove_dir(dir.join(EMBEDDINGS));
    let _ = std::fs::remove_dir(dir);
    Ok(entries)
}

/// SHA-256 of a file's bytes, read in 1 MiB chunks: `hash_files` of one file (its tests).
#[cfg(test)]
fn hash_file(path: &Path) -> Result<[u8; 32], OptimizeError> {
    hash_files(&[path.to_path_buf()])
}

/// The cache key's model part: the weights' hash with the tokenizer and config files that
/// turn captions into embeddings with them (another tokenizer, other embeddings).
pub fn model_key(weights_hash: &[u8; 32], others: &[PathBuf]) -> Result<[u8; 32], OptimizeError> {
    let mut h = Sha256::new();
    h.update(weights_hash);
    h.update(hash_files(others)?);
    Ok(h.finalize().into())
}

/// SHA-256 of several files one after the other (a sharded checkpoint); for one file, its
/// SHA-256, so caches keyed by a single weights file stay valid.
pub fn hash_files(paths: &[PathBuf]) -> Result<[u8; 32], OptimizeError> {
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    for path in paths {
        let err = |error: std::io::Error| CaptionError::Hash {
            path: path.clone(),
            error,
        };
        let mut f = crate::input::open(path).map_err(err)?;
        loop {
            let n = f.read(&mut buf).map_err(err)?;
            if n == 0 {
                break;
            }
            h.update(&buf[..n]);
        }
    }
    Ok(h.finalize().into())
}

/// The cache key of (model, caption list): SHA-256 over the model hash and every caption,
/// each caption prefixed by its byte length so that no two lists share a key by concatenation.
pub fn cache_key(model_hash: &[u8], captions: &[String]) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"t2tf text embeddings v1\0");
    h.update((model_hash.len() as u64).to_le_bytes());
    h.update(model_hash);
    h.update((captions.len() as u64).to_le_bytes());
    for c in captions {
        h.update((c.len() as u64).to_le_bytes());
        h.update(c.as_bytes());
    }
    h.finalize().into()
}

/// Version 2 adds the SHA-256 of the values after the header (version 1 files are
/// recomputed: their magic does not match).
const MAGIC: &[u8; 8] = b"T2TFEMB2";
const HEADER: usize = 8 + 32 + 8 + 8 + 32;

/// Where the embeddings for `key` live inside the cache directory `dir`.
pub(crate) fn cache_path(dir: &Path, key: &[u8; 32]) -> PathBuf {
    let hex: String = key.iter().map(|b| format!("{b:02x}")).collect();
    dir.join(EMBEDDINGS).join(format!("{hex}.bin"))
}

/// Serialize embeddings: magic, key, count (u64), dimension (u64), SHA-256 of the values,
/// then count × dim f32, all little-endian. The checksum catches a file changed on disk
/// (flipped bytes keep the size and the finiteness, and would silently change the TF).
fn encode(key: &[u8; 32], embeddings: &[Vec<f32>]) -> Vec<u8> {
    let dim = embeddings.first().map_or(0, Vec::len);
    let values: Vec<u8> = embeddings
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let mut out = Vec::with_capacity(HEADER + values.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(key);
    out.extend_from_slice(&(embeddings.len() as u64).to_le_bytes());
    out.extend_from_slice(&(dim as u64).to_le_bytes());
    out.extend_from_slice(&Sha256::digest(&values));
    out.extend_from_slice(&values);
    out
}

/// Parse a cache file; `None` for anything that does not match `key` and `count` exactly
/// (other model, other list, truncated or foreign file, non-finite values).
fn decode(bytes: &[u8], key: &[u8; 32], count: usize) -> Option<Vec<Vec<f32>>> {
    if bytes.len() < HEADER || &bytes[..8] != MAGIC || &bytes[8..40] != key {
        return None;
    }
    let n = u64::from_le_bytes(bytes[40..48].try_into().ok()?) as usize;
    let dim = u64::from_le_bytes(bytes[48..56].try_into().ok()?) as usize;
    if n != count
        || dim == 0
        || bytes.len() != HEADER.checked_add(n.checked_mul(dim)?.checked_mul(4)?)?
        || Sha256::digest(&bytes[HEADER..]).as_slice() != &bytes[56..HEADER]
    {
        return None;
    }
    let values: Vec<f32> = bytes[HEADER..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if values.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some(values.chunks_exact(dim).map(<[f32]>::to_vec).collect())
}

/// How the caption cache (`cached_embeddings`) got its result.
#[derive(Clone, Debug, PartialEq)]
pub enum CacheOutcome {
    /// Read from the cache file.
    Hit(PathBuf),
    /// Computed and written to the cache file.
    Stored(PathBuf),
    /// Computed; the cache could not be written (the reason, for a warning). Not an error:
    /// a read-only home must not stop an optimization.
    NotStored(String),
}

/// The embeddings of `captions` under the model with hash `model_hash`: from the cache in
/// `dir` when a matching file is there, else from `compute` (then stored atomically).
/// A cache file that does not match is recomputed and replaced, never an error.
pub(crate) fn cached_embeddings<E>(
    dir: Option<&Path>,
    model_hash: &[u8],
    captions: &[String],
    compute: impl FnOnce(&[String]) -> Result<Vec<Vec<f32>>, E>,
) -> Result<(Vec<Vec<f32>>, CacheOutcome), E> {
    let key = cache_key(model_hash, captions);
    let path = dir.map(|d| cache_path(d, &key));
    if let Some(p) = &path {
        if let Some(e) =
            read_cache(p, captions.len()).and_then(|b| decode(&b, &key, captions.len()))
        {
            return Ok((e, CacheOutcome::Hit(p.clone())));
        }
    }
    let emb = compute(captions)?;
    let outcome = match path {
        None => CacheOutcome::NotStored(
            "no cache directory (neither XDG_CACHE_HOME nor HOME is set)".into(),
        ),
        Some(p) => match store(&p, &key, &emb) {
            Ok(()) => CacheOutcome::Stored(p),
            Err(e) => CacheOutcome::NotStored(e.to_string()),
        },
    };
    Ok((emb, outcome))
}

/// Widest embedding a cache file may hold: a bound on what is read, so a file planted in the
/// cache's place (a FIFO, `/dev/zero`, a huge file) is skipped, never read to the end.
const MAX_DIM: usize = 16384;

/// The cache file's bytes if it is a regular file no larger than `count` embeddings of at
/// most [`MAX_DIM`] values can be (else `None`: recomputed and replaced).
fn read_cache(path: &Path, count: usize) -> Option<Vec<u8>> {
    use std::io::Read;
    let limit = HEADER.checked_add(count.checked_mul(MAX_DIM)?.checked_mul(4)?)?;
    let file = crate::input::open(path).ok()?;
    let len = usize::try_from(file.metadata().ok()?.len()).ok()?;
    if len > limit {
        return None;
    }
    let mut bytes = Vec::with_capacity(len);
    file.take(limit as u64 + 1).read_to_end(&mut bytes).ok()?;
    (bytes.len() <= limit).then_some(bytes)
}

/// Why the cache file could not be written (a warning, never an error of the run).
#[derive(Debug, thiserror::Error)]
enum StoreError {
    #[error("{0}: embeddings have unequal or zero length; not cached")]
    Shape(PathBuf),
    #[error("{path}: cannot create: {source}")]
    Dir {
        path: PathBuf,
        source: std::io::Error,
    },
    /// `crate::fs::atomic_replace_bytes`'s error (it names the file).
    #[error(transparent)]
    Write(#[from] crate::fs::FsError),
}

fn store(path: &Path, key: &[u8; 32], emb: &[Vec<f32>]) -> Result<(), StoreError> {
    let dim = emb.first().map_or(0, Vec::len);
    if dim == 0 || emb.iter().any(|e| e.len() != dim) {
        return Err(StoreError::Shape(path.to_path_buf()));
    }
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|source| StoreError::Dir {
            path: parent.to_path_buf(),
            source,
        })?;
    }
    // The cache folder is t2tf's own: a symlink planted at the name is replaced, not followed.
    Ok(crate::fs::atomic_replace_bytes(path, &encode(key, emb))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn builtin_pool_is_large_deduplicated_and_short() {
        let pool = CaptionPool::builtin();
        assert!(pool.len() >= 5000, "{}", pool.len());
        let lines = BUILTIN_CAPTIONS.lines().count();
        assert_eq!(
            lines,
            pool.len(),
            "the shipped file must already be deduplicated"
        );
        // CLIP's context is 77 tokens; every caption is well inside it (≤ 80 characters).
        assert!(pool
            .captions()
            .iter()
            .all(|c| c.len() <= 80 && !c.is_empty()));
        let words: HashSet<&str> = pool.captions().iter().flat_map(|c| c.split(' ')).collect();
        assert!(words.len() > 300, "vocabulary too small: {}", words.len());
    }

    #[test]
    fn parse_trims_skips_blank_and_dedups_in_order() {
        let p = CaptionPool::parse("b cat\n\n  a dog \r\nb cat\n a dog\n");
        assert_eq!(p.captions(), &["b cat".to_string(), "a dog".to_string()]);
    }

    #[test]
    fn file_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let empty = dir.path().join("empty.txt");
        std::fs::write(&empty, "\n  \n").unwrap();
        let m = CaptionPool::from_file(&empty).unwrap_err().to_string();
        assert!(m.contains("empty.txt") && m.contains("no captions"), "{m}");
        let bin = dir.path().join("bin.txt");
        std::fs::write(&bin, [b'a', 0xff, b'b']).unwrap();
        let m = CaptionPool::from_file(&bin).unwrap_err().to_string();
        assert!(m.contains("bin.txt") && m.contains("UTF-8"), "{m}");
        let m = CaptionPool::from_file(&dir.path().join("missing.txt"))
            .unwrap_err()
            .to_string();
        assert!(m.contains("missing.txt"), "{m}");
        let ok = dir.path().join("ok.txt");
        std::fs::write(&ok, "one\ntwo\n").unwrap();
        assert_eq!(CaptionPool::from_file(&ok).unwrap().len(), 2);
    }

    #[test]
    fn sampling_is_seeded_distinct_and_bounded() {
        let a = sample_indices(6000, 128, &mut ChaCha8Rng::seed_from_u64(3));
        let b = sample_indices(6000, 128, &mut ChaCha8Rng::seed_from_u64(3));
        let c = sample_indices(6000, 128, &mut ChaCha8Rng::seed_from_u64(4));
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_eq!(a.iter().collect::<HashSet<_>>().len(), 128);
        assert!(a.iter().all(|&i| i < 6000));
        let mut all = sample_indices(5, 128, &mut ChaCha8Rng::seed_from_u64(3));
        all.sort();
        assert_eq!(all, vec![0, 1, 2, 3, 4]);
        assert!(sample_indices(0, 128, &mut ChaCha8Rng::seed_from_u64(3)).is_empty());
    }

    #[test]
    fn user_negatives_default_and_blank() {
        assert_eq!(user_negatives(&[]).unwrap(), vec!["a blank image"]);
        assert_eq!(
            user_negatives(&[" a human skull ".into()]).unwrap(),
            vec!["a human skull"]
        );
        assert!(user_negatives(&["  ".into()]).is_err());
    }

    #[test]
    fn cache_round_trips_and_recomputes_on_mismatch() {
        let dir = tempfile::tempdir().unwrap();
        let caps: Vec<String> = vec!["a dog".into(), "a cat".into()];
        let emb = vec![vec![1.0f32, -2.5, 3.25], vec![0.0, 1e-30, -7.0]];
        let calls = std::cell::Cell::new(0);
        let compute = |c: &[String]| -> Result<Vec<Vec<f32>>, ()> {
            calls.set(calls.get() + 1);
            assert_eq!(c.len(), 2);
            Ok(emb.clone())
        };
        let (e1, o1) = cached_embeddings(Some(dir.path()), b"model A", &caps, compute).unwrap();
        assert!(matches!(o1, CacheOutcome::Stored(_)), "{o1:?}");
        let (e2, o2) = cached_embeddings(Some(dir.path()), b"model A", &caps, compute).unwrap();
        assert!(matches!(o2, CacheOutcome::Hit(_)), "{o2:?}");
        assert_eq!(e1, emb);
        assert_eq!(e2, emb);
        assert_eq!(calls.get(), 1);
        // Another model or another caption list: a different key, so a recompute.
        cached_embeddings(Some(dir.path()), b"model B", &caps, compute).unwrap();
        let other: Vec<String> = vec!["a dog".into(), "a cow".into()];
        cached_embeddings(Some(dir.path()), b"model A", &other, compute).unwrap();
        assert_eq!(calls.get(), 3);
        // A corrupt file under the right name is recomputed and replaced.
        let p = cache_path(dir.path(), &cache_key(b"model A", &caps));
        let mut bytes = std::fs::read(&p).unwrap();
        bytes.truncate(bytes.len() - 1);
        std::fs::write(&p, &bytes).unwrap();
        let (e3, o3) = cached_embeddings(Some(dir.path()), b"model A", &caps, compute).unwrap();
        assert!(matches!(o3, CacheOutcome::Stored(_)));
        assert_eq!(e3, emb);
        assert_eq!(calls.get(), 4);
        assert_eq!(std::fs::read(&p).unwrap().len(), HEADER + 2 * 3 * 4);
        // Two bytes of a value swapped: same size, still finite, caught by the checksum.
        let mut bytes = std::fs::read(&p).unwrap();
        bytes.swap(HEADER + 2, HEADER + 3);
        std::fs::write(&p, &bytes).unwrap();
        let (e4, o4) = cached_embeddings(Some(dir.path()), b"model A", &caps, compute).unwrap();
        assert!(matches!(o4, CacheOutcome::Stored(_)), "{o4:?}");
        assert_eq!(e4, emb);
        assert_eq!(calls.get(), 5);
    }

    #[test]
    fn clear_removes_only_our_files() {
        let dir = tempfile::tempdir().unwrap();
        let cache = dir.path().join("t2tf");
        assert!(
            cache_entries(&cache).unwrap().is_empty(),
            "a missing cache is empty"
        );
        let emb = vec![vec![0.5f32; 4]; 3];
        let mut ours = Vec::new();
        for text in ["a", "b"] {
            let key = cache_key(b"model", &[text.to_string()]);
            let path = cache_path(&cache, &key);
            store(&path, &key, &emb).unwrap();
            ours.push(path);
        }
        let folder = cache.join(EMBEDDINGS);
        // Not ours: another name, and our name pattern holding another program's bytes.
        let foreign = [
            folder.join("notes.txt"),
            folder.join(format!("{}.bin", "f".repeat(64))),
            cache.join("other-tool.db"),
        ];
        for f in &foreign {
            std::fs::write(f, b"not t2tf's: keep me").unwrap();
        }
        let listed = cache_entries(&cache).unwrap();
        let mut paths: Vec<_> = listed.iter().map(|e| e.path.clone()).collect();
        ours.sort();
        paths.sort();
        assert_eq!(paths, ours);
        for e in &listed {
            assert_eq!((e.captions, e.dim), (3, 4));
            assert_eq!(e.bytes, (HEADER + 3 * 4 * 4) as u64);
        }
        let removed = clear_cache(&cache).unwrap();
        assert_eq!(removed, listed);
        for p in &ours {
            assert!(!p.exists(), "{} not removed", p.display());
        }
        for f in &foreign {
            assert!(f.is_file(), "{} removed", f.display());
        }
        assert!(cache_entries(&cache).unwrap().is_empty());
        // With nothing else there, the folders go too.
        for f in &foreign {
            std::fs::remove_file(f).unwrap();
        }
        let key = cache_key(b"model", &["c".to_string()]);
        store(&cache_path(&cache, &key), &key, &emb).unwrap();
        assert_eq!(clear_cache(&cache).unwrap().len(), 1);
        assert!(!cache.exists());
    }

    #[test]
    fn a_special_or_huge_file_in_the_caches_place_is_never_read() {
        let dir = tempfile::tempdir().unwrap();
        let caps: Vec<String> = vec!["a dog".into()];
        let compute = |_: &[String]| -> Result<Vec<Vec<f32>>, ()> { Ok(vec![vec![0.5, 1.5]]) };
        let p = cache_path(dir.path(), &cache_key(b"m", &caps));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        // A FIFO without a writer: reading it would hang the run. It is skipped, and, not
        // being a file t2tf may replace, left with a warning.
        let made = std::process::Command::new("mkfifo").arg(&p).status();
        if made.is_ok_and(|s| s.success()) {
            let (e, o) = cached_embeddings(Some(dir.path()), b"m", &caps, compute).unwrap();
            assert_eq!(e, vec![vec![0.5, 1.5]]);
            assert!(
                matches!(&o, CacheOutcome::NotStored(w) if w.contains("FIFO")),
                "{o:?}"
            );
            std::fs::remove_file(&p).unwrap();
        }
        // Larger than one caption's embeddings can be: not read, recomputed.
        std::fs::write(&p, vec![0u8; HEADER + MAX_DIM * 4 + 1]).unwrap();
        assert_eq!(read_cache(&p, 1), None);
        let (e, o) = cached_embeddings(Some(dir.path()), b"m", &caps, compute).unwrap();
        assert!(matches!(o, CacheOutcome::Stored(_)), "{o:?}");
        assert_eq!(e, vec![vec![0.5, 1.5]]);
        assert!(read_cache(&p, 1).is_some());
    }

    #[test]
    fn cache_key_separates_concatenations() {
        let a = cache_key(b"m", &["ab".into(), "c".into()]);
        let b = cache_key(b"m", &["a".into(), "bc".into()]);
        assert_ne!(a, b);
    }

    #[test]
    fn unwritable_cache_is_a_warning_not_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("not-a-dir");
        std::fs::write(&file, "x").unwrap();
        let caps: Vec<String> = vec!["a dog".into()];
        let (e, o) = cached_embeddings(Some(&file), b"m", &caps, |_| {
            Ok::<_, ()>(vec![vec![1.0f32]])
        })
        .unwrap();
        assert_eq!(e, vec![vec![1.0]]);
        assert!(matches!(o, CacheOutcome::NotStored(_)), "{o:?}");
    }

    #[test]
    fn hash_file_matches_known_sha256() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("w.bin");
        std::fs::write(&p, b"abc").unwrap();
        let h = hash_file(&p).unwrap();
        let hex: String = h.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(
            hex,
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert!(hash_file(&dir.path().join("none")).is_err());
    }
}
