//! The library's errors name what was wrong, never a command-line flag; here the binary adds
//! the flag that fixes it where it knows one.

use crate::optimize::OptimizeError;
use crate::pipeline::PipelineError;

/// The budget's flag, said after any error of the memory budget.
const MEMORY_HINT: &str = "or set the budget with --max-memory, e.g. --max-memory 16G";

/// Settings the command line has a flag of the same name for.
const SETTING_FLAGS: [&str; 14] = [
    "steps",
    "negative",
    "views",
    "lr",
    "momentum",
    "prior-weight",
    "prior-ab",
    "prior-start",
    "l1",
    "l2",
    "control-points",
    "negatives-per-step",
    "seed",
    "render-size",
];

/// A pipeline error as the command line says it.
pub fn pipeline(e: PipelineError) -> anyhow::Error {
    match e {
        PipelineError::Optimize(o) => optimize(o),
        PipelineError::Memory(m) => anyhow::anyhow!("{m} ({MEMORY_HINT})"),
        PipelineError::Volume(v) => volume(v),
        other => memory_hint(other.into()),
    }
}

/// An optimizer error as the command line says it.
pub fn optimize(e: OptimizeError) -> anyhow::Error {
    match e {
        OptimizeError::Setting { name, message } if SETTING_FLAGS.contains(&name) => {
            anyhow::anyhow!("invalid setting --{name}: {message}")
        }
        OptimizeError::EmptyPrompt => {
            anyhow::anyhow!("--prompt is empty: say what the renderings should show")
        }
        other => other.into(),
    }
}

/// A volume error as the command line says it.
pub fn volume(e: crate::volume::VolumeError) -> anyhow::Error {
    memory_hint(e.into())
}

/// An output-folder error as the command line says it.
pub fn fs(e: crate::fs::FsError) -> anyhow::Error {
    e.into()
}

/// Any error whose message came from the memory budget gets the budget's flag.
pub fn memory_hint(e: anyhow::Error) -> anyhow::Error {
    let from_budget = e
        .chain()
        .any(|c| c.downcast_ref::<crate::memory::MemoryError>().is_some())
        || e.to_string().contains(" is available for it");
    if from_budget {
        anyhow::anyhow!("{e:#} ({MEMORY_HINT})")
    } else {
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_get_their_flags() {
        let e = optimize(OptimizeError::Setting {
            name: "views",
            message: "must be at least 1".into(),
        });
        assert_eq!(e.to_string(), "invalid setting --views: must be at least 1");
        let e = optimize(OptimizeError::Setting {
            name: "rho",
            message: "must be in (0, 1)".into(),
        });
        assert_eq!(e.to_string(), "invalid setting rho: must be in (0, 1)");
        assert!(optimize(OptimizeError::EmptyPrompt)
            .to_string()
            .starts_with("--prompt is empty"));
    }

    #[test]
    fn memory_errors_name_the_budget_flag() {
        let m = crate::memory::Budget::bytes(1)
            .check("x", Some(2), 1, "ask for less")
            .unwrap_err();
        let e = pipeline(PipelineError::Memory(m)).to_string();
        assert!(
            e.contains("ask for less") && e.contains("--max-memory"),
            "{e}"
        );
    }
}
