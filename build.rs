//! Which outside tools the tests can use here, as cfgs, so a test that cannot run is counted as
//! ignored (`#[cfg_attr(not(t2tf_pvpython), ignore = "…")]`) instead of passing without
//! running:
//!
//! - `t2tf_pvpython`: `pvpython` and `xvfb-run` on PATH (ParaView's tests).
//! - `t2tf_pvserver`: also `mpiexec` and `pvserver` (the remote-server test).
//! - `t2tf_python`: `python3` runs (syntax checks and the VisIt stand-in).
//! - `t2tf_python_hub`: `$T2TF_PYTHON` (else `python3`) imports `huggingface_hub`.
//!
//! Where a tool is required (`T2TF_REQUIRE_PARAVIEW`, `T2TF_REQUIRE_PYTHON`,
//! `T2TF_REQUIRE_PYTHON_HUB`, set by CI), its cfg is set whether or not it was found, so its
//! tests run and fail loudly rather than be ignored; the build says what is missing.
//!
//! A cross build (tests run under wine or qemu-user) sets none: the tools found here are this
//! machine's, not the target's, so their tests are ignored there.

use std::path::Path;
use std::process::{Command, Stdio};

fn main() {
    for cfg in [
        "t2tf_pvpython",
        "t2tf_pvserver",
        "t2tf_python",
        "t2tf_python_hub",
    ] {
        println!("cargo:rustc-check-cfg=cfg({cfg})");
    }
    for var in [
        "PATH",
        "T2TF_PYTHON",
        "T2TF_REQUIRE_PARAVIEW",
        "T2TF_REQUIRE_PYTHON",
        "T2TF_REQUIRE_PYTHON_HUB",
    ] {
        println!("cargo:rerun-if-env-changed={var}");
    }
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var("TARGET").ok() != std::env::var("HOST").ok() {
        return;
    }

    let paraview = on_path("pvpython") && on_path("xvfb-run");
    let pvserver = paraview && on_path("mpiexec") && on_path("pvserver");
    let python = runs("python3", &["-c", "pass"]);
    let python_exe = std::env::var("T2TF_PYTHON").unwrap_or_else(|_| "python3".into());
    let python_hub = runs(&python_exe, &["-c", "import huggingface_hub"]);

    let need_paraview = required("T2TF_REQUIRE_PARAVIEW");
    let need_python = required("T2TF_REQUIRE_PYTHON");
    let need_hub = required("T2TF_REQUIRE_PYTHON_HUB");
    for (found, needed, var, what) in [
        (
            pvserver,
            need_paraview,
            "T2TF_REQUIRE_PARAVIEW",
            "pvpython, xvfb-run, mpiexec and pvserver",
        ),
        (python, need_python, "T2TF_REQUIRE_PYTHON", "python3"),
        (
            python_hub,
            need_hub,
            "T2TF_REQUIRE_PYTHON_HUB",
            "a python3 (or $T2TF_PYTHON) that imports huggingface_hub",
        ),
    ] {
        if needed && !found {
            println!(
                "cargo:warning={var} is set but not all of {what} were found: those tests will run and fail"
            );
        }
    }
    let set = |cfg: &str, on: bool| {
        if on {
            println!("cargo:rustc-cfg={cfg}");
        }
    };
    set("t2tf_pvpython", paraview || need_paraview);
    set("t2tf_pvserver", pvserver || need_paraview);
    set("t2tf_python", python || need_python);
    set("t2tf_python_hub", python_hub || need_hub);
}

/// Set to anything but empty or "0".
fn required(var: &str) -> bool {
    std::env::var(var).is_ok_and(|v| !v.is_empty() && v != "0")
}

/// Whether an executable file `exe` is in a folder of PATH.
fn on_path(exe: &str) -> bool {
    use std::os::unix::fs::PermissionsExt;
    let Some(path) = std::env::var_os("PATH") else {
        return false;
    };
    std::env::split_paths(&path).any(|dir| {
        let p = Path::new(&dir).join(exe);
        std::fs::metadata(&p).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
    })
}

/// Whether `exe args` runs and exits 0.
fn runs(exe: &str, args: &[&str]) -> bool {
    Command::new(exe)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}
