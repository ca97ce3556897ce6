//! report.json repeats a run: a run started in one folder with relative paths and
//! non-default flags, run again from another folder with only what its report.json holds
//! (settings and absolute paths), writes the same TF files. Also: the hashes it records,
//! `--steps 0` from a TF needing no model, and negative numbers reaching the validation.

use std::path::{Path, PathBuf};
use std::process::Command;

use std::ops::ControlFlow;

use serde_json::Value;
use t2tf::formats::DEFAULT_MAX_PRESET_SIZE;
use t2tf::pipeline::{self, Event, InitTf, Job, Model, ModelOptions, Target};

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const NEGHIP: &str = "../shared/data/volumes/neghip_64x64x64_uint8.raw";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `t2tf optimize ARGS…` in `cwd` with its caption cache in `cache`: (success, stderr).
fn t2tf(cwd: &Path, args: &[String], cache: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .current_dir(cwd)
        .arg("optimize")
        .args(args)
        .env("XDG_CACHE_HOME", cache)
        // Nothing here may reach the Hub: a model that is looked up fails at once.
        .env("HF_HUB_OFFLINE", "1")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}

fn read_report(out: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

fn sha256(path: &Path) -> String {
    let bytes = std::fs::read(path).unwrap();
    <sha2::Sha256 as sha2::Digest>::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The same file, whichever way the two paths spell it.
fn same_file(a: &str, b: &Path) -> bool {
    Path::new(a).is_absolute()
        && std::fs::canonicalize(a).unwrap() == std::fs::canonicalize(b).unwrap()
}

/// A JSON number or string as a flag's value.
fn value(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// The flags of `t2tf optimize` that repeat the run `report` describes, built from its
/// settings and absolute paths alone (not its argv), with `--out out`.
fn flags_from(report: &Value, out: &Path) -> Vec<String> {
    let volume = &report["volume"];
    let mut a = vec![value(&volume["path"])];
    let mut flag = |name: &str, v: &Value| {
        if !v.is_null() {
            a.push(format!("--{name}"));
            a.push(value(v));
        }
    };
    let dims = volume["dims"].as_array().unwrap();
    let triple = |v: &[Value]| Value::String(v.iter().map(value).collect::<Vec<_>>().join(","));
    flag("dims", &triple(dims));
    flag("spacing", &triple(volume["spacing"].as_array().unwrap()));
    flag("dtype", &volume["dtype"]);
    flag("byte-order", &volume["byte_order"]);
    flag("array", &volume["array"]);
    flag("prompt", &report["prompt"]);
    flag("reference-image", &report["reference_image_file"]["path"]);
    for n in report["negatives"].as_array().unwrap() {
        flag("negative", n);
    }
    flag("negatives-file", &report["negatives_file"]["path"]);
    let model = &report["model"];
    flag("model", &model["folder"]);
    flag("revision", &model["revision"]);
    flag("tokenizer", &model["tokenizer"]);
    let s = &report["settings"];
    for (name, key) in [
        ("steps", "steps"),
        ("views", "views"),
        ("lr", "lr"),
        ("momentum", "momentum"),
        ("prior-weight", "prior_weight"),
        ("prior-ab", "prior_a"),
        ("prior-start", "prior_start"),
        ("l1", "l1"),
        ("l2", "l2"),
        ("control-points", "control_points"),
        ("negatives-per-step", "negatives_per_step"),
        ("seed", "seed"),
    ] {
        flag(name, &s[key]);
    }
    let r = &report["render"];
    flag("up", &r["up"]);
    flag("step-size", &r["step_size"]);
    flag("level", &r["level"]);
    flag("render-size", &r["render_size"]);
    flag("threads", &r["threads"]);
    flag("precision", &r["clip_precision"]);
    flag("max-memory", &r["max_memory"]);
    flag("init", &report["init_file"]["path"]);
    flag("preset", &report["init_preset"]);
    for l in report["locks"].as_array().into_iter().flatten() {
        let l = l.as_array().unwrap();
        flag("lock", &Value::String(format!("{},{}", l[0], l[1])));
    }
    let name = tf_name(report);
    a.extend([
        "--name".into(),
        name,
        "--out".into(),
        out.display().to_string(),
    ]);
    a
}

/// The TF files' base name, from the files the report lists.
fn tf_name(report: &Value) -> String {
    let first = report["outputs"][0].as_str().unwrap();
    first.strip_suffix(".json").unwrap().to_string()
}

fn tf_files(report: &Value) -> Vec<String> {
    let name = tf_name(report);
    ["json", "xml", "ct"]
        .iter()
        .map(|e| format!("{name}.{e}"))
        .collect()
}

#[test]
fn report_json_repeats_the_run_from_another_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let first = tmp.path().join("first");
    // Relative paths, as a user types them in the checkout, and flags away from their
    // defaults (--up above all, which report.json once left out).
    let given = strings(&[
        NEGHIP,
        "--prompt",
        "a protein molecule",
        "--negative",
        "a cube",
        "--model",
        MODEL,
        "--tokenizer",
        TOKENIZER,
        "--precision",
        "f32",
        "--up",
        "-x",
        "--steps",
        "3",
        "--views",
        "1",
        "--seed",
        "7",
        "--lr",
        "8",
        "--control-points",
        "12",
        "--negatives-per-step",
        "8",
        "--step-size",
        "0.75",
        "--threads",
        "2",
        "--progress",
        "lines",
        "--out",
    ]);
    let mut args = given.clone();
    args.push(first.display().to_string());
    let (ok, err) = t2tf(&repo(), &args, &tmp.path().join("cache1"));
    assert!(ok, "{err}");
    let report = read_report(&first);

    // The command line as given, and where it was given.
    let argv: Vec<String> = report["argv"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_str().unwrap().to_string())
        .collect();
    assert_eq!(argv[1], "optimize", "{argv:?}");
    assert_eq!(argv[2..], args[..], "{argv:?}");
    assert!(same_file(report["cwd"].as_str().unwrap(), &repo()));
    // Absolute paths, and the hash of the tokenizer read.
    assert!(same_file(
        report["volume"]["path"].as_str().unwrap(),
        &repo().join(NEGHIP)
    ));
    assert!(same_file(
        report["model"]["folder"].as_str().unwrap(),
        &repo().join(MODEL)
    ));
    assert!(same_file(
        report["model"]["tokenizer"].as_str().unwrap(),
        &repo().join(TOKENIZER)
    ));
    assert_eq!(
        report["model"]["tokenizer_sha256"],
        sha256(&repo().join(TOKENIZER)).as_str()
    );
    assert_eq!(report["render"]["up"], "-x", "{report}");
    assert_eq!(report["volume"]["dtype"], "uint8", "{report}");

    // From another folder, with only what report.json holds.
    let elsewhere = tmp.path().join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let second = tmp.path().join("second");
    let replay = flags_from(&report, &second);
    let (ok, err) = t2tf(&elsewhere, &replay, &tmp.path().join("cache2"));
    assert!(ok, "{replay:?}: {err}");
    for f in tf_files(&report) {
        let (a, b) = (
            std::fs::read(first.join(&f)).unwrap(),
            std::fs::read(second.join(&f)).unwrap(),
        );
        assert!(a == b, "{f} differs between the run and its repetition");
    }
    let again = read_report(&second);
    assert_eq!(again["settings"], report["settings"]);
    assert_eq!(again["steps"].as_array().unwrap().len(), 3);
    for (a, b) in report["steps"]
        .as_array()
        .unwrap()
        .iter()
        .zip(again["steps"].as_array().unwrap())
    {
        assert_eq!(a["total"], b["total"], "the losses differ");
    }

    // The same flags with the default --up give another TF: what the report records matters.
    let third = tmp.path().join("third");
    let mut without_up = flags_from(&report, &third);
    let at = without_up.iter().position(|a| a == "--up").unwrap();
    without_up.drain(at..at + 2);
    let (ok, err) = t2tf(&elsewhere, &without_up, &tmp.path().join("cache2"));
    assert!(ok, "{err}");
    let f = &tf_files(&report)[0];
    assert_ne!(
        std::fs::read(first.join(f)).unwrap(),
        std::fs::read(third.join(f)).unwrap(),
        "--up made no difference: the repetition proves nothing"
    );
}

#[test]
fn steps_0_from_a_tf_needs_no_model_and_records_the_hashes() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let vol = repo().join(NEGHIP);
    // A TF with opacity to start from: a short run's.
    let start = tmp.path().join("start");
    let (ok, err) = t2tf(
        &repo(),
        &strings(&[
            vol.to_str().unwrap(),
            "--prompt",
            "a protein molecule",
            "--model",
            MODEL,
            "--tokenizer",
            TOKENIZER,
            "--steps",
            "2",
            "--views",
            "1",
            "--negatives-per-step",
            "8",
            "--threads",
            "2",
            "--out",
            start.to_str().unwrap(),
            "--name",
            "start",
        ]),
        &cache,
    );
    assert!(ok, "{err}");
    let init = start.join("start.json");

    // --steps 0 with a model that does not exist: nothing resolves or loads it.
    let zero = |out: &Path, model: &str| {
        t2tf(
            tmp.path(),
            &strings(&[
                vol.to_str().unwrap(),
                "--prompt",
                "a protein molecule",
                "--steps",
                "0",
                "--init",
                "start/start.json",
                "--model",
                model,
                "--tokenizer",
                repo().join(TOKENIZER).to_str().unwrap(),
                "--threads",
                "2",
                "--up",
                "y",
                "--out",
                out.to_str().unwrap(),
                "--name",
                "zero",
            ]),
            &cache,
        )
    };
    let without = tmp.path().join("without");
    let (ok, err) = zero(&without, "no-such-org/no-such-model");
    assert!(ok, "{err}");
    let report = read_report(&without);
    assert!(report["model"].is_null(), "{report}");
    assert_eq!(report["steps_run"], 0);
    assert_eq!(report["final_scores"], serde_json::json!([]));
    assert!(same_file(
        report["init_file"]["path"].as_str().unwrap(),
        &init
    ));
    assert_eq!(report["init_file"]["sha256"], sha256(&init).as_str());
    let preset = t2tf::formats::read_tf(&init).unwrap().name;
    assert_eq!(report["init_preset"], preset.as_str());
    for f in ["zero.json", "zero.xml", "zero.ct", "preview.png", "tf.png"] {
        assert!(without.join(f).is_file(), "{f} not written");
    }

    // The library with the model gives the same TF and preview: the model changes nothing
    // at 0 steps, and the command's files are the library's.
    let volume = t2tf::volume::load(&vol, &Default::default()).unwrap();
    let mut opts = ModelOptions::new(repo().join(MODEL).to_str().unwrap());
    opts.tokenizer = Some(repo().join(TOKENIZER));
    let model = Model::load(&opts).unwrap();
    let mut job = Job::new(Target::Prompt("a protein molecule".into()));
    job.settings.steps = 0;
    job.up = "y".parse().unwrap();
    job.caption_cache = None;
    let fresh = job.clone().validate().unwrap();
    job.init = Some(InitTf::read(&init, None, DEFAULT_MAX_PRESET_SIZE).unwrap());
    let job = job.validate().unwrap();
    assert!(!job.needs_model() && fresh.needs_model());
    let go = &mut |_: Event| ControlFlow::Continue(());
    let with = pipeline::optimize(&volume, &model, &job, go).unwrap();
    let without_model = pipeline::optimize_without_model(&volume, &job, go).unwrap();
    assert_eq!(with.control_points(), without_model.control_points());
    assert_eq!(with.preview().data, without_model.preview().data);
    assert!(with.report.model.is_some() && without_model.report.model.is_none());
    let library = tmp.path().join("library");
    with.write(&library, "zero").unwrap();
    for f in ["zero.json", "zero.xml", "zero.ct", "preview.png"] {
        assert!(
            std::fs::read(without.join(f)).unwrap() == std::fs::read(library.join(f)).unwrap(),
            "{f} differs from the library's run with the model"
        );
    }
    // A job that needs the model is refused without one.
    assert!(pipeline::optimize_without_model(&volume, &fresh, go).is_err());

    // A reference image is recorded with its hash.
    let picture = start.join("preview.png");
    let like = tmp.path().join("like");
    let (ok, err) = t2tf(
        &repo(),
        &strings(&[
            vol.to_str().unwrap(),
            "--reference-image",
            picture.to_str().unwrap(),
            "--model",
            MODEL,
            "--tokenizer",
            TOKENIZER,
            "--steps",
            "1",
            "--views",
            "1",
            "--negatives-per-step",
            "8",
            "--threads",
            "2",
            "--out",
            like.to_str().unwrap(),
        ]),
        &cache,
    );
    assert!(ok, "{err}");
    let report = read_report(&like);
    let file = &report["reference_image_file"];
    assert!(same_file(file["path"].as_str().unwrap(), &picture));
    assert_eq!(file["sha256"], sha256(&picture).as_str());
}

#[test]
fn steps_0_without_a_start_still_needs_the_model() {
    let tmp = tempfile::tempdir().unwrap();
    let (ok, err) = t2tf(
        &repo(),
        &strings(&[
            NEGHIP,
            "--prompt",
            "x",
            "--steps",
            "0",
            "--model",
            tmp.path().join("no-such-model").to_str().unwrap(),
            "--out",
            tmp.path().join("out").to_str().unwrap(),
        ]),
        &tmp.path().join("cache"),
    );
    // The paper's initialization is measured at CLIP's image size: the model is loaded.
    assert!(!ok && err.contains("no-such-model"), "{err}");
}

#[test]
fn negative_numbers_reach_the_validation() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    for (flag, v, says) in [
        ("--steps", "-5", "--steps -5 must be 0 or more"),
        ("--views", "-1", "--views -1 must be 0 or more"),
        ("--threads", "-2", "--threads -2 must be 0 or more"),
        (
            "--seed",
            "-1",
            "--seed -1 must be a whole number from 0 to 18446744073709551615",
        ),
        (
            "--steps",
            "18446744073709551615",
            "--steps: must be at most 1000000",
        ),
        (
            "--step-size",
            "-1",
            "--step-size must be a positive number of voxels, got -1",
        ),
        ("--lr", "-0.5", "--lr: must be finite and ≥ 0, got -0.5"),
        (
            "--max-memory",
            "-1G",
            "invalid value '-1G' for '--max-memory <SIZE>'",
        ),
    ] {
        let (ok, err) = t2tf(
            &repo(),
            &strings(&[NEGHIP, "--prompt", "x", flag, v, "--model", MODEL]),
            &cache,
        );
        assert!(!ok, "{flag} {v} was accepted");
        assert!(err.contains(says), "{flag} {v}: {err}");
        assert!(!err.contains("tip:"), "{flag} {v}: {err}");
        // Ours are one line; a value clap checks gets its own message and clap's pointer to
        // --help.
        if !says.starts_with("invalid value") {
            assert_eq!(err.trim().lines().count(), 1, "{err}");
        }
    }
}
