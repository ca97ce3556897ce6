//! Hostile outputs, inputs and signals, through the binary: outputs that are not ours are refused
//! (devices, FIFOs, folders); a symlink given as an output is followed only when it is the
//! caller's, and one planted in an output folder or the caption cache is replaced, its target
//! untouched; sizes from headers and flags end in a clean
//! error under an address-space limit, never in an abort (exit 134); `optimize` writes its files as
//! one set under a lock, stops on SIGTERM with exit 143 after writing, and a SIGKILL leaves the
//! previous complete set, cleaned up by the next run. Every bad file is made by the test.

use crate::limits_util::limit_address_space;
use crate::reap::Reaped;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const VOLUME: &str = "tests/fixtures/volumes/ramp_7x6x5_uint16.raw";

fn t2tf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_t2tf"))
}

fn run(cmd: &mut Command) -> (i32, String) {
    let out: Output = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    (out.status.code().unwrap_or(-1), err)
}

/// A ParaView JSON preset over 0..65535 (the ramp's range is inside it).
fn preset(dir: &Path) -> PathBuf {
    let p = dir.join("tf.json");
    std::fs::write(
        &p,
        r#"[{"Name":"t","ColorSpace":"RGB","RGBPoints":[0,1,0,0,65535,0,0,1],"Points":[0,0,0.5,0,65535,1,0.5,0]}]"#,
    )
    .unwrap();
    p
}

fn render(out: &Path, extra: &[&str]) -> (i32, String) {
    let dir = tempfile::tempdir().unwrap();
    let tf = preset(dir.path());
    run(t2tf()
        .args(["render", VOLUME, "--size", "16", "--tf"])
        .arg(&tf)
        .arg("--out")
        .arg(out)
        .args(extra))
}

fn make_fifo(p: &Path) {
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: mkfifo reads a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
}

#[test]
fn render_refuses_dev_full_and_fifos_and_follows_symlinks() {
    let dir = tempfile::tempdir().unwrap();
    // /dev/full itself, through a symlink named .png: refused, the device untouched.
    let link = dir.path().join("full.png");
    std::os::unix::fs::symlink("/dev/full", &link).unwrap();
    let (code, err) = render(&link, &[]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("not a regular file"), "{err}");
    let fifo = dir.path().join("pipe.png");
    make_fifo(&fifo);
    let (code, err) = render(&fifo, &[]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("a FIFO"), "{err}");
    use std::os::unix::fs::FileTypeExt;
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo());
    // A symlink to a regular file: the link stays, its target gets the image.
    let real = dir.path().join("real.png");
    std::fs::write(&real, b"old").unwrap();
    let link = dir.path().join("view.png");
    std::os::unix::fs::symlink("real.png", &link).unwrap();
    let (code, err) = render(&link, &[]);
    assert_eq!(code, 0, "{err}");
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(std::fs::read(&real).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn convert_refuses_devices_and_fifos_and_overflowing_rescale() {
    let dir = tempfile::tempdir().unwrap();
    let tf = preset(dir.path());
    let fifo = dir.path().join("out.ct");
    make_fifo(&fifo);
    let (code, err) = run(t2tf().arg("convert").arg(&tf).arg(&fifo));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("a FIFO"), "{err}");
    let link = dir.path().join("null.json");
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    let (code, err) = run(t2tf().arg("convert").arg(&tf).arg(&link));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("a device"), "{err}");
    let out = dir.path().join("wide.json");
    let (code, err) = run(t2tf()
        .arg("convert")
        .arg(&tf)
        .arg(&out)
        .arg("--rescale=-1e308,1e308"));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("too wide"), "{err}");
    assert!(!out.exists());
}

/// A file outside every output, and what it holds.
fn victim(dir: &Path) -> (PathBuf, &'static str) {
    let v = dir.join("victim.txt");
    let text = "the victim's own contents\n";
    std::fs::write(&v, text).unwrap();
    (v, text)
}

