//! Output files: every file goes to a temporary beside its target and is renamed over it, so
//! an interrupted run never leaves a partial file under the final name; only regular files are
//! written; a run's files go out as one set (staged in a hidden folder, then moved in with
//! `report.json` last); a lock keeps two runs out of one folder; files left by killed runs are
//! removed by the next one.
//!
//! Symlinks: a path the user names (`render --out FILE`, `convert IN OUT`) that is a symlink is
//! followed only when every link on the way belongs to the caller (the effective uid), as
//! Linux's `protected_symlinks` reasons: a link someone else planted is refused, never written
//! through. Inside a folder t2tf owns the names of (an output folder, the caption cache) no
//! symlink is ever followed: a finished file is renamed over the name, so a link there is
//! replaced, not its target; the lock file is opened without following a link (`O_NOFOLLOW`,
//! on Windows `FILE_FLAG_OPEN_REPARSE_POINT`: [`platform::no_follow`]); temporaries are
//! created new (`O_CREAT|O_EXCL`, never following) under random names; stale files are
//! removed by name (`unlink` removes a link, never its target).

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::platform;

/// Why an output file or folder could not be written; every message names the file or
/// folder. The system's error is part of the message and not a `source`: the CLI prints the
/// cause chain (`{:#}`), which would say it twice.
#[derive(Debug, thiserror::Error)]
pub enum FsError {
    /// An operation on `path` failed (`action` says which: "writing failed", "cannot list", …).
    #[error("{}: {action}: {error}", path.display())]
    Io {
        /// The file or folder (as the user named it where there is such a name).
        path: PathBuf,
        /// What was being done, in the words of the message.
        action: &'static str,
        /// What the system said.
        error: std::io::Error,
    },
    /// The name exists and is a folder, device, FIFO or socket, which a file must not replace.
    #[error("{}: exists and is not a regular file ({kind}); t2tf writes regular files only: choose another name", path.display())]
    NotRegular {
        /// The name given.
        path: PathBuf,
        /// What it is ("a folder", "a device", …).
        kind: &'static str,
    },
    /// The chain of symlinks is longer than Linux follows (or loops).
    #[error("{}: too many levels of symlinks", path.display())]
    TooManyLinks {
        /// The name given.
        path: PathBuf,
    },
    /// A symlink on the way to an output belongs to another user: not followed.
    #[error("{}: {} is a symlink owned by another user (uid {owner}); t2tf follows only the caller's own symlinks: remove it or choose another name", path.display(), if link == path { "this".to_string() } else { link.display().to_string() })]
    ForeignLink {
        /// The name given.
        path: PathBuf,
        /// The link that is not the caller's (`path` itself, or a link it leads to).
        link: PathBuf,
        /// The link's owner.
        owner: u32,
    },
    /// A temporary (or the lock file, or the staging folder) cannot be created in `dir`.
    #[error("{}: cannot create a file in {}: {why}", path.display(), dir.display())]
    Folder {
        /// The file that was to be written.
        path: PathBuf,
        /// Its folder.
        dir: PathBuf,
        /// Why, without the temporary's name.
        why: String,
    },
    /// `--out` names something that is not a folder.
    #[error("{}: the output folder exists and is not a folder", dir.display())]
    NotAFolder {
        /// The name given as `--out`.
        dir: PathBuf,
    },
    /// Another run holds the lock of the output folder.
    #[error("{}: another t2tf run ({who}) is writing into this folder; wait for it to finish or choose another output folder", dir.display())]
    Busy {
        /// The output folder.
        dir: PathBuf,
        /// "process PID", or "another process" when the lock file does not say.
        who: String,
    },
    /// The staging folder of an output set could not be created.
    #[error("cannot stage the output files: {0}")]
    Stage(Box<FsError>),
    /// A staged file could not be moved into the output folder; it stays staged.
    #[error("{}: cannot move the finished file into place (it is kept at {}): {error}", to.display(), from.display())]
    Move {
        /// The staged file.
        from: PathBuf,
        /// Where it was to go.
        to: PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
}

impl FsError {
    /// What a front end needs to word its advice: the system's error, or another.
    pub fn hint(&self) -> crate::error::Hint {
        use crate::error::{ErrorKind, Hint};
        match self {
            FsError::Io { .. } | FsError::Move { .. } => Hint::new(ErrorKind::Io),
            FsError::Stage(e) => e.hint(),
            _ => Hint::other(),
        }
    }

