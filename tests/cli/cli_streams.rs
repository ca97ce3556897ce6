//! Output streams that close or fail: a reader that leaves (`t2tf … | head -1`) ends the
//! command quietly with status 0; a full stdout (`> /dev/full`) is one error line and status
//! 1; a progress stream that fails is dropped while `optimize` goes on and writes its files.
//! Never a panic (exit 101), which is what `println!` and `eprintln!` do on such streams.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use crate::reap::Reaped;

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const VOLUME: &str = "tests/fixtures/volumes/ramp_7x6x5_uint16.raw";
const LIBRARY: &str = "tests/fixtures/paraview/paraview_library.json";

fn t2tf() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_t2tf"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

/// Run with stdout a pipe whose reader left before the first write (what `| head -1` becomes
/// once head has its line, and `| true` from the start).
fn stdout_closed(cmd: &mut Command) -> Output {
    let mut child = Reaped::spawn(cmd.stdout(Stdio::piped()).stderr(Stdio::piped()));
    drop(child.stdout.take());
    child.wait_with_output().expect("wait for t2tf")
}

fn quiet_success(what: &str, o: &Output) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{what}: {err}");
    assert!(err.is_empty(), "{what}: said something on stderr: {err}");
}

/// A PNG for clip-score.
fn picture(dir: &Path) -> PathBuf {
    let png = dir.join("view.png");
    let mut im = t2tf::image::Image::new(40, 40);
    for (i, v) in im.data.iter_mut().enumerate() {
        *v = ((i * 17) % 255) as f32 / 255.0;
    }
    im.save_png(&png).unwrap();
    png
}

#[test]
fn a_reader_that_leaves_ends_each_command_quietly() {
    let dir = tempfile::tempdir().unwrap();
    // A cache with one model, so `model list` has rows to print.
    let snapshot = dir
        .path()
        .join("hub/models--someone--clip-test/snapshots/0123456789abcdef");
    std::fs::create_dir_all(&snapshot).unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(MODEL)
            .join("config.json"),
        snapshot.join("config.json"),
    )
    .unwrap();
    let png = picture(dir.path());
    let cases: Vec<(&str, Command)> = vec![
        ("convert --list", {
            let mut c = t2tf();
            c.args(["convert", "--list", LIBRARY]);
            c
        }),
        ("info --json", {
            let mut c = t2tf();
            c.args(["info", "--json", VOLUME]);
            c
        }),
        ("info", {
            let mut c = t2tf();
            c.args(["info", VOLUME]);
            c
        }),
        ("clip-score", {
            let mut c = t2tf();
            c.args(["clip-score"])
                .arg(&png)
                .args(["--model", MODEL, "--tokenizer", TOKENIZER])
                .args(["--caption", "a skull", "--caption", "an engine"]);
            c
        }),
        ("model list --all", {
            let mut c = t2tf();
            c.args(["model", "list", "--all"])
                .env("HF_HUB_CACHE", dir.path().join("hub"));
            c
        }),
        ("--help", {
            let mut c = t2tf();
            c.arg("--help");
            c
        }),
    ];
    for (what, mut cmd) in cases {
        // The same command with stdout open prints something: the closed pipe was written to.
        let open = cmd.output().unwrap();
        assert!(
            open.status.success() && !open.stdout.is_empty(),
            "{what}: {}",
            String::from_utf8_lossy(&open.stderr)
        );
        quiet_success(what, &stdout_closed(&mut cmd));
    }
}

#[test]
fn a_full_stdout_is_one_error_line_not_a_panic() {
    for args in [
        &["info", "--json", VOLUME][..],
        &["convert", "--list", LIBRARY][..],
    ] {
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let o = t2tf().args(args).stdout(full).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.starts_with("t2tf: error: cannot write to standard output"),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[cfg(unix)]
fn optimize(out: &Path, cache: &Path) -> Command {
    let run = ["--prompt", "x", "--steps", "3", "--views", "1"];
    crate::hostile_cli::optimize_with_progress(out, cache, "lines", &run)
}

#[cfg(unix)]
/// The run wrote its whole set: report.json and every file it lists.
fn wrote_the_set(out: &Path) {
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let outputs = report["outputs"].as_array().unwrap();
    assert!(outputs.len() >= 5, "{report}");
    for name in outputs {
        assert!(out.join(name.as_str().unwrap()).is_file(), "{name} missing");
    }
}

#[cfg(unix)]
#[test]
fn optimize_goes_on_when_its_progress_stream_fails() {
    let dir = tempfile::tempdir().unwrap();
    // `2>/dev/full`: every progress line fails to write.
    let out = dir.path().join("full");
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let status = optimize(&out, dir.path()).stderr(full).status().unwrap();
    assert_eq!(status.code(), Some(0));
    wrote_the_set(&out);

    // `2>&1 | head -1`: the log's reader leaves after the first line.
    let out = dir.path().join("pipe");
    let mut child = Reaped::spawn(
        optimize(&out, dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    );
    let mut stderr = child.stderr.take().unwrap();
    let mut first = [0u8; 1];
    std::io::Read::read_exact(&mut stderr, &mut first).unwrap();
    drop(stderr);
    assert_eq!(child.wait().unwrap().code(), Some(0));
    wrote_the_set(&out);
}
