//! Each command's help: an example, and words true to the code.

use std::process::Command;

fn help(args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .arg("--help")
        .output()
        .unwrap();
    assert!(o.status.success(), "{args:?}");
    String::from_utf8(o.stdout).unwrap()
}

#[test]
fn every_command_shows_an_example() {
    for args in [
        &["info"][..],
        &["convert"],
        &["render"],
        &["clip-score"],
        &["optimize"],
        &["model"],
        &["model", "fetch"],
        &["model", "list"],
        &["cache"],
        &["cache", "list"],
        &["cache", "clear"],
    ] {
        let h = help(args);
        let example = h
            .split_once("Example")
            .map(|(_, rest)| rest)
            .unwrap_or_else(|| panic!("{args:?} has no example:\n{h}"));
        assert!(
            example.contains(&format!("t2tf {}", args.join(" "))),
            "{args:?}: the example does not run the command:\n{h}"
        );
    }
}

#[test]
fn convert_output_is_required_unless_listing() {
    let h = help(&["convert"]);
    let usage = h.lines().find(|l| l.starts_with("Usage:")).unwrap();
    assert!(usage.contains("<INPUT> <OUTPUT>"), "{h}");
    let output = h
        .lines()
        .find(|l| l.contains("OUTPUT]") || l.contains("OUTPUT>  "))
        .unwrap();
    assert!(output.contains("required unless --list"), "{h}");
    assert!(h.contains("--list <INPUT>"), "{h}");
    // And clap holds it: OUTPUT missing is an error, except with --list.
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(["convert", "in.json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("<OUTPUT>"));
}

#[test]
fn precision_help_points_to_the_measurements() {
    let h = help(&["optimize"]);
    let p = h.split("--precision").nth(1).unwrap();
    let p = p.split("\n  -").next().unwrap();
    assert!(!p.contains("not measured"), "{p}");
    for needle in ["reproducible", "BENCHMARKS.md", "0.58×"] {
        assert!(p.contains(needle), "--precision help lacks {needle}: {p}");
    }
}
