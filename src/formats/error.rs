//! Errors of the TF readers and converters: one line naming the file and what is wrong.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    /// A problem not tied to one file (e.g. a volume without a source for a script).
    #[error("{0}")]
    Message(String),
    /// The io error is part of the message and not a `source`: the CLI prints the cause
    /// chain (`{:#}`), which would say it twice.
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
}

impl FormatError {
    pub fn file(path: &Path, message: impl Into<String>) -> Self {
        FormatError::File {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// A failed read or write of `path`; a missing file says so in words, as volumes do.
    pub fn io(path: &Path, error: std::io::Error) -> Self {
        if error.kind() == std::io::ErrorKind::NotFound {
            return FormatError::file(path, "no such file");
        }
        FormatError::Io {
            path: path.to_path_buf(),
            error,
        }
    }
}

/// Read a text file with a clear error for a missing file, a directory or non-UTF-8 bytes.
pub fn read_text(path: &Path) -> Result<String, FormatError> {
    if path.is_dir() {
        return Err(FormatError::file(path, "is a directory, not a file"));
    }
    let bytes = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        FormatError::file(
            path,
            format!("is not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}
