//! `t2tf optimize`: the flags and their defaults as `--help` prints them, argument errors from
//! the binary, and `execute` (everything after loading) on the analytic stand-ins.

mod optimize_toy;

use std::path::Path;
use std::process::Command;

use clap::Parser;
use optimize_toy::*;
use t2tf::cli::optimize::{execute, Loaded, OptimizeArgs};
use t2tf::optimize::report::{ModelInfo, VolumeInfo};
use t2tf::optimize::tf_plot::Curve;

fn t2tf(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn help_lists_every_flag_with_the_papers_default() {
    let (ok, help, _) = t2tf(&["optimize", "--help"]);
    assert!(ok);
    let help = help.replace('\n', " ");
    for (flag, default) in [
        ("--steps", "300"),
        ("--views", "3"),
        ("--lr", "10"),
        ("--momentum", "0.75"),
        ("--prior-weight", "0.02"),
        ("--prior-ab", "0.5"),
        ("--prior-start", "100"),
        ("--l1", "0.00002"),
        ("--l2", "0.0008"),
        ("--control-points", "32"),
        ("--negatives-per-step", "128"),
        ("--seed", "0"),
        ("--model", "openai/clip-vit-base-patch32"),
        ("--out", "t2tf-output"),
    ] {
        let at = help
            .find(&format!("{flag} "))
            .unwrap_or_else(|| panic!("{flag} missing from --help"));
        let rest = &help[at..];
        let next = rest[2..].find("  --").map_or(rest.len(), |i| i + 2);
        assert!(
            rest[..next].contains(&format!("[default: {default}]")),
            "{flag} should show [default: {default}]: {}",
            &rest[..next]
        );
    }
    for flag in [
        "--prompt",
        "--negative ",
        "--name",
        "--negatives-file",
        "--reference-image",
        "--step-size",
        "--level",
        "--render-size",
        "--threads",
    ] {
        assert!(help.contains(flag), "{flag} missing from --help");
    }
}

#[test]
fn argument_errors_are_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, _, err) = t2tf(&["optimize", "no-such-volume.raw", "--prompt", "x"]);
    assert!(!ok && err.contains("no-such-volume.raw"), "{err}");
    let vol = dir.path().join("v_2x2x2_uint8.raw");
    std::fs::write(&vol, [0u8; 8]).unwrap();
    let v = vol.to_str().unwrap();
    let (ok, _, err) = t2tf(&["optimize", v, "--prompt", " "]);
    assert!(!ok && err.contains("--prompt is empty"), "{err}");
    let (ok, _, err) = t2tf(&["optimize", v, "--prompt", "x", "--views", "0"]);
    assert!(!ok && err.contains("--views"), "{err}");
    let (ok, _, err) = t2tf(&["optimize", v]);
    assert!(!ok && err.contains("--prompt"), "{err}");
    let (ok, _, err) = t2tf(&["optimize", v, "--prompt", "x", "--render-size", "4"]);
    assert!(
        !ok && err.contains("--render-size must be 8 to 4096"),
        "{err}"
    );
}

#[derive(Parser)]
struct Wrap {
    #[command(flatten)]
    args: OptimizeArgs,
}

fn loaded() -> Loaded {
    let mut histogram = vec![100u64; 256];
    histogram[0] = 50_000;
    Loaded {
        histogram,
        volume: VolumeInfo {
            path: "toy".into(),
            dims: [6, 6, 1],
            spacing: [1.0; 3],
            range: [0.0, 1.0],
            non_finite_voxels: 0,
        },
        model: ModelInfo {
            id: "toy".into(),
            revision: None,
            weights_sha256: Some("00".into()),
            logit_scale: 100.0,
        },
        weights_hash: Some(b"toy weights".to_vec()),
        render: serde_json::json!({"step_size": 0.5}),
        preview_views: 4,
        tf_curve: Curve::Opacity {
            unit_over_length: 1.0 / 6.0,
        },
    }
}

#[test]
fn execute_writes_the_outputs_and_reuses_the_caption_cache() {
    let dir = tempfile::tempdir().unwrap();
    // The cache goes under XDG_CACHE_HOME (only this test in this binary reads it).
    std::env::set_var("XDG_CACHE_HOME", dir.path().join("cache"));
    let f = Fixture::new();
    let t = ToyText {
        known: vec![("a red and yellow thing".into(), f.positive.clone())],
        calls: 0.into(),
        texts: 0.into(),
    };
    let out = dir.path().join("red-thing");
    let argv = [
        "t2tf",
        "toy.raw",
        "--prompt",
        "a red and yellow thing",
        "--steps",
        "20",
        "--views",
        "2",
        "--lr",
        "0.05",
        "--control-points",
        "5",
        "--negatives-per-step",
        "16",
        "--out",
        out.to_str().unwrap(),
    ];
    let args = Wrap::try_parse_from(argv).unwrap().args;
    let exported = std::cell::RefCell::new(Vec::new());
    let mut export =
        |d: &Path, name: &str, cp: &t2tf::tf::ControlPoints| -> anyhow::Result<Vec<String>> {
            let file = format!("{name}.json");
            std::fs::write(d.join(&file), format!("{:?}", cp.sigma))?;
            exported.borrow_mut().push(cp.clone());
            Ok(vec![file])
        };
    let report = execute(&args, &loaded(), &f.toy, &f.enc, &t, &TanhTf, &mut export).unwrap();
    assert_eq!(report.steps_run, 20);
    assert_eq!(report.negatives, vec!["a blank image"]);
    assert_eq!(report.caption_pool, "builtin");
    assert!(report.caption_pool_size >= 5000);
    assert_eq!(report.render["step_size"], 0.5);
    for name in [
        // Named after the --out folder.
        "red-thing.json",
        "tf.png",
        "preview.png",
        "report.json",
    ] {
        assert!(out.join(name).is_file(), "{name} missing");
        assert!(
            report.outputs.iter().any(|o| o == name),
            "{name} not listed"
        );
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["prompt"], "a red and yellow thing");
    assert_eq!(json["model"]["id"], "toy");
    assert_eq!(json["settings"]["steps"], 20);
    let done = exported.borrow().clone();
    assert_eq!(done.len(), 1);
    assert_eq!(done[0].len(), 5);
    assert!(done[0]
        .sigma
        .iter()
        .all(|s| s.is_finite() && (0.0..=255.0).contains(s)));
    // The whole pool was encoded once, then cached: a second run encodes only 2 texts.
    let first = t.texts.get();
    assert!(first >= report.caption_pool_size);
    let cached = std::fs::read_dir(dir.path().join("cache/t2tf/text-embeddings"))
        .unwrap()
        .count();
    assert_eq!(cached, 1);
    execute(&args, &loaded(), &f.toy, &f.enc, &t, &TanhTf, &mut export).unwrap();
    assert_eq!(t.texts.get() - first, 2);
}