fn is_regular(p: &Path) -> bool {
    std::fs::symlink_metadata(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .file_type()
        .is_file()
}

#[test]
fn symlinks_planted_in_the_output_folder_and_the_cache_are_replaced_not_followed() {
    let dir = tempfile::tempdir().unwrap();
    let (victim, text) = victim(dir.path());
    let cache = dir.path().join("cache");
    // A first run fills the caption cache; its file is then swapped for a symlink.
    let args = ["--steps", "1", "--prompt", "x", "--name", "t"];
    let (code, err) = run(&mut optimize(&dir.path().join("first"), &cache, &args));
    assert_eq!(code, 0, "{err}");
    let embeddings = cache.join("t2tf/text-embeddings");
    let cached: Vec<PathBuf> = std::fs::read_dir(&embeddings)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(cached.len(), 1, "{cached:?}");
    let cache_file = &cached[0];
    std::fs::remove_file(cache_file).unwrap();
    std::os::unix::fs::symlink(&victim, cache_file).unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let planted = ["report.json", "preview.png", "t.json", ".t2tf.lock"];
    for name in planted {
        std::os::unix::fs::symlink(&victim, out.join(name)).unwrap();
    }
    let (code, err) = run(&mut optimize(&out, &cache, &args));
    assert_eq!(code, 0, "{err}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), text);
    let report = one_complete_set(&out);
    assert!(report["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .any(|n| n == "t.json"));
    for name in ["report.json", "preview.png", "t.json"] {
        assert!(is_regular(&out.join(name)), "{name} is still a symlink");
    }
    assert!(std::fs::read(out.join("preview.png"))
        .unwrap()
        .starts_with(b"\x89PNG"));
    let preset: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("t.json")).unwrap()).unwrap();
    assert!(preset[0]["RGBPoints"].is_array(), "{preset}");
    // The lock file lived only while the run did; the cache holds embeddings again.
    assert!(std::fs::symlink_metadata(out.join(".t2tf.lock")).is_err());
    assert!(is_regular(cache_file));
    assert!(std::fs::read(cache_file).unwrap().len() > text.len());
}

#[test]
fn an_output_symlink_of_another_user_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (victim, text) = victim(dir.path());
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("skipped: giving a symlink to another user (lchown) needs root");
        return;
    }
    let tf = preset(dir.path());
    for (name, cmd) in [("view.png", "render"), ("tf.ct", "convert")] {
        let link = dir.path().join(name);
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        std::os::unix::fs::lchown(&link, Some(65534), Some(65534)).unwrap();
        let (code, err) = if cmd == "render" {
            render(&link, &[])
        } else {
            run(t2tf().arg("convert").arg(&tf).arg(&link))
        };
        assert_eq!(code, 1, "{cmd}: {err}");
        assert!(
            err.contains("symlink owned by another user (uid 65534)"),
            "{cmd}: {err}"
        );
        assert_eq!(err.trim_end().lines().count(), 1, "{cmd}: {err}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), text);
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
    }
    // The same links, the caller's own, are followed.
    let own = dir.path().join("own.ct");
    std::os::unix::fs::symlink(&victim, &own).unwrap();
    let (code, err) = run(t2tf().arg("convert").arg(&tf).arg(&own));
    assert_eq!(code, 0, "{err}");
    assert!(std::fs::read_to_string(&victim).unwrap() != text);
}

const AS_LIMIT: u64 = 2 << 30;

#[test]
fn huge_orbit_sheets_are_a_clean_error_under_a_memory_limit() {
    let dir = tempfile::tempdir().unwrap();
    let tf = preset(dir.path());
    for extra in [
        &["--orbit", "64", "--size", "8192"][..],
        &["--orbit", "100000"][..],
    ] {
        let (code, err) = run(limit_address_space(
            t2tf()
                .args(["render", VOLUME, "--tf"])
                .arg(&tf)
                .arg("--out")
                .arg(dir.path().join("sheet.png"))
                .args(extra),
            AS_LIMIT,
        ));
        assert_eq!(code, 1, "{extra:?}: {err}");
        assert!(err.contains("--max-memory"), "{err}");
    }
}

/// A valid PNG header claiming `w`×`h` pixels followed by one tiny IDAT: 74 bytes or so.
fn lying_png(path: &Path, w: u32, h: u32) {
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend((data.len() as u32).to_be_bytes());
        let mut crc = flate2::Crc::new();
        crc.update(kind);
        crc.update(data);
        out.extend(kind);
        out.extend(data);
        out.extend(crc.sum().to_be_bytes());
    }
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(w.to_be_bytes());
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, 2, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(
        &mut png,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    chunk(&mut png, b"IEND", &[]);
    std::fs::write(path, png).unwrap();
}

fn optimize(out: &Path, cache: &Path, extra: &[&str]) -> Command {
    optimize_with_progress(out, cache, "json", extra)
}

/// `t2tf optimize` of the test volume with the test model on one thread into `out`, its
/// caption cache in `cache`, progress as `progress` says.
pub(crate) fn optimize_with_progress(
    out: &Path,
    cache: &Path,
    progress: &str,
    extra: &[&str],
) -> Command {
    let mut c = t2tf();
    c.env("XDG_CACHE_HOME", cache)
        .args([
            "optimize",
            VOLUME,
            "--model",
            MODEL,
            "--tokenizer",
            TOKENIZER,
        ])
        .args(["--threads", "1", "--progress", progress, "--out"])
        .arg(out)
        .args(extra);
    c
}

#[test]
fn a_png_claiming_100000_squared_pixels_is_a_clean_error() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("liar.png");
    lying_png(&png, 100_000, 100_000);
    let (code, err) = run(limit_address_space(
        optimize(&dir.path().join("out"), dir.path(), &["--steps", "1"])
            .arg("--reference-image")
            .arg(&png),
        8 << 30,
    ));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("100000×100000") && err.contains("--max-memory"),
        "{err}"
    );
}

