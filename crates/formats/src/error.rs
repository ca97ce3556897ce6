//! Errors of the TF readers, writers and converters: one line naming the file and what is
//! wrong.

use std::path::{Path, PathBuf};

/// Why a TF file could not be read, written or converted.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    /// A problem with one file's content or name.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A problem not tied to one file (e.g. a volume without a source for a script).
    #[error("{0}")]
    Message(String),
    /// The io error is part of the message and not a `source`: the CLI prints the cause
    /// chain (`{:#}`), which would say it twice.
    #[error("{path}: {error}")]
    Io {
        /// The file read.
        path: PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
    /// Writing an output failed (`t2tf_core::fs`'s error, which names the file).
    #[error(transparent)]
    Output(#[from] t2tf_core::fs::FsError),
}

impl FormatError {
    pub(crate) fn file(path: &Path, message: impl Into<String>) -> Self {
        FormatError::File {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// A failed read of `path`; a missing file says so in words, as volumes do.
    pub(crate) fn io(path: &Path, error: std::io::Error) -> Self {
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
pub(crate) fn read_text(path: &Path) -> Result<String, FormatError> {
    if path.is_dir() {
        return Err(FormatError::file(path, "is a directory, not a file"));
    }
    let bytes = t2tf_core::input::read(path).map_err(|e| FormatError::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        FormatError::file(
            path,
            format!("is not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}