    /// `map_err` adapter: the io error of `action` on `path`.
    fn io<'a>(path: &'a Path, action: &'static str) -> impl Fn(std::io::Error) -> FsError + 'a {
        move |error| FsError::Io {
            path: path.to_path_buf(),
            action,
            error,
        }
    }
}

type Result<T, E = FsError> = std::result::Result<T, E>;

/// Prefix of every temporary t2tf leaves beside an output (`.t2tf-PID-XXXXXX.partial`).
const PARTIAL_PREFIX: &str = ".t2tf-";
const PARTIAL_SUFFIX: &str = ".partial";
/// Folder a run stages its output set in (`.t2tf-set-PID`), inside `--out`.
const SET_PREFIX: &str = ".t2tf-set-";
/// The file that holds the lock of an output folder.
pub const LOCK_NAME: &str = ".t2tf.lock";
/// Written last in a set: while it is missing from the output folder, the set is incomplete.
pub const MANIFEST: &str = "report.json";

/// Symlinks followed before giving up (Linux's own limit).
const MAX_LINKS: usize = 40;

/// The end of `path`'s chain of symlinks, following only links owned by the caller, and what
/// is there (`None`: nothing). A link of another user is `FsError::ForeignLink`.
fn resolve_own_links(path: &Path) -> Result<(PathBuf, Option<std::fs::Metadata>)> {
    let mut target = path.to_path_buf();
    for _ in 0..MAX_LINKS {
        let meta = match std::fs::symlink_metadata(&target) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((target, None)),
            Err(e) => return Err(FsError::io(path, "cannot inspect the output")(e)),
        };
        if !meta.file_type().is_symlink() {
            return Ok((target, Some(meta)));
        }
        let (own, owner) = platform::link_owned_by_caller(&meta);
        if !own {
            return Err(FsError::ForeignLink {
                path: path.to_path_buf(),
                link: target,
                owner,
            });
        }
        let link =
            std::fs::read_link(&target).map_err(FsError::io(path, "cannot read the symlink"))?;
        target = match target.parent() {
            Some(dir) if link.is_relative() => dir.join(link),
            _ => link,
        };
    }
    Err(FsError::TooManyLinks {
        path: path.to_path_buf(),
    })
}

/// The file that writing the user-named `path` replaces: `path` itself, or the end of its
/// chain of symlinks when every link in it is the caller's (another user's link is refused).
/// Refuses anything that exists and is not a regular file: a device, a FIFO, a socket or a
/// folder is not ours to replace with a file.
pub fn output_target(path: &Path) -> Result<PathBuf> {
    let (target, meta) = resolve_own_links(path)?;
    match meta {
        Some(m) if !m.file_type().is_file() => Err(FsError::NotRegular {
            path: path.to_path_buf(),
            kind: kind_name(&m.file_type()),
        }),
        _ => Ok(target),
    }
}

/// Check that the name `path` in a folder t2tf owns may be replaced by a file: free, a regular
/// file or a symlink (the link itself is replaced, never followed). Runs call it for every
/// file of their set before any work, and again as they write.
pub fn replaceable(path: &Path) -> Result<()> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if !(m.file_type().is_file() || m.file_type().is_symlink()) => {
            Err(FsError::NotRegular {
                path: path.to_path_buf(),
                kind: kind_name(&m.file_type()),
            })
        }
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(FsError::io(path, "cannot inspect the output")(e)),
    }
}

