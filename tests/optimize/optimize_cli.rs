//! `t2tf optimize`: the flags and their defaults as `--help` prints them, and argument errors
//! from the binary. The run itself is the library's `t2tf::pipeline` (optimize_pipeline.rs);
//! parsing and validating the flags is unit-tested next to them (src/commands/optimize.rs).

use std::process::Command;

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
