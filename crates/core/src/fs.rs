//! Output files: every file goes to a temporary beside its target and is renamed over it, so
//! an interrupted run never leaves a partial file under the final name; only regular files are
//! written (a symlink is followed and its target replaced); a run's files go out as one set
//! (staged in a hidden folder, then moved in with `report.json` last); a lock keeps two runs
//! out of one folder; files left by killed runs are removed by the next one.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

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

/// The file that writing `path` replaces: `path` itself, or the end of its chain of symlinks.
/// Refuses anything that exists and is not a regular file: a device, a FIFO, a socket or a
/// folder is not ours to replace with a file.
pub fn output_target(path: &Path) -> Result<PathBuf> {
    let mut target = path.to_path_buf();
    for _ in 0..MAX_LINKS {
        let meta = match std::fs::symlink_metadata(&target) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(target),
            Err(e) => return Err(FsError::io(path, "cannot inspect the output")(e)),
        };
        let kind = meta.file_type();
        if kind.is_file() {
            return Ok(target);
        }
        if !kind.is_symlink() {
            return Err(FsError::NotRegular {
                path: path.to_path_buf(),
                kind: kind_name(&kind),
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

/// Write `path` through `fill`; the file appears under its name only if `fill` succeeds.
pub fn atomic_write(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    let target = output_target(path)?;
    let dir = parent_of(&target);
    let mut builder = tempfile::Builder::new();
    // The PID in the name lets a later run tell a dead run's temporary from a live one's.
    let prefix = format!("{PARTIAL_PREFIX}{}-", std::process::id());
    builder.prefix(&prefix).suffix(PARTIAL_SUFFIX);
    // tempfile creates 0600 files; outputs are ordinary user files (0644 before the umask).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    // tempfile's error names its own temporary file, which the user never asked for: say
    // what went wrong with the folder instead.
    let mut tmp = builder
        .tempfile_in(dir)
        .map_err(|e| folder_error(path, dir, &e))?;
    {
        let mut w = BufWriter::new(tmp.as_file_mut());
        fill(&mut w)
            .and_then(|()| w.flush())
            .map_err(FsError::io(path, "writing failed"))?;
    }
    tmp.as_file()
        .sync_all()
        .map_err(FsError::io(path, "writing failed"))?;
    tmp.persist(&target)
        .map_err(|e| FsError::io(path, "cannot rename the finished file into place")(e.error))?;
    Ok(())
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

/// Atomically write a byte string (text formats build their content in memory).
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic_write(path, |w| w.write_all(bytes))
}

/// Check before any work that a file can be written at `path`: the name is free or a regular
/// file (or a symlink to one), and its folder accepts new files.
pub fn check_writable(path: &Path) -> Result<()> {
    let target = output_target(path)?;
    let dir = parent_of(&target);
    tempfile::Builder::new()
        .prefix(&format!("{PARTIAL_PREFIX}{}-", std::process::id()))
        .suffix(PARTIAL_SUFFIX)
        .tempfile_in(dir)
        .map_err(|e| folder_error(path, dir, &e))?;
    Ok(())
}

/// Whether process `pid` still runs (a PID that is not ours to signal counts as running).
fn alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: kill with signal 0 only checks that the process exists; it sends nothing.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
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
        if let Some(pid) = pid_after(&name, SET_PREFIX) {
            if !alive(pid) {
                finish_or_drop_set(dir, &entry.path())?;
                done.push(name);
            }
        } else if name.ends_with(PARTIAL_SUFFIX) {
            let dead = pid_after(&name, PARTIAL_PREFIX).is_none_or(|pid| !alive(pid));
            if dead && std::fs::remove_file(entry.path()).is_ok() {
                done.push(name);
            }
        }
    }
    Ok(done)
}

fn finish_or_drop_set(dir: &Path, staged: &Path) -> Result<()> {
    if staged.join(MANIFEST).is_file() {
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

/// An exclusive lock on an output folder, held while a run writes into it (an advisory
/// `flock` on `.t2tf.lock`, released by the kernel however the process ends, so a killed run
/// never leaves the folder locked). The file holds the owner's PID for the error message, and
/// is removed when the lock is dropped; a killed run leaves it behind, unlocked, and the next
/// run takes it over.
#[derive(Debug)]
pub struct OutputLock {
    file: std::fs::File,
    path: PathBuf,
    /// The folder, if this lock created it: a run that fails before writing anything takes
    /// it away again rather than leave an empty folder behind.
    created: Option<PathBuf>,
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while the flock is still held (`file` closes after this body), so no other
        // run holds a lock on it then; one that opened it and waits finds, once it gets the
        // lock, that the name no longer leads to its file, and starts over (`acquire`).
        if is_current(&self.file, &self.path) {
            let _ = std::fs::remove_file(&self.path);
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
            let mut file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| folder_error(&path, dir, &e))?;
            lock_file(&file).map_err(|_| busy(dir, &path))?;
            // The previous holder removes the file as it ends: a lock on a removed file locks
            // nothing another run can see, so open the name again.
            if !is_current(&file, &path) {
                continue;
            }
            file.set_len(0)
                .and_then(|()| writeln!(file, "{}", std::process::id()))
                .map_err(FsError::io(dir, "cannot write to the output folder"))?;
            return Ok(OutputLock {
                file,
                path,
                created,
            });
        }
        Err(busy(dir, &path))
    }
}

/// Whether `path` still names the open `file` (same device and inode).
#[cfg(unix)]
fn is_current(file: &std::fs::File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn is_current(_file: &std::fs::File, path: &Path) -> bool {
    path.exists()
}

#[cfg(unix)]
fn lock_file(file: &std::fs::File) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a descriptor this function borrows; no memory is shared.
    let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(unix))]
fn lock_file(_file: &std::fs::File) -> std::io::Result<()> {
    Ok(())
}

fn busy(dir: &Path, lock: &Path) -> FsError {
    let owner = std::fs::read_to_string(lock)
        .ok()
        .and_then(|s| s.trim().parse::<u32>().ok());
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
    /// checked first, so a refused one leaves the previous set untouched and this one staged.
    pub fn commit(self, names: &[String]) -> Result<()> {
        let mut moves = Vec::with_capacity(names.len());
        for n in names.iter().filter(|n| n.as_str() != MANIFEST) {
            moves.push((self.staging.join(n), output_target(&self.out.join(n))?));
        }
        let manifest = self.staging.join(MANIFEST);
        let manifest_target = output_target(&self.out.join(MANIFEST))?;
        if manifest_target.exists() {
            std::fs::remove_file(&manifest_target)
                .map_err(FsError::io(&manifest_target, "cannot replace"))?;
        }
        for (from, to) in &moves {
            rename(from, to)?;
        }
        if manifest.exists() {
            rename(&manifest, &manifest_target)?;
        }
        sync_dir(&self.out);
        std::fs::remove_dir_all(&self.staging).map_err(FsError::io(&self.staging, "cannot remove"))
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
    fn symlinks_are_followed_and_their_target_replaced() {
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
