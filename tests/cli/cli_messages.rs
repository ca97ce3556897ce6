//! What a new user sees when something is wrong, through the binary: one line on stderr
//! that names the file or flag, says each cause once, a non-zero exit, and no output file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const NUCLEON: &str = "../shared/data/volumes/nucleon_41x41x41_uint8.raw";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn t2tf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .output()
        .expect("run t2tf")
}

/// Run a command that must fail: exit status 1, stderr one line that contains every
/// `needle` and none of the `absent`, and in which no `: `-separated part is repeated
/// (a cause said twice, e.g. an io error that is both the message and its source).
fn fails(args: &[&str], needles: &[&str], absent: &[&str]) -> String {
    let o = t2tf(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: lacks '{n}': {err}");
    }
    for a in absent {
        assert!(!err.contains(a), "{args:?}: says '{a}': {err}");
    }
    let parts: Vec<&str> = err.trim_end().split(": ").collect();
    for (i, p) in parts.iter().enumerate() {
        assert!(!parts[..i].contains(p), "'{p}' said twice: {err}");
    }
    err
}

/// A ParaView preset for the 0..255 range (t2tf's JSON shape).
fn write_preset(dir: &Path) -> PathBuf {
    let p = dir.join("tf.json");
    std::fs::write(
        &p,
        r#"[{"Name":"t","ColorSpace":"RGB","RGBPoints":[0,0,0,1, 255,1,1,1],
            "Points":[0,0,0.5,0, 255,0.8,0.5,0]}]"#,
    )
    .unwrap();
    p
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn missing_files_are_named_once() {
    let d = tempfile::tempdir().unwrap();
    let nucleon = repo().join(NUCLEON);
    let tf = write_preset(d.path());
    let out = d.path().join("r.png");
    let gone_tf = d.path().join("gone.json");
    let gone_vol = d.path().join("gone_8x8x8_uint8.raw");
    let os_error = ["(os error", "No such file or directory"];
    // A missing TF file (render and convert read it through the formats module).
    let render_args = [
        "render",
        s(&nucleon),
        "--tf",
        s(&gone_tf),
        "--out",
        s(&out),
        "--size",
        "16",
    ];
    fails(&render_args, &[s(&gone_tf), "no such file"], &os_error);
    let xml = d.path().join("out.xml");
    fails(
        &["convert", s(&gone_tf), s(&xml)],
        &[s(&gone_tf), "no such file"],
        &os_error,
    );
    // A missing volume, for every command that reads one.
    fails(
        &["info", s(&gone_vol)],
        &[s(&gone_vol), "no such file"],
        &os_error,
    );
    let render_args = [
        "render",
        s(&gone_vol),
        "--tf",
        s(&tf),
        "--out",
        s(&out),
        "--size",
        "16",
    ];
    fails(&render_args, &[s(&gone_vol)], &os_error);
    assert!(!out.exists() && !xml.exists());
    // An output folder that does not exist: the folder is named, not a temporary file.
    let nowhere = d.path().join("no-such-folder").join("r.png");
    let render_args = [
        "render",
        s(&nucleon),
        "--tf",
        s(&tf),
        "--out",
        s(&nowhere),
        "--size",
        "16",
    ];
    fails(
        &render_args,
        &[s(&nowhere), "the folder does not exist"],
        &[".partial", "(os error"],
    );
}

#[test]
fn a_missing_raw_flag_is_named() {
    let d = tempfile::tempdir().unwrap();
    let rule = "NAME_XxYxZ_DTYPE";
    for name in ["volume.raw", "volume.bin"] {
        let p = d.path().join(name);
        std::fs::write(&p, [0u8; 64]).unwrap();
        fails(
            &["info", s(&p), "--dims", "4,4,4"],
            &[name, "the scalar type --dtype is missing"],
            &[rule, "--dims"],
        );
        fails(
            &["info", s(&p), "--dtype", "uint8"],
            &[name, "the dimensions --dims are missing"],
            &[rule, "--dtype"],
        );
    }
    // Neither flag on a .raw without the pattern: the naming rule is the answer.
    let p = d.path().join("volume.raw");
    fails(
        &["info", s(&p)],
        &["volume.raw", rule, "--dims", "--dtype"],
        &[],
    );
}

