//! `t2tf cache list` and `t2tf cache clear` on the caption-embedding cache a real run fills
//! (`XDG_CACHE_HOME` points into a temporary folder).

use std::path::Path;
use std::process::{Command, Output};

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const VOLUME: &str = "tests/fixtures/volumes/ramp_7x6x5_uint16.raw";

/// `t2tf ARGS` with the caption cache in `xdg` and the Hugging Face cache in `xdg/hf`
/// (offline): nothing of this machine's caches is read.
fn t2tf(xdg: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .env("XDG_CACHE_HOME", xdg)
        .env("HF_HOME", xdg.join("hf"))
        .env_remove("HF_HUB_CACHE")
        .env_remove("HUGGINGFACE_HUB_CACHE")
        .env("HF_HUB_OFFLINE", "1")
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
        assert!(l.contains("captions ×"), "{l}");
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

/// The test model as the Hub cache holds a download of `acme/tiny-clip` at `main`: the
/// weights a link to their blob (named by their SHA-256), config and tokenizer beside it.
fn cache_hub_model(hf: &Path) {
    let repo = hf.join("hub/models--acme--tiny-clip");
    let commit = "0123456789abcdef0123456789abcdef01234567";
    let snapshot = repo.join("snapshots").join(commit);
    std::fs::create_dir_all(&snapshot).unwrap();
    std::fs::create_dir_all(repo.join("blobs")).unwrap();
    std::fs::create_dir_all(repo.join("refs")).unwrap();
    std::fs::write(repo.join("refs/main"), commit).unwrap();
    let weights = std::fs::read(Path::new(MODEL).join("model.safetensors")).unwrap();
    let sha: String = {
        use sha2::Digest;
        sha2::Sha256::digest(&weights)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    };
    std::fs::write(repo.join("blobs").join(&sha), &weights).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(
        format!("../../blobs/{sha}"),
        snapshot.join("model.safetensors"),
    )
    .unwrap();
    // Where symlinks need a privilege (Windows), `huggingface_hub` copies the blob into the
    // snapshot: the listing then hashes the file instead of reading the link's target name.
    #[cfg(not(unix))]
    std::fs::write(snapshot.join("model.safetensors"), &weights).unwrap();
    std::fs::copy(
        Path::new(MODEL).join("config.json"),
        snapshot.join("config.json"),
    )
    .unwrap();
    std::fs::copy(TOKENIZER, snapshot.join("tokenizer.json")).unwrap();
}

/// A one-step run into `out` with `model` and `extra` flags.
fn run(xdg: &Path, out: &Path, model: &str, extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "optimize",
        VOLUME,
        "--model",
        model,
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
    ];
    args.push(out.to_str().unwrap());
    args.extend(extra);
    ok(&t2tf(xdg, &args));
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

#[cfg(unix)]
#[test]
fn list_names_the_model_of_each_file() {
    let xdg = tempfile::tempdir().unwrap();
    cache_hub_model(&xdg.path().join("hf"));
    let files = || -> Vec<std::path::PathBuf> {
        let dir = xdg.path().join("t2tf/text-embeddings");
        let mut f: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        f.sort();
        f
    };

    // A run of the Hub model: its file is listed by repo and revision (and bf16 where the run
    // computed in bf16), with its size.
    let report = run(xdg.path(), &xdg.path().join("a"), "acme/tiny-clip", &[]);
    let precision = report["render"]["clip_precision"]
        .as_str()
        .unwrap()
        .to_string();
    let cached = files();
    assert_eq!(cached.len(), 1);
    let size = std::fs::metadata(&cached[0]).unwrap().len();
    let pool = t2tf::optimize::captions::CaptionPool::builtin().len();
    let label = format!(
        "acme/tiny-clip@main{}",
        if precision == "f32" { "" } else { " (bf16)" }
    );
    let line = format!(
        "{label}  {:>10}  {pool} captions × 12",
        t2tf::units::human_bytes(size.into())
    );
    let listed = ok(&t2tf(xdg.path(), &["cache", "list"]));
    assert_eq!(listed.lines().next(), Some(line.as_str()), "{listed}");

    // A model folder with a caption file of its own: no cached model is its, and the line says
    // what it may be instead of a hash.
    let captions = xdg.path().join("captions.txt");
    std::fs::write(&captions, "a red car\na green tree\n").unwrap();
    let extra = [
        "--tokenizer",
        TOKENIZER,
        "--negatives-file",
        captions.to_str().unwrap(),
    ];
    run(xdg.path(), &xdg.path().join("b"), MODEL, &extra);
    assert_eq!(files().len(), 2);
    let listed = ok(&t2tf(xdg.path(), &["cache", "list"]));
    let lines: Vec<&str> = listed.lines().collect();
    assert_eq!(lines.len(), 3, "{listed}");
    assert!(lines.contains(&line.as_str()), "{listed}");
    let other = lines.iter().find(|l| **l != line).unwrap();
    assert!(
        other.starts_with(
            "(a model folder, or a run with its own --tokenizer or --negatives-file)  "
        ) && other.contains(" 2 captions × 12"),
        "{listed}"
    );
    for l in &lines {
        assert!(
            !files()
                .iter()
                .any(|f| { l.contains(f.file_stem().unwrap().to_str().unwrap()) }),
            "a hash is shown: {l}"
        );
    }
}