fn kind_name(kind: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_char_device() || kind.is_block_device() {
            return "a device";
        }
        if kind.is_fifo() {
            return "a FIFO";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    if kind.is_dir() {
        "a folder"
    } else {
        "not a plain file"
    }
}

fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Write the user-named `path` through `fill`; the file appears under its name only if
/// `fill` succeeds. A symlink at `path` is followed when it is the caller's (`output_target`).
pub fn atomic_write(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    let target = output_target(path)?;
    write_then_rename(path, &target, fill)
}

/// Write `path`, a name in a folder t2tf owns (a cache), through `fill`: the finished file is
/// renamed over the name itself, so a symlink there is replaced and its target never touched.
pub fn atomic_replace(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    replaceable(path)?;
    write_then_rename(path, path, fill)
}

/// `fill` a temporary beside `target`, then rename it over `target` (rename(2) replaces the
/// name: a symlink there is replaced, not followed). `path` names the file in messages.
fn write_then_rename(
    path: &Path,
    target: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    let dir = parent_of(target);
    let mut tmp = temporary(path, dir)?;
    {
        let mut w = BufWriter::new(tmp.as_file_mut());
        fill(&mut w)
            .and_then(|()| w.flush())
            .map_err(FsError::io(path, "writing failed"))?;
    }
    tmp.as_file()
        .sync_all()
        .map_err(FsError::io(path, "writing failed"))?;
    tmp.persist(target)
        .map_err(|e| FsError::io(path, "cannot rename the finished file into place")(e.error))?;
    Ok(())
}

/// A new temporary in `dir` for the output `path`: a random name, created with
/// `O_CREAT|O_EXCL|O_NOFOLLOW` (a name that exists, a symlink included, is never opened; another
/// random name is tried), mode 0644 before the umask (outputs are ordinary user files). Removed
/// when dropped unless persisted.
fn temporary(path: &Path, dir: &Path) -> Result<tempfile::NamedTempFile> {
    // The PID in the name lets a later run tell a dead run's temporary from a live one's.
    let prefix = format!("{PARTIAL_PREFIX}{}-", std::process::id());
    tempfile::Builder::new()
        .prefix(&prefix)
        .suffix(PARTIAL_SUFFIX)
        .make_in(dir, |name| {
            let mut o = std::fs::OpenOptions::new();
            o.read(true).write(true).create_new(true);
            platform::no_follow(&mut o).open(name)
        })
        // tempfile's error names its own temporary file, which the user never asked for: say
        // what went wrong with the folder instead.
        .map_err(|e| folder_error(path, dir, &e))
}

fn folder_error(path: &Path, dir: &Path, e: &std::io::Error) -> FsError {
    let why = match e.kind() {
        std::io::ErrorKind::NotFound => "the folder does not exist".to_string(),
        kind => std::io::Error::from(kind).to_string(),
    };
    FsError::Folder {
        path: path.to_path_buf(),
        dir: dir.to_path_buf(),
        why,
    }
}

/// Atomically write a byte string to a user-named path (`atomic_write`).
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic_write(path, |w| w.write_all(bytes))
}

/// Atomically write a byte string to a name in a folder t2tf owns (`atomic_replace`).
pub fn atomic_replace_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic_replace(path, |w| w.write_all(bytes))
}

/// Check before any work that a file can be written at the user-named `path`: the name is
/// free or a regular file (or the caller's symlink to one), and its folder accepts new files.
pub fn check_writable(path: &Path) -> Result<()> {
    let target = output_target(path)?;
    temporary(path, parent_of(&target))?;
    Ok(())
}

/// The PID in a name `PREFIX<pid>…`, if the name has that form.
fn pid_after(name: &str, prefix: &str) -> Option<u32> {
    let rest = name.strip_prefix(prefix)?;
    let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
    digits.parse().ok()
}

/// Remove what killed runs left in `dir`: `.t2tf-PID-*.partial` temporaries of dead processes,
/// and their staging folders (a staged set that was complete is moved in first, so the folder
/// holds the newest complete set). Returns the names removed or finished.
pub fn clean_stale(dir: &Path) -> Result<Vec<String>> {
    let mut done = Vec::new();
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(done),
        Err(e) => return Err(FsError::io(dir, "cannot list the output folder")(e)),
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        // The entry's own type: a symlink named like a staging folder is not ours to follow.
        let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
        if let Some(pid) = pid_after(&name, SET_PREFIX) {
            if is_dir && !platform::process_alive(pid) {
                finish_or_drop_set(dir, &entry.path())?;
                done.push(name);
            }
        } else if name.ends_with(PARTIAL_SUFFIX) {
            let dead =
                pid_after(&name, PARTIAL_PREFIX).is_none_or(|pid| !platform::process_alive(pid));
            // unlink removes the name (a symlink itself, never its target).
            if dead && std::fs::remove_file(entry.path()).is_ok() {
                done.push(name);
            }
        }
    }
    Ok(done)
}

fn finish_or_drop_set(dir: &Path, staged: &Path) -> Result<()> {
    let manifest = std::fs::symlink_metadata(staged.join(MANIFEST));
    if manifest.is_ok_and(|m| m.file_type().is_file()) {
        let set = OutputSet {
            out: dir.to_path_buf(),
            staging: staged.to_path_buf(),
        };
        let names = set.staged_names()?;
        set.commit(&names)
    } else {
        std::fs::remove_dir_all(staged).map_err(FsError::io(staged, "cannot remove a stale folder"))
    }
}

