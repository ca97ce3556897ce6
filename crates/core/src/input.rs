//! Opening the files a user hands in (volumes, presets, pictures, captions, model files): only
//! regular files, and never an open that blocks. A named pipe without a writer would hang an
//! `open`, and `/dev/zero` would be read until memory runs out; both are refused at once.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

use crate::platform;

/// Open `path` for reading if it is a regular file (symlinks followed). The open itself does
/// not block (`O_NONBLOCK`, cleared again once the file is known to be regular), so a FIFO is
/// refused rather than waited on.
pub fn open(path: &Path) -> io::Result<File> {
    let file = platform::open_without_waiting(path)?;
    regular(&file.metadata()?)?;
    platform::set_blocking(&file)?;
    Ok(file)
}

/// The whole of the regular file at `path`.
pub fn read(path: &Path) -> io::Result<Vec<u8>> {
    let mut file = open(path)?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// The whole of the regular file at `path`, as UTF-8 text.
pub fn read_to_string(path: &Path) -> io::Result<String> {
    String::from_utf8(read(path)?)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "is not UTF-8 text"))
}

/// `Ok` for a regular file, else an error saying what the path is instead.
pub fn regular(meta: &std::fs::Metadata) -> io::Result<()> {
    if meta.is_file() {
        return Ok(());
    }
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("is {}, not a regular file", kind(meta)),
    ))
}

/// What a file that is not regular is, for messages.
fn kind(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a named pipe (FIFO)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if meta.is_dir() {
        "a directory"
    } else {
        "not a file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_files_open_and_special_files_are_refused_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.txt");
        std::fs::write(&file, "hello").unwrap();
        assert_eq!(read_to_string(&file).unwrap(), "hello");
        let e = read(dir.path()).unwrap_err().to_string();
        assert!(e.contains("a directory"), "{e}");
        #[cfg(unix)]
        {
            let fifo = dir.path().join("pipe");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            // SAFETY: mkfifo with a NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            // No writer: a plain open would block forever here.
            let e = read(&fifo).unwrap_err().to_string();
            assert!(e.contains("named pipe"), "{e}");
            let e = read(Path::new("/dev/zero")).unwrap_err().to_string();
            assert!(e.contains("character device"), "{e}");
        }
        std::fs::write(dir.path().join("bad"), [0xff, 0xfe]).unwrap();
        assert!(read_to_string(&dir.path().join("bad")).is_err());
    }
}