#[test]
fn spacings_whose_box_single_precision_cannot_hold_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let tf = preset(dir.path());
    for s in ["1e300,1,1", "1e-300,1e-300,1e-300"] {
        let (code, err) = run(t2tf()
            .args(["render", VOLUME, "--spacing", s, "--tf"])
            .arg(&tf)
            .arg("--out")
            .arg(dir.path().join("v.png")));
        assert_eq!(code, 1, "{s}: {err}");
        assert!(err.contains("single precision"), "{err}");
    }
}

/// Start a long `optimize` and return once it has finished a step (its progress line).
fn start_long_run(out: &Path, cache: &Path) -> Reaped {
    let mut child = Reaped::spawn(
        optimize(out, cache, &["--steps", "100000", "--prompt", "x"]).stderr(Stdio::piped()),
    );
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    loop {
        let line = lines.next().expect("optimize ended before a step").unwrap();
        if line.contains("\"event\":\"step\"") {
            break;
        }
    }
    // Keep draining so the child never blocks on a full pipe.
    std::thread::spawn(move || for _ in lines {});
    child
}

fn signal(child: &Child, sig: i32) {
    // SAFETY: kill sends a signal to our own child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, sig) }, 0);
}

/// The folder holds exactly one complete set: report.json lists files that all exist, and no
/// staging folder or temporary is left.
fn one_complete_set(out: &Path) -> serde_json::Value {
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    for name in report["outputs"].as_array().unwrap() {
        assert!(out.join(name.as_str().unwrap()).is_file(), "{name} missing");
    }
    for e in std::fs::read_dir(out).unwrap() {
        let n = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!n.starts_with(".t2tf-"), "{n} left in {}", out.display());
    }
    report
}

