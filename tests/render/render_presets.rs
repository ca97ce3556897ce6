//! `t2tf render` with ParaView presets in other colour spaces and files holding several.

use std::path::Path;
use std::process::Command;

use t2tf::image::Image;

const NEGHIP: &str = "../shared/data/volumes/neghip_64x64x64_uint8.raw";

fn render(tf: &Path, out: &Path, extra: &[&str]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(["render", NEGHIP, "--size", "48", "--tf"])
        .arg(tf)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn preset_picks_one_of_several_and_a_missing_choice_lists_them() {
    let dir = tempfile::tempdir().unwrap();
    let fixtures = Path::new("tests/fixtures/paraview");
    // One file holding ParaView's HSV and Lab presets, as ParaView writes several.
    let mut all = Vec::new();
    for space in ["HSV", "Lab"] {
        let text =
            std::fs::read_to_string(fixtures.join(format!("colorspace_{space}.json"))).unwrap();
        let v: Vec<serde_json::Value> = serde_json::from_str(&text).unwrap();
        all.extend(v);
    }
    let both = dir.path().join("both.json");
    std::fs::write(&both, serde_json::to_string(&all).unwrap()).unwrap();

    let out = dir.path().join("view.png");
    let (ok, err) = render(&both, &out, &[]);
    assert!(
        !ok && err.contains("--preset") && err.contains("colorspace_Lab"),
        "{err}"
    );
    assert!(!out.exists());

    let (ok, err) = render(&both, &out, &["--preset", "colorspace_Lab"]);
    assert!(ok, "{err}");
    let lab_from_both = Image::load_png(&out).unwrap();
    // The same as rendering the single-preset file.
    let single = dir.path().join("single.png");
    let (ok, err) = render(&fixtures.join("colorspace_Lab.json"), &single, &[]);
    assert!(ok, "{err}");
    assert_eq!(Image::load_png(&single).unwrap(), lab_from_both);
    // And not the HSV one: the choice matters.
    let (ok, err) = render(&both, &out, &["--preset", "colorspace_HSV"]);
    assert!(ok, "{err}");
    assert_ne!(Image::load_png(&out).unwrap(), lab_from_both);

    let (ok, err) = render(&both, &out, &["--preset", "no such preset"]);
    assert!(!ok && err.contains("no such preset"), "{err}");
}
