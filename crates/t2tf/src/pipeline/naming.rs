//! What a run's files are called when the caller does not say: the output folder's default,
//! the TF base name (from the folder the user named, else the prompt or the reference
//! picture), and one name per prompt of a batch. The CLI and the Python package both ask here,
//! so a run gets the same names from either.

use std::path::Path;

use super::{check_name, PipelineError, Target};

/// The output folder when none is given.
pub const DEFAULT_OUT: &str = "t2tf-output";

/// The TF base name: `name` when given, else the slug of the output folder's name when the
/// user named one (`out` other than [`DEFAULT_OUT`]: `aneurism-tf` writes `aneurism-tf.json`),
/// else the slug of the prompt or of the reference picture's stem. Checked either way
/// ([`check_name`]): `--out report` would make `report.json` the TF's and the report's.
pub fn tf_name(
    name: Option<&str>,
    out: Option<&Path>,
    target: &Target,
) -> Result<String, PipelineError> {
    let name = derived_name(name, out, target);
    check_name(&name)?;
    Ok(name)
}

fn derived_name(name: Option<&str>, out: Option<&Path>, target: &Target) -> String {
    if let Some(n) = name {
        return n.to_string();
    }
    if let Some(out) = out.filter(|o| *o != Path::new(DEFAULT_OUT)) {
        let folder = out.file_name().map(|f| slug(&f.to_string_lossy()));
        if let Some(f) = folder.filter(|f| !f.is_empty()) {
            return f;
        }
    }
    match target {
        Target::Prompt(p) => slug(p),
        Target::Image(path) => slug(
            &path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
        ),
    }
}

/// One name per prompt of a batch: its slug, with -2, -3, … where two prompts give the same;
/// each checked ([`check_name`]: a prompt "Report" would overwrite its folder's report).
pub fn batch_names(prompts: &[String]) -> Result<Vec<String>, PipelineError> {
    let mut names: Vec<String> = Vec::with_capacity(prompts.len());
    for p in prompts {
        let base = slug(p);
        let mut name = base.clone();
        let mut n = 1;
        while names.contains(&name) {
            n += 1;
            name = format!("{base}-{n}");
        }
        check_name(&name)?;
        names.push(name);
    }
    Ok(names)
}

/// Lower-case words of letters and digits joined by '-', at most 48 characters; "tf" if none.
pub fn slug(text: &str) -> String {
    let mut s = String::new();
    for word in text
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
    {
        let w = word.to_lowercase();
        if s.len() + w.len() + 1 > 48 {
            break;
        }
        if !s.is_empty() {
            s.push('-');
        }
        s.push_str(&w);
    }
    if s.is_empty() {
        "tf".into()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slugs() {
        assert_eq!(slug("The teeth of a CT head!"), "the-teeth-of-a-ct-head");
        assert_eq!(slug("  ...  "), "tf");
        assert!(slug(&"word ".repeat(40)).len() <= 48);
    }

    #[test]
    fn a_named_folder_names_the_tf_else_the_prompt_or_picture_does() {
        let prompt = Target::Prompt("A potted tree".into());
        assert_eq!(tf_name(None, None, &prompt).unwrap(), "a-potted-tree");
        let out = Path::new("runs/Bonsai TF");
        assert_eq!(tf_name(None, Some(out), &prompt).unwrap(), "bonsai-tf");
        let default = Path::new(DEFAULT_OUT);
        assert_eq!(
            tf_name(None, Some(default), &prompt).unwrap(),
            "a-potted-tree"
        );
        assert_eq!(tf_name(Some("y"), Some(out), &prompt).unwrap(), "y");
        assert!(tf_name(Some("report"), None, &prompt).is_err());
        // Derived names are checked as given ones are.
        assert!(tf_name(None, Some(Path::new("out/report")), &prompt).is_err());
        assert!(tf_name(None, None, &Target::Prompt("Report".into())).is_err());
        let picture = Target::Image("pics/Red Car.png".into());
        assert_eq!(tf_name(None, None, &picture).unwrap(), "red-car");
    }

    #[test]
    fn prompts_that_slug_alike_get_numbers() {
        let prompts = ["a tree".to_string(), "A tree!".into(), "a rock".into()];
        assert_eq!(
            batch_names(&prompts).unwrap(),
            ["a-tree", "a-tree-2", "a-rock"]
        );
        assert!(batch_names(&["x".into(), "Report".into()]).is_err());
    }
}
