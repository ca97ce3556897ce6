//! Inputs that are not regular files — a named pipe with no writer, a character device — are
//! refused at once with one line naming the file, wherever a command reads a file: volumes of
//! every format, presets, pictures, caption files, tokenizers and model folders. A plain open
//! of such a pipe would block forever, and `/dev/zero` would be read until memory runs out.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::reap::Reaped;

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const VOLUME: &str = "tests/fixtures/volumes/ramp_7x6x5_uint16.raw";

/// A named pipe at `dir/name` that nobody writes to.
fn fifo(dir: &Path, name: &str) -> PathBuf {
    let p = dir.join(name);
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: mkfifo with a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
    p
}

/// Run `t2tf args`, killed after 20 s: a hang is a failure, not a stuck test run.
fn t2tf(args: &[&str]) -> (Option<i32>, String) {
    let mut child = Reaped::spawn(
        Command::new(env!("CARGO_BIN_EXE_t2tf"))
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    );
    let start = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            let out = child.wait_with_output().unwrap();
            let err = String::from_utf8_lossy(&out.stderr).into_owned();
            return (out.status.code(), err);
        }
        if start.elapsed() > Duration::from_secs(20) {
            // Killed and reaped as `child` drops.
            return (None, format!("t2tf {args:?} hung"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn refused(args: &[&str], file: &Path) {
    let (code, err) = t2tf(args);
    assert_eq!(code, Some(1), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    let f = file.display().to_string();
    assert!(err.contains(&f), "{args:?} does not name {f}: {err}");
    assert!(
        err.contains("named pipe") || err.contains("character device"),
        "{args:?}: {err}"
    );
}

#[test]
fn pipes_and_devices_are_refused_as_inputs_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    let out = out.to_str().unwrap();
    for name in ["v.vti", "v.vtk", "v_7x6x5_uint16.raw"] {
        let p = fifo(d, name);
        refused(&["info", p.to_str().unwrap()], &p);
    }
    let p = fifo(d, "p.json");
    let png = d.join("o.png");
    let png = png.to_str().unwrap();
    refused(
        &["render", VOLUME, "--tf", p.to_str().unwrap(), "--out", png],
        &p,
    );
    refused(&["convert", p.to_str().unwrap(), &format!("{out}.ct")], &p);
    let p = fifo(d, "i.png");
    let (m, t) = (MODEL, TOKENIZER);
    refused(
        &[
            "clip-score",
            p.to_str().unwrap(),
            "--caption",
            "x",
            "--model",
            m,
            "--tokenizer",
            t,
        ],
        &p,
    );
    let opt = |extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = [
            "optimize", VOLUME, "--model", m, "--steps", "1", "--out", out,
        ]
        .map(String::from)
        .to_vec();
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let run = |a: Vec<String>, p: &Path| {
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        refused(&a, p)
    };
    let p = fifo(d, "neg.txt");
    let ps = p.to_str().unwrap();
    run(
        opt(&["--tokenizer", t, "--prompt", "x", "--negatives-file", ps]),
        &p,
    );
    let zero = Path::new("/dev/zero");
    run(
        opt(&[
            "--tokenizer",
            t,
            "--prompt",
            "x",
            "--negatives-file",
            "/dev/zero",
        ]),
        zero,
    );
    let p = fifo(d, "ref.png");
    run(
        opt(&["--tokenizer", t, "--reference-image", p.to_str().unwrap()]),
        &p,
    );
    let p = fifo(d, "tokenizer.json");
    run(
        opt(&["--tokenizer", p.to_str().unwrap(), "--prompt", "x"]),
        &p,
    );
    // A model folder whose weights are a pipe.
    let model = d.join("model");
    std::fs::create_dir(&model).unwrap();
    std::fs::copy(Path::new(m).join("config.json"), model.join("config.json")).unwrap();
    let w = fifo(&model, "model.safetensors");
    let a = [
        "optimize",
        VOLUME,
        "--model",
        model.to_str().unwrap(),
        "--tokenizer",
        t,
    ];
    refused(
        &[&a[..], &["--prompt", "x", "--steps", "1", "--out", out]].concat(),
        &w,
    );
}