/// An exclusive lock on an output folder, held while a run writes into it (a lock on
/// `.t2tf.lock`: `flock` on Unix, `LockFileEx` on Windows, released by the system however the
/// process ends, so a killed run never leaves the folder locked). The file holds the owner's
/// PID for the error message (on Windows the lock keeps others from reading it: "another
/// process"), and is removed when the lock is dropped; a killed run leaves it behind,
/// unlocked, and the next run takes it over.
#[derive(Debug)]
pub struct OutputLock {
    /// Open (and locked) until the lock is dropped.
    file: Option<std::fs::File>,
    path: PathBuf,
    /// The folder, if this lock created it: a run that fails before writing anything takes
    /// it away again rather than leave an empty folder behind.
    created: Option<PathBuf>,
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while the lock is still held, so no other run holds a lock on it then;
        // one that opened it and waits finds, once it gets the lock, that the name no longer
        // leads to its file, and starts over (`acquire`).
        if let Some(file) = self.file.take() {
            if is_current(&file, &self.path) {
                let _ = std::fs::remove_file(&self.path);
            }
            // Closed before the folder is removed: where a removed file keeps its name until
            // its last handle closes (Windows without POSIX deletes), the folder empties now.
            drop(file);
        }
        let Some(dir) = &self.created else { return };
        let empty = std::fs::read_dir(dir).is_ok_and(|mut entries| entries.next().is_none());
        if empty {
            let _ = std::fs::remove_dir(dir);
        }
    }
}

/// Attempts at locking a lock file that the holder removed between our open and our lock.
/// Each failure means another run ended in that instant; a few in a row are already unlikely.
const LOCK_ATTEMPTS: usize = 100;

impl OutputLock {
    /// Lock `dir` (created if missing) or fail naming the process that holds it.
    pub fn acquire(dir: &Path) -> Result<OutputLock> {
        // `--out` itself is a name the user gave: a symlink there is followed only if theirs.
        resolve_own_links(dir)?;
        let created = (!dir.exists()).then(|| dir.to_path_buf());
        std::fs::create_dir_all(dir)
            .map_err(FsError::io(dir, "cannot create the output folder"))?;
        if !dir.is_dir() {
            return Err(FsError::NotAFolder {
                dir: dir.to_path_buf(),
            });
        }
        let path = dir.join(LOCK_NAME);
        for _ in 0..LOCK_ATTEMPTS {
            let Some(mut file) = open_lock_file(&path, dir)? else {
                continue;
            };
            let locked =
                lock_file(&file).map_err(FsError::io(&path, "cannot lock the lock file"))?;
            if !locked {
                return Err(busy(dir, &mut file));
            }
            // The previous holder removes the file as it ends: a lock on a removed file locks
            // nothing another run can see, so open the name again.
            if !is_current(&file, &path) {
                continue;
            }
            file.set_len(0)
                .and_then(|()| writeln!(file, "{}", std::process::id()))
                .map_err(FsError::io(dir, "cannot write to the output folder"))?;
            return Ok(OutputLock {
                file: Some(file),
                path,
                created,
            });
        }
        Err(FsError::Busy {
            dir: dir.to_path_buf(),
            who: "another process".to_string(),
        })
    }
}

/// Open (or create) the lock file without following a symlink ([`platform::no_follow_no_wait`]:
/// `O_NOFOLLOW`, and `O_NONBLOCK` so a FIFO in its place cannot hang the open). A symlink or a hard link to some other file in
/// its place is not ours: the name is removed (never what it leads to) and `None` asks the
/// caller to try again. Anything else that is not a regular file is refused.
fn open_lock_file(path: &Path, dir: &Path) -> Result<Option<std::fs::File>> {
    let mut o = std::fs::OpenOptions::new();
    o.read(true).write(true).create(true).truncate(false);
    let file = match platform::no_follow_no_wait(&mut o).open(path) {
        Ok(f) => f,
        Err(e) => {
            let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
            if !is_link {
                return Err(folder_error(path, dir, &e));
            }
            remove_name(path)?;
            return Ok(None);
        }
    };
    let meta = file
        .metadata()
        .map_err(FsError::io(path, "cannot inspect the lock file"))?;
    if !meta.file_type().is_file() {
        return Err(FsError::NotRegular {
            path: path.to_path_buf(),
            kind: kind_name(&meta.file_type()),
        });
    }
    // A lock file t2tf made has one name; another is a hard link to someone's file.
    if platform::hard_links(&file, &meta) > 1 {
        drop(file);
        remove_name(path)?;
        return Ok(None);
    }
    Ok(Some(file))
}

