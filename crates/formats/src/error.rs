//! Errors of the TF readers, writers and converters: one line naming the file and what is
//! wrong.

use std::path::{Path, PathBuf};

use t2tf_core::error::{ErrorKind, Hint};

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
    /// A problem with one file that an option settles (`preset`: which of its presets;
    /// `rescale`), named in the message by its field.
    #[error("{path}: {message}")]
    FileOption {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the option.
        message: String,
        /// The option (one of `t2tf_core::error::OPTIONS`).
        option: &'static str,
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
    /// A TF file larger than the cap on what is read ([`crate::DEFAULT_MAX_PRESET_SIZE`]),
    /// refused before any of it is read.
    #[error(
        "{path}: is {}, more than the {} a transfer-function file may be \
         (raise `max_preset_size` to read it)",
        t2tf_core::units::human_bytes(*size as u128),
        t2tf_core::units::human_bytes(*limit as u128)
    )]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size in bytes.
        size: u64,
        /// The cap in bytes.
        limit: u64,
    },
}

impl FormatError {
    /// What a front end needs to word its advice.
    pub fn hint(&self) -> Hint {
        match self {
            FormatError::FileOption { option, .. } => Hint::invalid(option),
            FormatError::Io { .. } => Hint::new(ErrorKind::Io),
            FormatError::Output(e) => e.hint(),
            FormatError::TooLarge { .. } => Hint::other().about("max_preset_size"),
            FormatError::File { .. } | FormatError::Message(_) => Hint::other(),
        }
    }

    /// A problem with `path` that `option` settles.
    pub(crate) fn about(path: &Path, option: &'static str, message: impl Into<String>) -> Self {
        FormatError::FileOption {
            path: path.to_path_buf(),
            message: message.into(),
            option,
        }
    }

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

/// Read a text file of at most `max_size` bytes, with a clear error for a missing file, a
/// directory, a larger file (before reading it) or non-UTF-8 bytes.
pub(crate) fn read_text(path: &Path, max_size: u64) -> Result<String, FormatError> {
    use std::io::Read;
    if path.is_dir() {
        return Err(FormatError::file(path, "is a directory, not a file"));
    }
    let file = t2tf_core::input::open(path).map_err(|e| FormatError::io(path, e))?;
    let size = file.metadata().map_err(|e| FormatError::io(path, e))?.len();
    let too_large = |size| FormatError::TooLarge {
        path: path.to_path_buf(),
        size,
        limit: max_size,
    };
    if size > max_size {
        return Err(too_large(size));
    }
    // The file may grow while it is read: never past the cap.
    let mut bytes = Vec::with_capacity(size as usize);
    file.take(max_size.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| FormatError::io(path, e))?;
    if bytes.len() as u64 > max_size {
        return Err(too_large(bytes.len() as u64));
    }
    String::from_utf8(bytes).map_err(|e| {
        FormatError::file(
            path,
            format!("is not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}
