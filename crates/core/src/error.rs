//! What kind of problem an error is, so that each front end (the command line, the Python
//! module, the ParaView plugin) can say how to fix it in its own terms: a flag, a keyword, a
//! property. A library message says what was wrong and names an option in backticks by its
//! field's name (`dims`); it carries no front end's advice. Every top-level error of the
//! library crates gives a [`Hint`] (`hint()`): its [`ErrorKind`] and the option it is about,
//! which a front end words from, never from the message's text.

/// What kind of problem an error is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// An option's value that cannot be used, or options that do not go together
    /// ([`Hint::option`] names it where there is one).
    InvalidOption,
    /// The CLIP model could not be had: not in the Hugging Face cache with offline mode on
    /// (`offline`), or the Hub could not be reached (not `offline`). A local model folder, or
    /// the model fetched where there is a network, fixes it.
    ModelUnavailable {
        /// The Hugging Face repo id (`owner/name`).
        repo: String,
        /// Whether offline mode was on.
        offline: bool,
    },
    /// Something did not fit the memory budget; a larger budget fixes it.
    Memory {
        /// Bytes asked for (`u64::MAX` where the size overflowed).
        needed: u64,
        /// Bytes the budget had.
        available: u64,
    },
    /// The prompt says nothing.
    EmptyPrompt,
    /// A volume file that cannot be read as a volume.
    Volume,
    /// A file or folder the system could not read or write.
    Io,
    /// Anything else.
    Other,
}

impl ErrorKind {
    /// The kind's name in snake case (`invalid_option`, `model_unavailable`, `memory`,
    /// `empty_prompt`, `volume`, `io`, `other`), as the front ends give it to programs.
    pub fn name(&self) -> &'static str {
        match self {
            ErrorKind::InvalidOption => "invalid_option",
            ErrorKind::ModelUnavailable { .. } => "model_unavailable",
            ErrorKind::Memory { .. } => "memory",
            ErrorKind::EmptyPrompt => "empty_prompt",
            ErrorKind::Volume => "volume",
            ErrorKind::Io => "io",
            ErrorKind::Other => "other",
        }
    }
}

/// What a front end needs to word its advice for an error: the kind of problem and the
/// option it is about, by the option's field name (one of [`OPTIONS`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Hint {
    /// What kind of problem.
    pub kind: ErrorKind,
    /// The option the message names and a front end can point to (`dims`, `model`), if any.
    pub option: Option<&'static str>,
}

impl Hint {
    /// A problem of `kind` about no option in particular.
    pub fn new(kind: ErrorKind) -> Hint {
        Hint { kind, option: None }
    }

    /// An invalid value of `option`.
    pub fn invalid(option: &'static str) -> Hint {
        Hint::new(ErrorKind::InvalidOption).about(option)
    }

    /// Anything else.
    pub fn other() -> Hint {
        Hint::new(ErrorKind::Other)
    }

    /// The same hint about `option`.
    pub fn about(self, option: &'static str) -> Hint {
        debug_assert!(OPTIONS.contains(&option), "{option} is not in OPTIONS");
        Hint {
            option: Some(option),
            ..self
        }
    }

    /// Whether this hint tells a front end anything beyond "an error".
    pub fn is_specific(&self) -> bool {
        self.kind != ErrorKind::Other || self.option.is_some()
    }
}

/// Every option a [`Hint`] may name, by the field that holds it in the library (`ReadOptions`,
/// `pipeline::Job`, `optimize::Settings`, `ModelRequest`, …). A front end keeps a table of
/// its own spelling for each (tested against this list).
pub const OPTIONS: [&str; 34] = [
    // Reading a volume (`ReadOptions`).
    "dims",
    "dtype",
    "byte_order",
    "array",
    // The model (`ModelRequest`, `ModelOptions`).
    "model",
    "revision",
    "tokenizer",
    // Memory and threads.
    "budget",
    "threads",
    // Rendering.
    "level",
    "step_size",
    "render_size",
    // A run (`pipeline::Job`, `optimize::Settings`).
    "prompt",
    "negatives",
    "negatives_file",
    "reference_image",
    "init",
    "preset",
    "locks",
    "steps",
    "views",
    "lr",
    "momentum",
    "prior_weight",
    "prior_ab",
    "l1",
    "l2",
    "control_points",
    "rho",
    "pitch_limit",
    "distance",
    // TF files.
    "max_preset_size",
    "rescale",
    // A camera.
    "up",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_snake_case_and_distinct() {
        let kinds = [
            ErrorKind::InvalidOption,
            ErrorKind::ModelUnavailable {
                repo: "o/n".into(),
                offline: true,
            },
            ErrorKind::Memory {
                needed: 2,
                available: 1,
            },
            ErrorKind::EmptyPrompt,
            ErrorKind::Volume,
            ErrorKind::Io,
            ErrorKind::Other,
        ];
        let names: Vec<&str> = kinds.iter().map(ErrorKind::name).collect();
        for (i, n) in names.iter().enumerate() {
            assert!(n.chars().all(|c| c.is_ascii_lowercase() || c == '_'), "{n}");
            assert!(!names[..i].contains(n), "{n} twice");
        }
    }

    #[test]
    fn options_are_field_names_listed_once() {
        for (i, o) in OPTIONS.iter().enumerate() {
            assert!(
                o.chars()
                    .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'),
                "{o}"
            );
            assert!(!OPTIONS[..i].contains(o), "{o} twice");
        }
        let h = Hint::invalid("dims");
        assert_eq!((h.kind.name(), h.option), ("invalid_option", Some("dims")));
        assert!(h.is_specific() && !Hint::other().is_specific());
    }
}