/// Remove the name `path` (for a symlink, the link, never its target; for a hard link, this
/// one name); a name that is not there is fine.
pub fn remove_name(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(FsError::io(path, "cannot replace")(e)),
    }
}

/// Whether `path` still names the open `file`.
fn is_current(file: &std::fs::File, path: &Path) -> bool {
    platform::same_file(file, path)
}

/// Take the exclusive lock of an open lock file without waiting (`flock` on Unix,
/// `LockFileEx` on Windows); held until the file is closed, so a killed run's lock is gone.
fn lock_file(file: &std::fs::File) -> Result<bool, std::io::Error> {
    match file.try_lock() {
        Ok(()) => Ok(true),
        Err(std::fs::TryLockError::WouldBlock) => Ok(false),
        Err(std::fs::TryLockError::Error(e)) => Err(e),
    }
}

/// The error for a lock held by another run, naming it by the PID in the open lock file.
fn busy(dir: &Path, lock: &mut std::fs::File) -> FsError {
    use std::io::{Read, Seek};
    let mut text = String::new();
    let read = lock
        .rewind()
        .and_then(|()| lock.take(32).read_to_string(&mut text));
    let owner = read.ok().and_then(|_| text.trim().parse::<u32>().ok());
    let who = owner.map_or("another process".to_string(), |p| format!("process {p}"));
    FsError::Busy {
        dir: dir.to_path_buf(),
        who,
    }
}

/// The files of one run, staged in `OUT/.t2tf-set-PID/` and moved into `OUT` together by
/// [`OutputSet::commit`]: the previous `report.json` goes first and the new one comes last,
/// so whenever `OUT/report.json` exists, the files it lists are of its own run.
#[derive(Debug)]
pub struct OutputSet {
    out: PathBuf,
    staging: PathBuf,
}

impl OutputSet {
    /// A fresh, empty staging folder in `out` (which must exist).
    pub fn begin(out: &Path) -> Result<OutputSet> {
        let staging = out.join(format!("{SET_PREFIX}{}", std::process::id()));
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(FsError::io(&staging, "cannot remove"))?;
        }
        std::fs::create_dir(&staging)
            .map_err(|e| FsError::Stage(Box::new(folder_error(&staging, out, &e))))?;
        Ok(OutputSet {
            out: out.to_path_buf(),
            staging,
        })
    }

    /// Where the run writes its files.
    pub fn dir(&self) -> &Path {
        &self.staging
    }

    fn staged_names(&self) -> Result<Vec<String>> {
        let mut names = Vec::new();
        let list = FsError::io(&self.staging, "cannot list");
        let entries = std::fs::read_dir(&self.staging).map_err(&list)?;
        for e in entries {
            let e = e.map_err(&list)?;
            names.push(e.file_name().to_string_lossy().into_owned());
        }
        Ok(names)
    }

    /// Move `names` (all staged) into the output folder, `report.json` last. Every target is
    /// checked first, so a refused one leaves the previous set untouched (and this one is
    /// removed, as on any failure). Each file is renamed over its name in the folder: a
    /// symlink there is replaced, never followed.
    pub fn commit(self, names: &[String]) -> Result<()> {
        let mut moves = Vec::with_capacity(names.len());
        for n in names.iter().filter(|n| n.as_str() != MANIFEST) {
            let to = self.out.join(n);
            replaceable(&to)?;
            moves.push((self.staging.join(n), to));
        }
        let manifest = self.staging.join(MANIFEST);
        let manifest_target = self.out.join(MANIFEST);
        replaceable(&manifest_target)?;
        remove_name(&manifest_target)?;
        for (from, to) in &moves {
            rename(from, to)?;
        }
        if std::fs::symlink_metadata(&manifest).is_ok() {
            rename(&manifest, &manifest_target)?;
        }
        sync_dir(&self.out);
        std::fs::remove_dir_all(&self.staging).map_err(FsError::io(&self.staging, "cannot remove"))
    }
}

