//! `paraview/scripts/t2tf_apply_preset.py` from the command line in real ParaView: a `.raw` volume
//! (t2tf's own main input) opens through an ImageReader by its Open SciVis name or by
//! `--dims`/`--dtype`, and what cannot be shown (unreadable volume, invisible result) ends
//! with exit status 1 and one line naming the file, not an empty screenshot.
//!
//! Without pvpython these tests say so and pass, unless T2TF_REQUIRE_PARAVIEW=1.

use crate::paraview_util;

use std::path::{Path, PathBuf};
use std::process::Output;

use paraview_util::{neghip, projected_box, pvpython_output, repo, require_paraview, test_tf};
use t2tf::camera::ParaViewCamera;
use t2tf::formats::write_all;
use t2tf::image::Image;
use t2tf::volume::Volume;

const NEGHIP: &str = "../shared/data/volumes/neghip_64x64x64_uint8.raw";

fn helper() -> PathBuf {
    repo().join("paraview/scripts/t2tf_apply_preset.py")
}

/// t2tf's preset for neghip, written into `dir`.
fn preset(dir: &Path, v: &Volume) -> PathBuf {
    let view = ParaViewCamera::front(&v.geometry, 2.5);
    write_all(dir, "neghip", &test_tf(), v, &view, [0.0; 3], None)
        .unwrap()
        .json
}

fn run(args: &[&str]) -> Output {
    pvpython_output(&helper(), args)
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The camera the helper printed after its screenshot (`camera {json}`).
fn printed_camera(out: &Output) -> serde_json::Value {
    let stdout = text(&out.stdout);
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("camera "))
        .unwrap_or_else(|| panic!("no camera line in:\n{stdout}"));
    serde_json::from_str(line).unwrap()
}

fn vec3(v: &serde_json::Value) -> [f64; 3] {
    let a: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    [a[0], a[1], a[2]]
}

/// The printed camera's JSON as a `ParaViewCamera`.
fn camera_of(camera: &serde_json::Value) -> ParaViewCamera {
    ParaViewCamera {
        position: vec3(&camera["position"]),
        focal_point: vec3(&camera["focal_point"]),
        view_up: vec3(&camera["view_up"]),
        view_angle: camera["view_angle"].as_f64().unwrap(),
    }
}