#[test]
fn sigterm_and_sighup_write_the_result_and_exit_128_plus_the_signal() {
    for (sig, code) in [
        (libc::SIGTERM, 143),
        (libc::SIGHUP, 129),
        (libc::SIGINT, 130),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let mut child = start_long_run(&out, dir.path());
        signal(&child, sig);
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "signal {sig}");
        let report = one_complete_set(&out);
        assert!(report["outputs"].as_array().unwrap().len() >= 5);
        // The lock is released and its file removed on this path too (it exits early).
        assert!(
            !out.join(".t2tf.lock").exists(),
            "signal {sig}: lock file left"
        );
    }
}

#[test]
fn a_second_run_into_the_same_folder_is_refused_naming_the_first() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut first = start_long_run(&out, dir.path());
    let (code, err) = run(&mut optimize(
        &out,
        dir.path(),
        &["--steps", "1", "--prompt", "x"],
    ));
    signal(&first, libc::SIGTERM);
    assert_eq!(first.wait().unwrap().code(), Some(143));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains(&format!("process {}", first.id())), "{err}");
    one_complete_set(&out);
}

#[test]
fn sigkill_keeps_the_previous_set_and_the_next_run_cleans_up() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let (code, err) = run(&mut optimize(
        &out,
        dir.path(),
        &["--steps", "1", "--prompt", "x"],
    ));
    assert_eq!(code, 0, "{err}");
    let before = std::fs::read(out.join("report.json")).unwrap();
    for _ in 0..3 {
        let mut child = start_long_run(&out, dir.path());
        signal(&child, libc::SIGKILL);
        child.wait().unwrap();
        assert_eq!(std::fs::read(out.join("report.json")).unwrap(), before);
        one_complete_set(&out);
    }
    // What a run killed while writing leaves: a temporary and a half-staged set.
    std::fs::write(out.join(".t2tf-2147483632-x.partial"), "half").unwrap();
    std::fs::create_dir(out.join(".t2tf-set-2147483632")).unwrap();
    let (code, err) = run(&mut optimize(
        &out,
        dir.path(),
        &["--steps", "1", "--prompt", "x"],
    ));
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("cleaned up"), "{err}");
    one_complete_set(&out);
}

#[test]
fn out_is_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, "x").unwrap();
    let (code, err) = run(&mut optimize(
        &file.join("out"),
        dir.path(),
        &["--steps", "1", "--prompt", "x"],
    ));
    assert_eq!(code, 1, "{err}");
    assert!(!err.contains("\"event\":\"step\""), "{err}");
}

#[test]
fn a_volume_too_large_for_memory_is_a_clean_error_not_an_abort() {
    // 8 GiB of uint8 (a sparse file: no disk is used) under a 2 GiB address-space limit.
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("big_2048x2048x2048_uint8.raw");
    std::fs::File::create(&raw)
        .unwrap()
        .set_len(2048 * 2048 * 2048)
        .unwrap();
    // `render` loads the volume (`info` streams it and succeeds: tests/volume/hostile_volumes.rs).
    let (code, err) = run(limit_address_space(
        t2tf()
            .arg("render")
            .arg(&raw)
            .arg("--tf")
            .arg(preset(dir.path()))
            .arg("--out")
            .arg(dir.path().join("x.png")),
        AS_LIMIT,
    ));
    assert_eq!(code, 1, "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("big_2048x2048x2048_uint8.raw"), "{err}");
    assert!(err.contains("GiB"), "does not say how much: {err}");
}

#[test]
fn threads_beyond_the_cpus_are_capped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let negatives = dir.path().join("negatives.txt");
    std::fs::write(&negatives, "a red car\n").unwrap();
    let start = std::time::Instant::now();
    let (code, err) = run(t2tf()
        .env("XDG_CACHE_HOME", dir.path().join("cache"))
        .args([
            "optimize", VOLUME, "--prompt", "x", "--steps", "1", "--views", "1",
        ])
        .args([
            "--model",
            MODEL,
            "--tokenizer",
            TOKENIZER,
            "--threads",
            "10000",
        ])
        .arg("--negatives-file")
        .arg(&negatives)
        .arg("--out")
        .arg(dir.path().join("out")));
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("--threads 10000 is more than"), "{err}");
    // 10,000 threads took over a minute to start; the capped pool takes none of that.
    assert!(start.elapsed().as_secs() < 60, "took {:?}", start.elapsed());
}