/// A set that was not committed (its run failed: a full disk, a refused name) leaves nothing
/// behind: the staged files are removed, so neither a hidden folder nor a half set stays in
/// the output folder. (A process killed outright leaves its staging for [`clean_stale`].)
impl Drop for OutputSet {
    fn drop(&mut self) {
        if std::fs::symlink_metadata(&self.staging).is_ok() {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

fn rename(from: &Path, to: &Path) -> Result<()> {
    std::fs::rename(from, to).map_err(|error| FsError::Move {
        from: from.to_path_buf(),
        to: to.to_path_buf(),
        error,
    })
}

/// Make the renames durable; a failure only weakens the guarantee after a power loss.
fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_the_lock_created_goes_away_if_nothing_was_written() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        drop(OutputLock::acquire(&out).unwrap());
        assert!(!out.exists(), "an empty output folder was left behind");
        let lock = OutputLock::acquire(&out).unwrap();
        std::fs::write(out.join("tf.json"), "[]").unwrap();
        drop(lock);
        assert!(out.join("tf.json").is_file());
        // A folder that was there before is never removed, even when empty.
        let before = dir.path().join("mine");
        std::fs::create_dir(&before).unwrap();
        drop(OutputLock::acquire(&before).unwrap());
        assert!(before.is_dir());
    }

    #[test]
    fn failed_fill_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.json");
        let r = atomic_write(&p, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("interrupted"))
        });
        assert!(r.is_err());
        assert!(!p.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[cfg(unix)]
    #[test]
    fn outputs_are_readable_by_others() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("preset.json");
        atomic_write_bytes(&p, b"[]").unwrap();
        let mode = std::fs::metadata(&p).unwrap().permissions().mode();
        assert_eq!(mode & 0o044, 0o044, "mode {mode:o}");
    }

    #[test]
    fn success_replaces_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.txt");
        std::fs::write(&p, "old").unwrap();
        atomic_write_bytes(&p, b"new").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new");
    }

    #[cfg(unix)]
    #[test]
    fn the_callers_own_symlinks_are_followed_and_their_target_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().join("real.txt");
        std::fs::write(&real, "old").unwrap();
        let link = dir.path().join("link.txt");
        std::os::unix::fs::symlink("real.txt", &link).unwrap();
        atomic_write_bytes(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read_to_string(&real).unwrap(), "new");
        // A dangling link creates its target.
        let dangling = dir.path().join("dangling.txt");
        std::os::unix::fs::symlink("made.txt", &dangling).unwrap();
        atomic_write_bytes(&dangling, b"x").unwrap();
        assert_eq!(std::fs::read(dir.path().join("made.txt")).unwrap(), b"x");
    }

    /// A victim file outside the output folder, and its content.
    #[cfg(unix)]
    fn victim(dir: &Path) -> PathBuf {
        let v = dir.join("victim.txt");
        std::fs::write(&v, "victim").unwrap();
        v
    }

    #[cfg(unix)]
    #[test]
    fn another_users_symlink_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = victim(dir.path());
        let link = dir.path().join("out.json");
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        if unsafe { libc::geteuid() } != 0 {
            eprintln!("skipped: giving a symlink to another user needs root");
            return;
        }
        std::os::unix::fs::lchown(&link, Some(65534), Some(65534)).unwrap();
        for e in [
            atomic_write_bytes(&link, b"new").unwrap_err(),
            check_writable(&link).unwrap_err(),
        ] {
            let m = e.to_string();
            assert!(m.contains("owned by another user (uid 65534)"), "{m}");
            assert!(!m.contains('\n'), "{m}");
        }
        // A chain: our own link to the foreign one is refused too, naming the foreign link.
        let ours = dir.path().join("ours.json");
        std::os::unix::fs::symlink("out.json", &ours).unwrap();
        let m = atomic_write_bytes(&ours, b"new").unwrap_err().to_string();
        assert!(
            m.contains(&format!("{} is a symlink", link.display())),
            "{m}"
        );
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "victim");
        // An output folder given through another user's link is refused as well.
        let folder = dir.path().join("folder");
        std::fs::create_dir(&folder).unwrap();
        let folder_link = dir.path().join("folder-link");
        std::os::unix::fs::symlink(&folder, &folder_link).unwrap();
        std::os::unix::fs::lchown(&folder_link, Some(65534), Some(65534)).unwrap();
        let m = OutputLock::acquire(&folder_link).unwrap_err().to_string();
        assert!(m.contains("owned by another user"), "{m}");
        assert_eq!(std::fs::read_dir(&folder).unwrap().count(), 0);
    }

    #[cfg(unix)]
    #[test]
    fn a_replaced_name_replaces_the_symlink_not_its_target() {
        let dir = tempfile::tempdir().unwrap();
        let victim = victim(dir.path());
        let link = dir.path().join("cache.bin");
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        atomic_replace_bytes(&link, b"ours").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_file());
        assert_eq!(std::fs::read_to_string(&link).unwrap(), "ours");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "victim");
        // A dangling link creates nothing at its target.
        let made = dir.path().join("made.txt");
        std::fs::remove_file(&link).unwrap();
        std::os::unix::fs::symlink(&made, &link).unwrap();
        atomic_replace_bytes(&link, b"ours").unwrap();
        assert!(!made.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[cfg(unix)]
    #[test]
    fn links_planted_in_an_output_folder_are_replaced_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = victim(dir.path());
        let out = dir.path().join("out");
        std::fs::create_dir(&out).unwrap();
        for n in ["a.json", MANIFEST] {
            std::os::unix::fs::symlink(&victim, out.join(n)).unwrap();
        }
        // The lock: a symlink, then a hard link, in its place.
        std::os::unix::fs::symlink(&victim, out.join(LOCK_NAME)).unwrap();
        let lock = OutputLock::acquire(&out).unwrap();
        drop(lock);
        std::fs::hard_link(&victim, out.join(LOCK_NAME)).unwrap();
        let lock = OutputLock::acquire(&out).unwrap();
        let set = OutputSet::begin(&out).unwrap();
        atomic_write_bytes(&set.dir().join("a.json"), b"new").unwrap();
        atomic_write_bytes(&set.dir().join(MANIFEST), b"new").unwrap();
        set.commit(&["a.json".into(), MANIFEST.into()]).unwrap();
        drop(lock);
        for n in ["a.json", MANIFEST] {
            let p = out.join(n);
            assert!(std::fs::symlink_metadata(&p).unwrap().file_type().is_file());
            assert_eq!(std::fs::read_to_string(&p).unwrap(), "new");
        }
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "victim");
        use std::os::unix::fs::MetadataExt;
        assert_eq!(std::fs::metadata(&victim).unwrap().nlink(), 1);
        assert!(std::fs::symlink_metadata(out.join(LOCK_NAME)).is_err());
        // A FIFO in the lock's place is refused at once, not waited on.
        let fifo = std::ffi::CString::new(out.join(LOCK_NAME).to_str().unwrap()).unwrap();
        // SAFETY: mkfifo reads a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o644) }, 0);
        let m = OutputLock::acquire(&out).unwrap_err().to_string();
        assert!(m.contains("a FIFO"), "{m}");
    }

    #[cfg(unix)]
    #[test]
    fn a_symlink_named_like_a_dead_runs_staging_folder_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let elsewhere = dir.path().join("elsewhere");
        std::fs::create_dir(&elsewhere).unwrap();
        std::fs::write(elsewhere.join("a.json"), "theirs").unwrap();
        std::fs::write(elsewhere.join(MANIFEST), "theirs").unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir(&out).unwrap();
        std::os::unix::fs::symlink(&elsewhere, out.join(".t2tf-set-2147483632")).unwrap();
        assert!(clean_stale(&out).unwrap().is_empty());
        assert!(!out.join("a.json").exists());
        assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 2);
    }

    #[test]
    fn folders_and_devices_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let e = atomic_write_bytes(dir.path(), b"x").unwrap_err();
        assert!(format!("{e:#}").contains("not a regular file"), "{e:#}");
        #[cfg(unix)]
        {
            let e = atomic_write_bytes(Path::new("/dev/null"), b"x").unwrap_err();
            assert!(format!("{e:#}").contains("a device"), "{e:#}");
        }
    }

    #[test]
    fn stale_partials_of_dead_processes_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        // PID 0x7fff_fff0 exceeds pid_max, so no process has it.
        let dead = dir.path().join(".t2tf-2147483632-abc.partial");
        let ours = dir
            .path()
            .join(format!(".t2tf-{}-abc.partial", std::process::id()));
        std::fs::write(&dead, "x").unwrap();
        std::fs::write(&ours, "x").unwrap();
        let removed = clean_stale(dir.path()).unwrap();
        assert_eq!(removed, vec![".t2tf-2147483632-abc.partial".to_string()]);
        assert!(ours.exists());
    }

    #[test]
    fn a_set_replaces_the_previous_one_with_its_report_last() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("a.json"), "old").unwrap();
        std::fs::write(dir.path().join(MANIFEST), "old").unwrap();
        let set = OutputSet::begin(dir.path()).unwrap();
        atomic_write_bytes(&set.dir().join("a.json"), b"new").unwrap();
        atomic_write_bytes(&set.dir().join(MANIFEST), b"new").unwrap();
        set.commit(&["a.json".into(), MANIFEST.into()]).unwrap();
        for n in ["a.json", MANIFEST] {
            assert_eq!(std::fs::read_to_string(dir.path().join(n)).unwrap(), "new");
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn a_complete_set_of_a_dead_run_is_finished() {
        let dir = tempfile::tempdir().unwrap();
        let staged = dir.path().join(".t2tf-set-2147483632");
        std::fs::create_dir(&staged).unwrap();
        std::fs::write(staged.join("a.json"), "new").unwrap();
        std::fs::write(staged.join(MANIFEST), "new").unwrap();
        let half = dir.path().join(".t2tf-set-2147483633");
        std::fs::create_dir(&half).unwrap();
        std::fs::write(half.join("a.json"), "half").unwrap();
        clean_stale(dir.path()).unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.path().join("a.json")).unwrap(),
            "new"
        );
        assert!(!staged.exists() && !half.exists());
    }

    #[test]
    fn messages_name_the_file_and_what_is_wrong() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no/such/tf.json");
        let e = atomic_write_bytes(&missing, b"[]").unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "{}: cannot create a file in {}: the folder does not exist",
                missing.display(),
                dir.path().join("no/such").display()
            )
        );
        let file = dir.path().join("file");
        std::fs::write(&file, "x").unwrap();
        // The system's reason follows the prefix, in its own words.
        let e = OutputLock::acquire(&file).unwrap_err().to_string();
        let prefix = format!("{}: cannot create the output folder: ", file.display());
        assert!(e.starts_with(&prefix), "{e}");
        assert!(file.is_file(), "a refused --out must not be touched");
    }

    #[test]
    fn the_lock_file_is_removed_when_the_run_ends() {
        let dir = tempfile::tempdir().unwrap();
        let lock = OutputLock::acquire(dir.path()).unwrap();
        let path = dir.path().join(LOCK_NAME);
        assert!(path.is_file());
        drop(lock);
        assert!(!path.exists(), "{} left behind", path.display());
        // A lock file left by a killed run (unlocked) is taken over and removed in turn.
        std::fs::write(&path, "999999\n").unwrap();
        let lock = OutputLock::acquire(dir.path()).unwrap();
        let pid = std::fs::read_to_string(&path).unwrap();
        assert_eq!(pid.trim(), std::process::id().to_string());
        drop(lock);
        assert!(!path.exists());
    }

    #[test]
    #[cfg_attr(
        windows,
        ignore = "wine 8 keeps a removed file's name openable and does not report it as \
                  delete-pending; Windows 10 and later remove the name at once (POSIX deletes)"
    )]
    fn a_run_holding_the_removed_lock_file_sees_it_is_stale() {
        // The race the removal opens: a second run opened the lock file, the first run ended
        // and removed it, then the second run's flock succeeds on a file no one else can
        // reach. `is_current` is the check `acquire` makes after locking.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(LOCK_NAME);
        let first = OutputLock::acquire(dir.path()).unwrap();
        let opened = std::fs::File::open(&path).unwrap();
        assert!(is_current(&opened, &path));
        drop(first);
        assert!(lock_file(&opened).is_ok(), "the flock itself succeeds");
        assert!(
            !is_current(&opened, &path),
            "a removed file passed as current"
        );
        // A third run creates the file anew, and the stale handle does not stop it.
        let third = OutputLock::acquire(dir.path()).unwrap();
        let reopened = std::fs::File::open(&path).unwrap();
        assert!(!is_current(&opened, &path));
        assert!(is_current(&reopened, &path));
        drop(third);
    }

    #[test]
    fn a_second_lock_names_the_holder() {
        let dir = tempfile::tempdir().unwrap();
        let _held = OutputLock::acquire(dir.path()).unwrap();
        // flock locks belong to the open file description: a second open conflicts even in
        // the same process.
        let e = OutputLock::acquire(dir.path()).unwrap_err();
        let m = format!("{e:#}");
        assert!(
            m.contains(&format!("process {}", std::process::id())),
            "{m}"
        );
    }
}
