//! `t2tf cache list` and `t2tf cache clear` on the caption-embedding cache a real run fills
//! (`XDG_CACHE_HOME` points into a temporary folder).

use std::path::Path;
use std::process::{Command, Output};

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const VOLUME: &str = "tests/fixtures/volumes/ramp_7x6x5_uint16.raw";

fn t2tf(xdg: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .env("XDG_CACHE_HOME", xdg)
        .args(args)
        .output()
        .unwrap()
}

fn ok(o: &Output) -> String {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout.clone()).unwrap()
}

#[test]
fn list_shows_what_a_run_cached_and_clear_removes_only_that() {
    let xdg = tempfile::tempdir().unwrap();
    let cache = xdg.path().join("t2tf");
    let empty = ok(&t2tf(xdg.path(), &["cache", "list"]));
    assert_eq!(
        empty.trim(),
        format!("total: 0 files, 0 B in {}", cache.display())
    );

    let out = xdg.path().join("run");
    ok(&t2tf(
        xdg.path(),
        &[
            "optimize",
            VOLUME,
            "--model",
            MODEL,
            "--tokenizer",
            TOKENIZER,
            "--prompt",
            "x",
            "--steps",
            "1",
            "--views",
            "1",
            "--threads",
            "1",
            "--progress",
            "none",
            "--out",
            out.to_str().unwrap(),
        ],
    ));
    let foreign = cache.join("text-embeddings").join("README");
    std::fs::write(&foreign, "not t2tf's").unwrap();

    let listed = ok(&t2tf(xdg.path(), &["cache", "list"]));
    let lines: Vec<&str> = listed.lines().collect();
    assert!(lines.len() >= 2, "{listed}");
    for l in &lines[..lines.len() - 1] {
        assert!(l.contains(".bin") && l.contains("captions ×"), "{l}");
    }
    let files = lines.len() - 1;
    let total = lines.last().unwrap();
    assert!(
        total.starts_with(&format!("total: {files} file"))
            && total.ends_with(&cache.display().to_string()),
        "{total}"
    );
    assert!(!listed.contains("README"), "{listed}");

    let cleared = ok(&t2tf(xdg.path(), &["cache", "clear"]));
    assert!(
        cleared.starts_with(&format!("removed {files} file")),
        "{cleared}"
    );
    assert!(foreign.is_file(), "a file that is not t2tf's was removed");
    let after = ok(&t2tf(xdg.path(), &["cache", "list"]));
    assert!(after.starts_with("total: 0 files"), "{after}");
}

#[test]
fn help_says_where_the_cache_is_with_examples() {
    let xdg = tempfile::tempdir().unwrap();
    for args in [
        &["cache", "--help"][..],
        &["cache", "list", "--help"][..],
        &["cache", "clear", "--help"][..],
    ] {
        let help = ok(&t2tf(xdg.path(), args));
        assert!(help.contains("Example"), "{args:?}: {help}");
    }
    let help = ok(&t2tf(xdg.path(), &["cache", "--help"]));
    assert!(help.contains("$XDG_CACHE_HOME/t2tf"), "{help}");
}
