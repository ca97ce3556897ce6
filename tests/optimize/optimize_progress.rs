//! Progress of `t2tf optimize` where no terminal is watching: plain lines in a log or pipe,
//! and one JSON object per line with `--progress json` (what the ParaView plugin parses).

use std::path::Path;
use std::process::Command;

use serde_json::Value;

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const NUCLEON: &str = "../shared/data/volumes/nucleon_41x41x41_uint8.raw";

/// A short run with stderr piped (so not a terminal); returns stderr.
fn run(out: &Path, extra: &[&str]) -> String {
    let negatives = out.with_extension("negatives.txt");
    std::fs::write(&negatives, "a red car\na bowl of fruit\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .env("XDG_CACHE_HOME", out.with_extension("cache"))
        .args(["optimize", NUCLEON, "--prompt", "a nucleon"])
        .args(["--model", MODEL, "--tokenizer", TOKENIZER, "--threads", "2"])
        .args(["--steps", "6", "--views", "1", "--prior-start", "3"])
        .arg("--negatives-file")
        .arg(&negatives)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .expect("the t2tf binary runs");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    err
}

#[test]
fn a_pipe_gets_plain_step_lines() {
    let dir = tempfile::tempdir().unwrap();
    let err = run(&dir.path().join("run"), &[]);
    // The first and the last step are always said; in between at most one line per 5 s.
    let steps: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("t2tf: step "))
        .collect();
    assert!(
        steps
            .first()
            .is_some_and(|l| l.starts_with("t2tf: step 1/6 ")),
        "{err}"
    );
    assert!(
        steps
            .last()
            .is_some_and(|l| l.starts_with("t2tf: step 6/6 ")),
        "{err}"
    );
    for l in &steps {
        assert!(l.contains("loss") && l.contains("ETA"), "{l}");
    }
    // The first step has no estimate yet; the last has one.
    assert!(steps[0].ends_with("ETA …"), "{}", steps[0]);
    assert!(steps.last().unwrap().ends_with("ETA 0 s"), "{err}");
    assert!(
        !err.contains('\r') && !err.contains('\u{1b}'),
        "terminal codes in a log: {err:?}"
    );
}

#[test]
fn json_progress_is_one_object_per_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let err = run(&out, &["--progress", "json"]);
    let events: Vec<Value> = err
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{l}: {e}")))
        .collect();
    let steps: Vec<&Value> = events.iter().filter(|e| e["event"] == "step").collect();
    assert_eq!(steps.len(), 6, "{err}");
    for (i, s) in steps.iter().enumerate() {
        assert_eq!(s["step"], i + 1);
        assert_eq!(s["steps"], 6);
        for key in ["loss", "elapsed_s", "p_prompt"] {
            assert!(s[key].as_f64().is_some_and(f64::is_finite), "{key}: {s}");
        }
        // No estimate from the first steps: the first carries one-off work.
        if i < 2 {
            assert!(s["eta_s"].is_null(), "step {}: {s}", i + 1);
        } else {
            assert!(s["eta_s"].as_f64().is_some_and(f64::is_finite), "{s}");
        }
    }
    assert_eq!(steps[5]["eta_s"], 0.0);
    let done = events.last().unwrap();
    assert_eq!(done["event"], "done", "{err}");
    assert_eq!(done["interrupted"], false);
    let files: Vec<&str> = done["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    // Files are named after the --out folder.
    assert!(files.contains(&"run.json"), "{files:?}");
    for f in files {
        assert!(out.join(f).is_file(), "{f} listed but not written");
    }
    // report.json says which matrix kernel CLIP ran on.
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let engine = report["render"]["clip_engine"].as_str().unwrap_or_default();
    assert!(engine.contains("engine"), "{report}");
    // And what else it takes to reproduce the run: the precision `auto` (the default) chose,
    // and why; bf16 only where this CPU has a bf16 kernel.
    let precision = match report["render"]["clip_precision"].as_str() {
        Some("f32") => t2tf::clip::Precision::F32,
        Some("bf16") if t2tf::clip::Precision::Bf16.native() => t2tf::clip::Precision::Bf16,
        other => panic!("clip_precision {other:?} on this CPU: {report}"),
    };
    assert!(engine.contains("chosen by auto"), "{report}");
    // One copy of the image tower's weights where the f32 kernel reads it fast (AVX2), else
    // two (this small model fits any budget twice; bf16 layers always keep two).
    let compute = t2tf::clip::Compute::new(precision);
    let copies = if compute.prefers_one_copy() {
        1
    } else {
        compute.backward_weight_copies()
    };
    assert_eq!(report["render"]["clip_weight_copies"], copies, "{report}");
    assert_eq!(report["render"]["threads"], 2, "{report}");
    assert!(report["settings"]["seed"].is_u64(), "{report}");
    assert_eq!(report["version"], env!("CARGO_PKG_VERSION"));
    let commit = report["commit"].as_str().unwrap();
    assert!(commit == "unknown" || commit.len() == 40, "{commit}");
    let tokenizer = std::fs::read(TOKENIZER).unwrap();
    let want: String = <sha2::Sha256 as sha2::Digest>::digest(&tokenizer)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert_eq!(report["model"]["tokenizer_sha256"], want.as_str());
    assert_eq!(
        report["model"]["weights_sha256"].as_str().map(str::len),
        Some(64)
    );
    assert!(report["machine"]["logical_cpus"]
        .as_u64()
        .is_some_and(|n| n >= 1));
    assert!(report["machine"]["cpu_flags"].is_array(), "{report}");
    // The output lock lives only while the run does.
    assert!(
        !out.join(".t2tf.lock").exists(),
        "the lock file was left behind"
    );
}
