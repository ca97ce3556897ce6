//! The library's errors name what was wrong, never a command-line flag; here the binary adds
//! the flag that fixes it where it knows one. Library messages name an option in backticks by
//! its field's name (`dims`, the `ReadOptions` field; Python takes the same keyword), which
//! [`say`] turns into the flag.

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

/// Options the library names in backticks, and the flags that set them.
const OPTION_FLAGS: [(&str, &str); 14] = [
    ("`rescale`", "--rescale MIN,MAX"),
    ("`dims`", "--dims"),
    ("`dtype`", "--dtype"),
    ("`byte_order`", "--byte-order"),
    ("`array`", "--array"),
    ("`level`", "--level"),
    ("`budget`", "--max-memory"),
    ("`tokenizer`", "--tokenizer"),
    ("`preset`", "--preset NAME"),
    ("`model`", "--model"),
    ("`max_preset_size`", "--max-preset-size SIZE"),
    ("`threads`", "--threads"),
    ("`step_size`", "--step-size"),
    ("`render_size`", "--render-size"),
];

/// The library's advice for a model the cache lacks, and what the command line says instead.
const FETCH: (&str, &str) = (" with network access", "` on a machine with network");
/// Said where a local model folder would do; `model fetch` takes none.
const LOCAL_MODEL: &str = ", or use a local `model` folder";

/// `message` (a whole error chain) as the command line says it: options as flags, and for a
/// model the cache lacks the command that fetches it. `fetching` is true for `t2tf model`,
/// which takes no `--model` folder.
pub fn say(message: &str, fetching: bool) -> String {
    let mut m = message.to_string();
    if m.contains(LOCAL_MODEL) {
        let local = match (fetching, test_model()) {
            (true, _) => String::new(),
            (false, None) => ", or pass --model DIR".to_string(),
            (false, Some((model, tokenizer))) => format!(
                ", or pass --model DIR (offline, the test model of the repository runs every \
                 stage: --model {} --tokenizer {})",
                model.display(),
                tokenizer.display()
            ),
        };
        m = m.replace(LOCAL_MODEL, &local);
    }
    // "fetch REPO with network access" → "run `t2tf model fetch REPO` on a machine with network"
    while let Some(end) = m.find(FETCH.0) {
        let Some(start) = m[..end].rfind("fetch ") else {
            break;
        };
        let repo = m[start + "fetch ".len()..end].to_string();
        m.replace_range(
            start..end + FETCH.0.len(),
            &format!("run `t2tf model fetch {repo}{}", FETCH.1),
        );
    }
    for (option, flag) in OPTION_FLAGS {
        m = m.replace(option, flag);
    }
    m
}

/// The repository's tiny test model and the shared CLIP tokenizer, as absolute paths, where
/// the checkout this binary was built from still has them (a hint that works from any folder);
/// `None` for a binary whose checkout is gone.
fn test_model() -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    // Cargo gives the manifest's folder as an absolute path.
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = repo.join("tests/fixtures/clip/quick_gelu");
    let tokenizer = repo.parent()?.join("shared/data/clip/tokenizer.json");
    (model.is_dir() && tokenizer.is_file()).then_some((model, tokenizer))
}

/// A pipeline error as the command line says it.
pub fn pipeline(e: PipelineError) -> anyhow::Error {
    match e {
        PipelineError::Optimize(o) => optimize(o),
        PipelineError::Memory(m) => anyhow::anyhow!("{m} ({MEMORY_HINT})"),
        PipelineError::Volume(v) => volume(v),
        // A job's settings by their flags (`step_size` → --step-size) where the error is made,
        // not only when it is printed.
        PipelineError::Job(j) => anyhow::anyhow!(say(&j, false)),
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
    fn options_become_flags() {
        assert_eq!(
            say("give `dims` and `dtype` to read raw data", false),
            "give --dims and --dtype to read raw data"
        );
        let offline =
            "x not cached; fetch o/n with network access (copy), or use a local `model` folder";
        let m = say(offline, false);
        assert!(
            m.contains("run `t2tf model fetch o/n` on a machine with network (copy)"),
            "{m}"
        );
        // The test model by the checkout's own (absolute) folder, so the hint works from any
        // folder. (Not `is_absolute`: under wine the folder is a Unix path without a drive.)
        let (model, tokenizer) = test_model().expect("the tests run in the checkout");
        let checkout = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        assert!(model.starts_with(checkout) && tokenizer.starts_with(checkout.parent().unwrap()));
        let hint = format!(
            "--model {} --tokenizer {}",
            model.display(),
            tokenizer.display()
        );
        assert!(m.contains("--model DIR") && m.contains(&hint), "{m}");
        let m = say(offline, true);
        assert!(
            m.contains("t2tf model fetch o/n") && !m.contains("--model"),
            "{m}"
        );
        // Commands in backticks that are not options stay as they are.
        assert_eq!(
            say("run `t2tf convert --list`", false),
            "run `t2tf convert --list`"
        );
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