/// Nothing of a run is left in `dir`'s subtree: no staging folder, temporary or lock.
fn no_run_traces(dir: &Path) {
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten() {
            let e = e.unwrap();
            let n = e.file_name().to_string_lossy().into_owned();
            assert!(!n.starts_with(".t2tf"), "{n} left in {}", d.display());
            if e.file_type().unwrap().is_dir() {
                stack.push(e.path());
            }
        }
    }
}

#[test]
fn every_output_name_is_checked_before_any_work() {
    // An obstacle must end the run before any step (and before an earlier prompt of a batch
    // runs): with `--steps 100000` a run takes minutes, so a quick error shows nothing ran.
    let long = ["--steps", "100000"];
    let dir = tempfile::tempdir().unwrap();
    let quick = |out: &Path, extra: &[&str]| {
        let start = std::time::Instant::now();
        let (code, err) = run(&mut optimize(out, dir.path(), &[&long[..], extra].concat()));
        assert!(start.elapsed().as_secs() < 20, "{extra:?} ran: {err}");
        assert_eq!(code, 1, "{extra:?}: {err}");
        err
    };
    // A TF name that is the report's (from --out here; from a prompt in the batch below and
    // in pipeline::naming's tests).
    let err = quick(&dir.path().join("report"), &["--prompt", "x"]);
    assert!(err.contains("report.json would be overwritten"), "{err}");
    assert!(err.contains("--out") && err.contains("--name"), "{err}");
    assert!(
        !dir.path().join("report").exists(),
        "an empty folder was left"
    );
    // A folder where a file of the set goes.
    let o = dir.path().join("o");
    std::fs::create_dir_all(o.join("o.json")).unwrap();
    let err = quick(&o, &["--prompt", "x"]);
    assert!(
        err.contains("o.json") && err.contains("not a regular file"),
        "{err}"
    );
    no_run_traces(&o);
    // A batch: a prompt named like the report, a folder at presets.json, an obstacle in the
    // second prompt's sub-folder; the first prompt's files are never written.
    let b = dir.path().join("b");
    let two = ["--prompt", "a tree", "--prompt", "a rock"];
    let err = quick(&b, &["--prompt", "a tree", "--prompt", "Report"]);
    assert!(err.contains("\"report\""), "{err}");
    std::fs::create_dir_all(b.join("presets.json")).unwrap();
    let err = quick(&b, &two);
    assert!(err.contains("presets.json"), "{err}");
    std::fs::remove_dir(b.join("presets.json")).unwrap();
    make_fifo(&{
        std::fs::create_dir_all(b.join("a-rock")).unwrap();
        b.join("a-rock").join("preview.png")
    });
    let err = quick(&b, &two);
    assert!(err.contains("preview.png") && err.contains("FIFO"), "{err}");
    assert!(!b.join("a-tree").exists(), "the first prompt ran");
    no_run_traces(&b);
}

#[test]
fn a_symlink_at_presets_json_is_replaced_not_followed() {
    let dir = tempfile::tempdir().unwrap();
    let (victim, text) = victim(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    std::os::unix::fs::symlink(&victim, out.join("presets.json")).unwrap();
    let (code, err) = run(&mut optimize(
        &out,
        dir.path(),
        &["--steps", "1", "--prompt", "a tree", "--prompt", "a rock"],
    ));
    assert_eq!(code, 0, "{err}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), text);
    assert!(is_regular(&out.join("presets.json")));
    let presets: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("presets.json")).unwrap()).unwrap();
    assert_eq!(presets.as_array().unwrap().len(), 2);
}

