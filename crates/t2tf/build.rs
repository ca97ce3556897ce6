//! The git commit the library is built from, for report.json (`T2TF_GIT_COMMIT`): `git
//! rev-parse HEAD` where the source is a git checkout and git is installed, else "unknown".

use std::path::PathBuf;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git")
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    (out.status.success() && !text.trim().is_empty()).then(|| text.trim().to_string())
}

fn main() {
    let commit = git(&["rev-parse", "HEAD"]).unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=T2TF_GIT_COMMIT={commit}");
    println!("cargo:rerun-if-changed=build.rs");
    // Rerun when HEAD moves: HEAD itself (a checkout), the branch it names (a commit), and
    // packed-refs (where git may keep that branch). In a worktree the branch lives in the
    // common folder.
    let path = |p: Option<String>| p.map(PathBuf::from);
    if let Some(head) = path(git(&["rev-parse", "--git-path", "HEAD"])) {
        watch(head);
    }
    if let Some(branch) = git(&["symbolic-ref", "-q", "HEAD"]) {
        if let Some(r) = path(git(&["rev-parse", "--git-path", &branch])) {
            watch(r);
        }
    }
    if let Some(packed) = path(git(&["rev-parse", "--git-path", "packed-refs"])) {
        watch(packed);
    }
}

/// Watch `p` (git prints it relative to the folder it ran in) if it exists: Cargo reruns a
/// build script on every build for a watched file that is missing.
fn watch(p: PathBuf) {
    let p = if p.is_absolute() {
        p
    } else {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(p)
    };
    if p.exists() {
        println!("cargo:rerun-if-changed={}", p.display());
    }
}