/// Fraction of the pixels well inside `b` that differ from the background `bg`.
fn shown_inside(img: &Image, b: [f64; 4], bg: [f32; 3]) -> f64 {
    let (mut inside, mut differs) = (0usize, 0usize);
    for y in 0..img.height {
        for x in 0..img.width {
            let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
            if cx > b[0] + 2.0 && cx < b[2] - 2.0 && cy > b[1] + 2.0 && cy < b[3] - 2.0 {
                inside += 1;
                let p = img.pixel(x, y);
                differs += (0..3).any(|c| (p[c] - bg[c]).abs() > 1.5 / 255.0) as usize;
            }
        }
    }
    assert!(inside > 100, "box {b:?} covers only {inside} pixels");
    differs as f64 / inside as f64
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn helper_shows_a_raw_volume_by_its_name_and_by_flags() {
    require_paraview("helper_shows_a_raw_volume_by_its_name_and_by_flags");
    let v = neghip();
    let dir = tempfile::tempdir().unwrap();
    let json = preset(dir.path(), &v);
    let (w, h) = (200usize, 150usize);
    let (size_w, size_h) = (w.to_string(), h.to_string());
    let shot = |name: &str, volume: &Path, extra: &[&str]| {
        let path = dir.path().join(name);
        let mut args = vec![
            json.to_str().unwrap(),
            volume.to_str().unwrap(),
            "--screenshot",
            path.to_str().unwrap(),
            "--size",
            &size_w,
            &size_h,
        ];
        args.extend_from_slice(extra);
        let out = run(&args);
        assert!(
            out.status.success(),
            "{}\n{}",
            text(&out.stdout),
            text(&out.stderr)
        );
        (Image::load_png(&path).unwrap(), printed_camera(&out))
    };

    let (img, camera) = shot("named.png", &repo().join(NEGHIP), &[]);
    assert_eq!((img.width, img.height), (w, h));
    let b = projected_box(&v, &camera_of(&camera), w, h);
    // The top-right corner is background (the orientation axes sit bottom left).
    let bg = img.pixel(w - 1, 0);
    let frac = shown_inside(&img, b, bg);
    eprintln!("projected box {b:?}: {frac:.2} of its pixels show the volume");
    assert!(
        frac > 0.3,
        "only {frac} of the projected box shows the volume"
    );

    // The same bytes under a name without the pattern, described by flags: same picture.
    let bin = dir.path().join("neghip.bin");
    std::fs::copy(repo().join(NEGHIP), &bin).unwrap();
    let flags = ["--dims", "64,64,64", "--dtype", "uint8"];
    let (by_flags, _) = shot("flags.png", &bin, &flags);
    assert_eq!(
        by_flags.data, img.data,
        "flags and name read the same volume"
    );
}

/// Run the helper expecting failure: exit status 1, one `t2tf_apply_preset: error:` line on
/// stderr naming `file` and containing `needle`, no traceback, no screenshot written.
fn fails(args: &[&str], file: &str, needle: &str, shot: &Path) {
    let out = run(args);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert_eq!(out.status.code(), Some(1), "{args:?}:\n{stdout}\n{stderr}");
    let ours: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("t2tf_apply_preset: error:"))
        .collect();
    assert_eq!(ours.len(), 1, "{args:?}: not one error line:\n{stderr}");
    assert!(ours[0].contains(file), "does not name {file}: {}", ours[0]);
    assert!(ours[0].contains(needle), "lacks '{needle}': {}", ours[0]);
    assert!(!stderr.contains("Traceback"), "{stderr}");
    assert!(!shot.exists(), "{args:?} wrote {}", shot.display());
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn helper_refuses_unreadable_volumes_and_empty_screenshots() {
    require_paraview("helper_refuses_unreadable_volumes_and_empty_screenshots");
    let v = neghip();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let json = preset(d, &v);
    let shot = d.join("shot.png");
    let args = |volume: &Path, extra: &[&'static str]| -> Vec<String> {
        let mut a = vec![
            json.display().to_string(),
            volume.display().to_string(),
            "--screenshot".to_string(),
            shot.display().to_string(),
            "--size".to_string(),
            "64".to_string(),
            "64".to_string(),
        ];
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let check = |volume: &Path, extra: &[&'static str], needle: &str| {
        let a = args(volume, extra);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let name = volume.file_name().unwrap().to_str().unwrap();
        fails(&a, name, needle, &shot);
    };
    let neghip_bytes = std::fs::read(repo().join(NEGHIP)).unwrap();

    // A .raw whose name does not give dims and type, and no flags.
    let unnamed = d.join("volume.raw");
    std::fs::write(&unnamed, &neghip_bytes).unwrap();
    check(&unnamed, &[], "name does not follow NAME_XxYxZ_DTYPE.raw");
    // --dims alone: the missing flag is named.
    check(&unnamed, &["--dims", "64,64,64"], "--dtype TYPE is missing");
    // A missing file.
    check(&d.join("missing_8x8x8_uint8.raw"), &[], "no such file");
    // A raw file of the wrong size for its name.
    let short = d.join("short_64x64x64_uint8.raw");
    std::fs::write(&short, &neghip_bytes[..1000]).unwrap();
    check(
        &short,
        &[],
        "file holds 1000 bytes but 64x64x64 uint8 needs 262144",
    );
    // A reader that produces no points: a .vti cut off inside its header.
    let fixture = repo().join("tests/fixtures/volumes/ascii_float32.vti");
    let cut = d.join("cut.vti");
    std::fs::write(&cut, &std::fs::read(fixture).unwrap()[..250]).unwrap();
    check(&cut, &[], "read 0 point(s)");
    // A readable volume with a preset that shows nothing: no empty screenshot.
    let zero = d.join("zero.json");
    std::fs::write(
        &zero,
        r#"[{"Name":"zero","RGBPoints":[0,1,1,1, 255,1,1,1],"Points":[0,0,0.5,0, 255,0,0.5,0]}]"#,
    )
    .unwrap();
    let mut a = args(&repo().join(NEGHIP), &[]);
    a[0] = zero.display().to_string();
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    fails(&a, "shot.png", "only the background", &shot);
}
