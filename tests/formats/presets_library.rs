//! ParaView's whole preset library as one file (exported by pvpython, see
//! tests/fixtures/paraview/make_colorspace_presets.py): `--list` shows every preset, each
//! continuous one converts to .xml and .ct by name, categorical ones are refused clearly.

use std::process::Command;

fn t2tf(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn whole_library_converts_preset_by_preset() {
    let lib = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/paraview/paraview_library.json"
    );
    let out = t2tf(&["convert", "--list", lib]);
    assert!(out.status.success());
    let listing = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = listing.lines().collect();
    assert!(lines.len() >= 50, "{}", lines.len());
    let dir = tempfile::tempdir().unwrap();
    let (mut converted, mut refused) = (0, 0);
    for line in &lines {
        let name = line.split('\t').next().unwrap();
        for ext in ["xml", "ct", "json"] {
            let o = dir.path().join(format!("p.{ext}"));
            let r = t2tf(&["convert", lib, o.to_str().unwrap(), "--preset", name]);
            let err = String::from_utf8_lossy(&r.stderr);
            let continuous_twin = lines
                .iter()
                .any(|l| l.split('\t').next() == Some(name) && !l.contains("categorical"));
            if line.contains("categorical") && !continuous_twin {
                assert!(
                    !r.status.success() && err.contains("categorical"),
                    "{name}: {err}"
                );
                refused += 1;
            } else {
                assert!(r.status.success(), "{name} → .{ext}: {err}");
                converted += 1;
            }
        }
    }
    eprintln!("{converted} conversions, {refused} categorical refusals");
    let r = t2tf(&["convert", lib, dir.path().join("x.ct").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("--preset NAME") && err.contains("Cool to Warm"),
        "{err}"
    );
}
