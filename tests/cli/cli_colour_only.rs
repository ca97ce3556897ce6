//! A ParaView colour map without opacity ("Cool to Warm" of ParaView's library) renders:
//! `t2tf render` draws it with the densities `t2tf optimize --init` starts it from (the paper's
//! initial ones under the preset's colours) and says so in one line.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use t2tf::camera::UpAxis;
use t2tf::formats::{read_tf, write_tf, ExportTf, DEFAULT_MAX_PRESET_SIZE};
use t2tf::image::{psnr, Image};
use t2tf::memory::Budget;
use t2tf::optimize::Settings;
use t2tf::pipeline::InitTf;

const PRESET: &str = "Cool to Warm";
const NOTE: &str = "t2tf: note: preset \"Cool to Warm\" has no opacity: drawn with the paper's \
                    initial densities, as `t2tf optimize --init` starts from it";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn library() -> PathBuf {
    repo().join("tests/fixtures/paraview/paraview_library.json")
}

fn neghip() -> PathBuf {
    repo().join("../shared/data/volumes/neghip_64x64x64_uint8.raw")
}

fn ok(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    err
}

/// `t2tf render neghip --tf TF [--preset NAME] --out OUT --size 96`, its stderr.
fn render(tf: &Path, preset: Option<&str>, out: &Path) -> String {
    let mut c = Command::new(env!("CARGO_BIN_EXE_t2tf"));
    c.arg("render")
        .arg(neghip())
        .arg("--tf")
        .arg(tf)
        .arg("--out")
        .arg(out)
        .args(["--size", "96"]);
    if let Some(p) = preset {
        c.args(["--preset", p]);
    }
    ok(&c.output().expect("run t2tf"))
}

/// The control points a colour-only start of "Cool to Warm" has on neghip with the default
/// settings, its start view rendered at `size` pixels.
fn start_points(size: usize) -> (t2tf::tf::ControlPoints, t2tf::volume::Volume) {
    let volume = t2tf::volume::load(&neghip(), &Default::default()).unwrap();
    let init = InitTf::read(&library(), Some(PRESET), DEFAULT_MAX_PRESET_SIZE).unwrap();
    assert!(init.colours_only());
    let settings = Settings::default().validate().unwrap();
    let cp = init
        .colours_only_points(
            &volume,
            &settings,
            size,
            UpAxis::default(),
            Budget::system(),
        )
        .unwrap();
    (cp, volume)
}

#[test]
fn a_colour_only_preset_renders_with_the_start_densities() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("ctw.png");
    let err = render(&library(), Some(PRESET), &out);
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 2, "{err}");
    assert_eq!(lines[0], NOTE);
    let img = Image::load_png(&out).unwrap();

    // Not empty, not black: the volume covers much of the frame in the map's blues and reds
    // (the background is gray 0.3).
    let pixels: Vec<[f32; 3]> = (0..img.height)
        .flat_map(|y| (0..img.width).map(move |x| (x, y)))
        .map(|(x, y)| img.pixel(x, y))
        .collect();
    let n = pixels.len() as f64;
    let shown = pixels
        .iter()
        .filter(|p| p.iter().any(|c| (c - 0.3).abs() > 2.0 / 255.0))
        .count() as f64;
    assert!(
        shown / n > 0.3,
        "only {shown} of {n} pixels show the volume"
    );
    let blue = pixels.iter().filter(|p| p[2] - p[0] > 0.2).count();
    let red = pixels.iter().filter(|p| p[0] - p[2] > 0.2).count();
    assert!(blue > 100 && red > 0, "blue {blue}, red {red} pixels");

    // The same densities, written as a TF with opacity (as `optimize` exports its start),
    // give the same picture.
    let (cp, volume) = start_points(224);
    let tf = ExportTf::from_control_points("start", &cp, &volume, None);
    assert!(!tf.opacity_points.is_empty());
    let file = d.path().join("start.json");
    write_tf(&file, &tf).unwrap();
    let same = d.path().join("same.png");
    let err = render(&file, None, &same);
    assert!(!err.contains("no opacity"), "{err}");
    let db = psnr(&img, &Image::load_png(&same).unwrap());
    assert!(db >= 40.0, "{db} dB from the same densities");

    // Other densities give another picture: the comparison can fail.
    let mut thin = cp.clone();
    thin.sigma.iter_mut().for_each(|s| *s *= 0.2);
    let other = ExportTf::from_control_points("thin", &thin, &volume, None);
    let file = d.path().join("thin.json");
    write_tf(&file, &other).unwrap();
    let thin_png = d.path().join("thin.png");
    render(&file, None, &thin_png);
    let db = psnr(&img, &Image::load_png(&thin_png).unwrap());
    assert!(db < 30.0, "{db} dB from a fifth of the densities");
}

/// The densities are those `optimize --init` starts from: a 0-step run with the test model
/// (32-pixel images) writes the TF of the same start at that size.
#[test]
fn optimize_init_starts_from_the_same_densities() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("run");
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .env("XDG_CACHE_HOME", d.path().join("cache"))
        .arg("optimize")
        .arg(neghip())
        .args(["--prompt", "x", "--steps", "0", "--preset", PRESET])
        .arg("--init")
        .arg(library())
        .arg("--model")
        .arg(repo().join("tests/fixtures/clip/quick_gelu"))
        .arg("--tokenizer")
        .arg(repo().join("../shared/data/clip/tokenizer.json"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    ok(&o);
    let written = read_tf(&out.join("run.json")).unwrap();
    let (cp, volume) = start_points(32);
    let ours = ExportTf::from_control_points("start", &cp, &volume, None);
    assert_eq!(written.unit_distance, ours.unit_distance);
    let (xs, a) = written.sample(1024);
    let (_, b) = ours.sample(1024);
    for ((x, p), q) in xs.iter().zip(&a).zip(&b) {
        for c in 0..4 {
            assert!(
                (p[c] - q[c]).abs() < 1e-6,
                "at {x}: {p:?} written, {q:?} ours"
            );
        }
    }
}