#[test]
fn render_refuses_other_image_formats_before_rendering() {
    let d = tempfile::tempdir().unwrap();
    let nucleon = repo().join(NUCLEON);
    let tf = write_preset(d.path());
    for name in ["r.jpg", "r.jpeg", "r.tif", "r"] {
        let out = d.path().join(name);
        let args = [
            "render",
            s(&nucleon),
            "--tf",
            s(&tf),
            "--out",
            s(&out),
            "--size",
            "16",
        ];
        fails(&args, &[s(&out), "--out", ".png"], &[]);
        assert!(!out.exists(), "{name} written");
    }
    // The check comes first: even a missing volume is not reached.
    let out = d.path().join("r.jpg");
    let missing = d.path().join("gone_8x8x8_uint8.raw");
    let args = ["render", s(&missing), "--tf", s(&tf), "--out", s(&out)];
    fails(&args, &["r.jpg", ".png"], &["gone_8x8x8_uint8.raw"]);
    // Any case of .png is fine.
    let out = d.path().join("r.PNG");
    let o = t2tf(&[
        "render",
        s(&nucleon),
        "--tf",
        s(&tf),
        "--out",
        s(&out),
        "--size",
        "16",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        &std::fs::read(&out).unwrap()[..8],
        b"\x89PNG\r\n\x1a\n",
        "PNG bytes"
    );
}

#[test]
fn sizes_from_flags_are_refused_before_anything_is_allocated() {
    // Sizes that would abort an allocation (or overflow a capacity) or take gigabytes: one
    // line names the flag and the limit, before the model loads.
    let vol = "../shared/data/volumes/neghip_64x64x64_uint8.raw";
    for (flag, value, limit) in [
        ("--steps", "1000000000000", "at most 1000000"),
        ("--steps", "18446744073709551615", "at most 1000000"),
        ("--views", "100000", "at most 64"),
        ("--control-points", "10000000", "between 2 and 4096"),
    ] {
        let start = std::time::Instant::now();
        fails(
            &["optimize", vol, "--prompt", "x", flag, value],
            &[flag, limit],
            &["panicked", "memory allocation"],
        );
        assert!(
            start.elapsed().as_secs() < 10,
            "{flag} {value} took {:?}",
            start.elapsed()
        );
    }
}

/// The whole stderr of a command that must fail with status `code`.
fn stderr_of(args: &[&str], code: i32) -> String {
    let o = t2tf(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(code), "{args:?}: {err}");
    err
}

#[test]
fn an_error_says_the_program_once() {
    // A context naming the command line (`t2tf optimize VOLUME: …`) would follow the line's
    // own `t2tf: error:`; the message goes on from the volume.
    let d = tempfile::tempdir().unwrap();
    let nucleon = repo().join(NUCLEON);
    let out = d.path().join("run");
    let args = [
        "optimize",
        s(&nucleon),
        "--prompt",
        "x",
        "--lock",
        "300,400",
        "--out",
        s(&out),
    ];
    assert_eq!(
        stderr_of(&args, 1),
        format!(
            "t2tf: error: {}: locked range 300,400 is outside the data range 0..249\n",
            nucleon.display()
        )
    );
}

#[test]
fn a_missing_file_is_said_alike_by_every_command() {
    let d = tempfile::tempdir().unwrap();
    let nucleon = repo().join(NUCLEON);
    let tf = write_preset(d.path());
    let out = d.path().join("r.png");
    let gone_vol = d.path().join("gone_8x8x8_uint8.raw");
    let gone_tf = d.path().join("gone.json");
    let gone_png = d.path().join("gone.png");
    let xml = d.path().join("out.xml");
    let said = |p: &Path| format!("t2tf: error: {}: no such file\n", p.display());
    let cases: [(Vec<&str>, &Path); 7] = [
        (vec!["info", s(&gone_vol)], &gone_vol),
        (
            vec![
                "optimize",
                s(&gone_vol),
                "--prompt",
                "a skull",
                "--out",
                s(&out),
            ],
            &gone_vol,
        ),
        (
            vec!["render", s(&gone_vol), "--tf", s(&tf), "--out", s(&out)],
            &gone_vol,
        ),
        (
            vec!["render", s(&nucleon), "--tf", s(&gone_tf), "--out", s(&out)],
            &gone_tf,
        ),
        (vec!["convert", s(&gone_tf), s(&xml)], &gone_tf),
        (vec!["convert", "--list", s(&gone_tf)], &gone_tf),
        (
            vec!["clip-score", s(&gone_png), "--caption", "a skull"],
            &gone_png,
        ),
    ];
    for (args, missing) in cases {
        assert_eq!(stderr_of(&args, 1), said(missing), "{args:?}");
    }
}

#[test]
fn negative_numbers_reach_the_checks_that_say_what_is_allowed() {
    let d = tempfile::tempdir().unwrap();
    let nucleon = repo().join(NUCLEON);
    let tf = write_preset(d.path());
    let out = d.path().join("r.png");
    let render = |flag: &str, value: &str| {
        let args = [
            "render",
            s(&nucleon),
            "--tf",
            s(&tf),
            "--out",
            s(&out),
            flag,
            value,
        ];
        stderr_of(&args, 1)
    };
    for (flag, value, said) in [
        ("--size", "-5", "--size -5 must be between 1 and 8192"),
        (
            "--seed",
            "-1",
            "--seed -1 must be a whole number from 0 to 18446744073709551615",
        ),
        ("--level", "-1", "--level -1 must be 0 or more"),
        ("--orbit", "-2", "--orbit -2: needs at least one view"),
        (
            "--distance",
            "-3",
            "--distance -3 must be a positive number",
        ),
        (
            "--step-size",
            "-0.5",
            "--step-size -0.5 must be a positive number",
        ),
        (
            "--unit-distance",
            "-2",
            "--unit-distance -2 must be a positive number",
        ),
    ] {
        assert_eq!(render(flag, value), format!("t2tf: error: {said}\n"));
    }
    assert!(!out.exists());
    // Flags whose values clap checks: the value's own message, never clap's advice to write
    // `-- -5` (which would not work for a flag's value).
    let clap_checked: [(Vec<&str>, &str); 6] = [
        (
            vec!["info", s(&nucleon), "--bins", "-3"],
            "invalid value '-3' for '--bins <BINS>': -3 is not in 1..=256",
        ),
        (
            vec!["info", s(&nucleon), "--spacing", "-1,1,1"],
            "invalid value '-1,1,1' for '--spacing <A,B,C>': spacing '-1,1,1' must be positive \
             finite numbers",
        ),
        (
            vec!["info", s(&nucleon), "--dims", "4,-4,4"],
            "invalid value '4,-4,4' for '--dims <X,Y,Z>': '-4' in '4,-4,4' is not whole numbers",
        ),
        (
            vec![
                "render",
                s(&nucleon),
                "--tf",
                s(&tf),
                "--out",
                s(&out),
                "--max-memory",
                "-5G",
            ],
            "invalid value '-5G' for '--max-memory <SIZE>': \"-5G\" is not a positive size like \
             512M or 16G",
        ),
        (
            vec!["convert", s(&tf), "o.json", "--max-preset-size", "-1M"],
            "invalid value '-1M' for '--max-preset-size <SIZE>': \"-1M\" is not a positive size \
             like 512M or 16G",
        ),
        (
            vec!["convert", s(&tf), "o.json", "--rescale", "-5,-10"],
            "invalid value '-5,-10' for '--rescale <MIN,MAX>': MIN (-5) must be below MAX (-10)",
        ),
    ];
    for (args, said) in clap_checked {
        let err = stderr_of(&args, 2);
        assert_eq!(
            err.lines().next(),
            Some(format!("error: {said}").as_str()),
            "{err}"
        );
        assert!(!err.contains("tip:") && !err.contains("'-- -"), "{err}");
    }
}