#[test]
fn a_signal_before_any_step_says_nothing_was_written() {
    // Whether the signal lands while loading or after the run began, the last line must say
    // what is there: nothing (and no folder), or a complete set.
    for delay_ms in [0u64, 20, 80] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let child = Reaped::spawn(
            optimize(&out, dir.path(), &["--steps", "100000", "--prompt", "x"])
                .stderr(Stdio::piped()),
        );
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        signal(&child, libc::SIGTERM);
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        if o.status.code().is_none() {
            // The signal came before the process installed its handlers: the system ended
            // it, before any output could exist.
            assert!(!out.join("report.json").exists());
            continue;
        }
        assert_eq!(o.status.code(), Some(143), "{err}");
        if err.contains("nothing was written") {
            assert!(
                !out.exists(),
                "said nothing was written, but {} exists",
                out.display()
            );
        } else {
            assert!(err.contains("was written to"), "{err}");
            one_complete_set(&out);
        }
    }
}

/// A write that fails part way through a set (a full disk; here a file-size limit, which
/// fails the same `write`) ends the run with one line naming the file, and leaves no staged
/// files, no half set and no folder the run created; the previous set in a folder stays.
#[test]
fn a_failed_write_leaves_no_staged_set() {
    use crate::limits_util::limit_file_size;
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let fresh = dir.path().join("fresh");
    // The TF files and scripts are a few KiB and the preview PNG over 100 KiB: some files of
    // the set are written before one fails.
    let mut cmd = optimize(&fresh, &cache, &["--steps", "1", "--prompt", "x"]);
    let (code, err) = run(limit_file_size(&mut cmd, 64 << 10));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("File too large"), "{err}");
    let errors: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("t2tf: error"))
        .collect();
    assert!(
        errors.len() == 1 && errors[0].contains("writing failed"),
        "{err}"
    );
    assert!(!fresh.exists(), "the run's own folder was left");
    // Into a folder with a complete set: that set is kept as it was.
    let kept = dir.path().join("kept");
    let (code, err) = run(&mut optimize(
        &kept,
        &cache,
        &["--steps", "1", "--prompt", "x"],
    ));
    assert_eq!(code, 0, "{err}");
    let before = one_complete_set(&kept);
    let mut cmd = optimize(&kept, &cache, &["--steps", "2", "--prompt", "x"]);
    let (code, err) = run(limit_file_size(&mut cmd, 64 << 10));
    assert_eq!(code, 1, "{err}");
    no_run_traces(&kept);
    assert_eq!(one_complete_set(&kept), before);
}

/// A batch killed between prompts leaves a presets.json of the prompts it finished, never the
/// previous run's beside its new sub-folders.
#[test]
fn a_killed_batch_leaves_a_library_of_its_finished_prompts_only() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let library = |out: &Path| -> Vec<String> {
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("presets.json")).unwrap()).unwrap();
        let names = v.as_array().unwrap().iter();
        names
            .map(|p| p["Name"].as_str().unwrap().to_string())
            .collect()
    };
    let before = ["--steps", "1", "--prompt", "old one", "--prompt", "old two"];
    let (code, err) = run(&mut optimize(&out, dir.path(), &before));
    assert_eq!(code, 0, "{err}");
    assert_eq!(library(&out).len(), 2);
    // 3000 steps take seconds on the test model: killed as the second prompt starts, the
    // first one's files and the library are written and the second's are not.
    let mut child = Reaped::spawn(
        optimize(&out, dir.path(), &["--steps", "3000", "--prompt", "new"])
            .args(["--prompt", "newer"])
            .stderr(Stdio::piped()),
    );
    let lines = BufReader::new(child.stderr.take().unwrap()).lines();
    for line in lines {
        if line.unwrap().contains("prompt 2 of 2") {
            break;
        }
    }
    signal(&child, libc::SIGKILL);
    child.wait().unwrap();
    let names = library(&out);
    assert_eq!(names.len(), 1, "{names:?}");
    assert!(names[0].starts_with("new-"), "{names:?}");
    one_complete_set(&out.join("new"));
}
