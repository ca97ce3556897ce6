//! Atomic file output: write to a temporary file beside the target, then rename over it, so
//! an interrupted run never leaves a partial file under the final name.

use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result};

/// Write `path` through `fill`; the file appears under its name only if `fill` succeeds.
pub fn atomic_write(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(".t2tf-").suffix(".partial");
    // tempfile creates 0600 files; outputs are ordinary user files (0644 before the umask).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    // tempfile's error names its own temporary file, which the user never asked for: say
    // what went wrong with the folder instead.
    let mut tmp = builder.tempfile_in(dir).map_err(|e| {
        let why = match e.kind() {
            std::io::ErrorKind::NotFound => "the folder does not exist".to_string(),
            kind => std::io::Error::from(kind).to_string(),
        };
        anyhow::anyhow!(
            "{}: cannot create a file in {}: {why}",
            path.display(),
            dir.display()
        )
    })?;
    {
        let mut w = BufWriter::new(tmp.as_file_mut());
        fill(&mut w).with_context(|| format!("{}: writing failed", path.display()))?;
        w.flush()
            .with_context(|| format!("{}: writing failed", path.display()))?;
    }
    tmp.as_file()
        .sync_all()
        .with_context(|| format!("{}: writing failed", path.display()))?;
    tmp.persist(path).map_err(|e| e.error).with_context(|| {
        format!(
            "{}: cannot rename the finished file into place",
            path.display()
        )
    })?;
    Ok(())
}

/// Atomically write a byte string (text formats build their content in memory).
pub fn atomic_write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic_write(path, |w| Ok(w.write_all(bytes)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_fill_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.json");
        let r = atomic_write(&p, |w| {
            w.write_all(b"half")?;
            anyhow::bail!("interrupted")
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
}
