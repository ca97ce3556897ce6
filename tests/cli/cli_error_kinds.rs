//! Errors by kind: the command's one line says the library's message with the command line's
//! advice (a flag, the command that fetches a model, the budget's flag), worded from the
//! error's kind and option; with `--progress json` the last line on stderr gives programs the
//! library's message, the kind and the option.

use std::path::{Path, PathBuf};
use std::process::Command;

const NUCLEON: &str = "../shared/data/volumes/nucleon_41x41x41_uint8.raw";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `t2tf args` with its caches in `dir` and offline: (exit code, stderr lines).
fn run(dir: &Path, args: &[&str]) -> (Option<i32>, Vec<String>) {
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .env("XDG_CACHE_HOME", dir.join("cache"))
        .env("HF_HUB_CACHE", dir.join("hub"))
        .env("HF_HUB_OFFLINE", "1")
        .output()
        .expect("run t2tf");
    let err = String::from_utf8_lossy(&o.stderr);
    (o.status.code(), err.lines().map(str::to_string).collect())
}

/// `t2tf optimize NUCLEON --progress json …` that fails: its human line and its final JSON
/// error event.
fn optimize_fails(dir: &Path, extra: &[&str]) -> (String, serde_json::Value) {
    let nucleon = repo().join(NUCLEON);
    let out = dir.join("out");
    let mut args = vec![
        "optimize",
        nucleon.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--progress",
        "json",
        "--threads",
        "2",
    ];
    args.extend(extra);
    let (code, lines) = run(dir, &args);
    assert_eq!(code, Some(1), "{lines:?}");
    let [.., human, last] = &lines[..] else {
        panic!("fewer than two lines: {lines:?}")
    };
    assert!(human.starts_with("t2tf: error: "), "{lines:?}");
    let event: serde_json::Value = serde_json::from_str(last).expect("the last line is JSON");
    assert_eq!(event["event"], "error", "{last}");
    // The keys in the documented order, nothing else.
    let keys: Vec<&str> = event
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    let mut want = vec!["event", "kind", "message", "option"];
    want.sort();
    assert_eq!(keys, want, "{last}");
    assert!(last.starts_with(r#"{"event":"error","message":"#), "{last}");
    (human.clone(), event)
}

#[test]
fn a_setting_out_of_range_names_its_flag_and_its_field() {
    let dir = tempfile::tempdir().unwrap();
    let (human, event) = optimize_fails(dir.path(), &["--prompt", "x", "--views", "0"]);
    assert!(
        human.ends_with("invalid setting --views: must be at least 1"),
        "{human}"
    );
    assert_eq!(event["kind"], "invalid_option");
    assert_eq!(event["option"], "views");
    // The library's words: the field, no flag.
    let message = event["message"].as_str().unwrap();
    assert!(
        message.ends_with("invalid setting `views`: must be at least 1"),
        "{message}"
    );
    assert!(!message.contains("--"), "{message}");
}

#[test]
fn an_empty_prompt_is_its_own_kind() {
    let dir = tempfile::tempdir().unwrap();
    let (human, event) = optimize_fails(dir.path(), &["--prompt", "  "]);
    assert!(human.contains("--prompt is empty"), "{human}");
    assert_eq!(
        (&event["kind"], &event["option"]),
        (&"empty_prompt".into(), &"prompt".into())
    );
    assert!(event["message"]
        .as_str()
        .unwrap()
        .ends_with("the prompt is empty: say what the renderings should show"));
}

#[test]
fn a_model_missing_offline_says_how_to_fetch_it_and_names_no_checkout_path() {
    let dir = tempfile::tempdir().unwrap();
    let (human, event) = optimize_fails(dir.path(), &["--prompt", "a skull", "--steps", "1"]);
    for needle in [
        "offline mode is on (HF_HUB_OFFLINE)",
        "run `t2tf model fetch openai/clip-vit-base-patch32` on a machine with network",
        "or pass --model DIR",
    ] {
        assert!(human.contains(needle), "lacks '{needle}': {human}");
    }
    // No path of the checkout this binary was built from (its test model): installed
    // binaries have none.
    let checkout = repo().display().to_string();
    assert!(!human.contains(&checkout), "{human}");
    assert!(!human.contains("quick_gelu"), "{human}");
    assert_eq!(event["kind"], "model_unavailable");
    assert_eq!(event["option"], "model");
    let message = event["message"].as_str().unwrap();
    assert!(
        message.contains("offline mode is on") && !message.contains("t2tf model fetch"),
        "{message}"
    );
}

#[test]
fn the_memory_budget_is_advised_by_its_flag() {
    let dir = tempfile::tempdir().unwrap();
    let nucleon = repo().join(NUCLEON);
    let tf = dir.path().join("tf.json");
    std::fs::write(
        &tf,
        r#"[{"Name":"t","ColorSpace":"RGB","RGBPoints":[0,0,0,1, 255,1,1,1],
            "Points":[0,0,0.5,0, 255,0.8,0.5,0]}]"#,
    )
    .unwrap();
    let png = dir.path().join("sheet.png");
    let (code, lines) = run(
        dir.path(),
        &[
            "render",
            nucleon.to_str().unwrap(),
            "--tf",
            tf.to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
            "--orbit",
            "64",
            "--size",
            "4096",
            "--max-memory",
            "64M",
        ],
    );
    assert_eq!(code, Some(1), "{lines:?}");
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert!(
        lines[0].ends_with("(or set the budget with --max-memory, e.g. --max-memory 16G)"),
        "{lines:?}"
    );
}
