//! `t2tf render` against ParaView 5.11's own screenshots (BENCHMARKS.md, "Render parity with
//! ParaView"): three shared volumes × three views × four presets from ParaView's library in
//! different colour spaces (Cool to Warm: Diverging; Blue to Red Rainbow: HSV; CIELab Blue to Red:
//! Lab; Black-Body Radiation: RGB), each spanning the data range; and a wide-range 16-bit CT where
//! the presets span a window 5 % of the range, with and without `--paraview-lut`.
//!
//! ParaView's side is one pvpython process (`tests/fixtures/paraview_parity/parity_shots.py`):
//! it applies each library preset, rescales it, sets the opacity and unit distance, writes the
//! transfer function with its own `ExportTransferFunction` (the file `t2tf render` then reads, in
//! the preset's colour space), and saves a screenshot per view. The cameras are t2tf's
//! (`Camera::orbit(..).paraview()`, 45° view angle); background and unit distance are the same
//! on both sides. Numbers: BENCHMARKS.md "Render parity with ParaView".
//!
//! Without pvpython this test says so and passes, unless T2TF_REQUIRE_PARAVIEW=1.
//! `T2TF_PARITY_KEEP=DIR` keeps the presets, screenshots and renders in DIR.

use crate::paraview_util;

use std::path::{Path, PathBuf};
use std::process::Command;

use paraview_util::{pvpython, repo, require_paraview};
use serde_json::{json, Value};
use t2tf::camera::{Camera, Orbit, UpAxis};
use t2tf::image::{psnr, Image};
use t2tf::volume::{load, ReadOptions};

/// Side of the screenshots and renders.
const SIZE: usize = 192;

/// The bar for every case. Measured (ParaView 5.11, Mesa llvmpipe): 48.5–60.7 dB where
/// the preset spans the data range (the uint8 neghip lowest: ParaView filters 8-bit textures
/// coarsely, tests/paraview/paraview_match.rs), 46.1–48.4 dB with --paraview-lut in the 5 % window.
const BAR: f64 = 40.0;

/// ParaView library presets, one per colour space: (name, the colour space ParaView keeps it
/// in, short id). "Blue to Red Rainbow" checks an HSV sector edge, where VTK's HSV→RGB formula
/// gives 1 + 2⁻⁵² (clamped in tf::color_convert::hsv_to_rgb).
const PRESETS: [(&str, &str, &str); 4] = [
    ("Cool to Warm", "Diverging", "cool"),
    ("Blue to Red Rainbow", "HSV", "rainbow"),
    ("CIELab Blue to Red", "Lab", "labbluered"),
    ("Black-Body Radiation", "RGB", "blackbody"),
];

/// Views as `t2tf render` flags: yaw and pitch in degrees, distance in bounding radii (z up).
const VIEWS: [(f64, f64, f64); 3] = [(30.0, 10.0, 2.5), (120.0, -20.0, 2.5), (235.0, 35.0, 3.0)];

/// A raw volume the test shows on both sides.
struct Vol {
    id: &'static str,
    path: PathBuf,
    dims: [usize; 3],
    /// uint16 (else uint8), little-endian.
    u16: bool,
    /// ScalarOpacityUnitDistance on both sides (world units).
    unit_distance: f64,
    background: f64,
}

impl Vol {
    fn values(&self) -> Vec<f64> {
        let bytes =
            std::fs::read(&self.path).unwrap_or_else(|e| panic!("{}: {e}", self.path.display()));
        if self.u16 {
            bytes
                .chunks_exact(2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]) as f64)
                .collect()
        } else {
            bytes.iter().map(|&b| b as f64).collect()
        }
    }

    fn job(&self) -> Value {
        json!({
            "path": self.path.to_str().expect("UTF-8 path"),
            "type": if self.u16 { "unsigned short" } else { "unsigned char" },
            "dims": self.dims,
            "spacing": [1.0, 1.0, 1.0],
            "origin": [0.0, 0.0, 0.0],
        })
    }
}

fn shared(name: &str) -> PathBuf {
    repo().join("../shared/data/volumes").join(name)
}

/// The `p`-quantile of the values above the minimum (the background of a CT).
fn percentile(values: &[f64], p: f64) -> f64 {
    let min = values.iter().copied().fold(f64::INFINITY, f64::min);
    let mut v: Vec<f64> = values.iter().copied().filter(|&x| x > min).collect();
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p) as usize]
}

/// headsq scaled into 0..16383 with eight voxels at 65535: the tissue fills the first quarter
/// of the range, as in a CT with metal or padding outliers (BENCHMARKS.md "Render defaults").
fn write_wide_ct(dir: &Path) -> Vol {
    let headsq = shared("headsq_64x64x93_uint16.raw");
    let raw = std::fs::read(&headsq).unwrap_or_else(|e| panic!("{}: {e}", headsq.display()));
    let vals: Vec<f64> = raw
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]) as f64)
        .collect();
    let max = vals.iter().copied().fold(0.0, f64::max);
    let mut wide: Vec<u16> = vals
        .iter()
        .map(|v| (v * 16383.0 / max).round() as u16)
        .collect();
    let n = wide.len();
    for k in 0..8 {
        wide[(k * 7919 + 13) % n] = 65535;
    }
    let path = dir.join("headsqwide_64x64x93_uint16.raw");
    let bytes: Vec<u8> = wide.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&path, bytes).unwrap();
    Vol {
        id: "headsq-wide",
        path,
        dims: [64, 64, 93],
        u16: true,
        unit_distance: 1.0,
        background: 0.3,
    }
}

/// One volume, preset and data window, shown from every view.
struct Case {
    name: String,
    vol: usize,
    preset: usize,
    /// The data range the preset is rescaled to.
    window: [f64; 2],
    /// ParaView opacity points [x, o, midpoint, sharpness]…
    opacity: Vec<f64>,
    /// Whether the window is a small part of a wide range.
    narrow: bool,
}

/// `t2tf render` of `vol` with the preset `tf` from `view` (yaw°, pitch°, distance) into `out`.
fn t2tf_render(vol: &Vol, tf: &Path, view: (f64, f64, f64), out: &Path, extra: &[&str]) -> Image {
    let o = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .arg("render")
        .arg(&vol.path)
        .arg("--tf")
        .arg(tf)
        .arg("--out")
        .arg(out)
        .args(["--size", &SIZE.to_string()])
        .args(["--yaw", &view.0.to_string()])
        .args(["--pitch", &view.1.to_string()])
        .args(["--distance", &view.2.to_string()])
        .args(["--background", &format!("gray:{}", vol.background)])
        .args(["--unit-distance", &vol.unit_distance.to_string()])
        .args(extra)
        .output()
        .expect("run t2tf");
    assert!(
        o.status.success(),
        "t2tf render {}: {}",
        tf.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    Image::load_png(out).unwrap()
}

/// Share of pixels that differ from the background by more than 0.05 in some channel.
fn lit(img: &Image, bg: f64) -> f64 {
    let n = img.width * img.height;
    (0..n)
        .filter(|&i| (0..3).any(|c| (img.data[3 * i + c] as f64 - bg).abs() > 0.05))
        .count() as f64
        / n as f64
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn renders_match_paraview_screenshots() {
    require_paraview("renders_match_paraview_screenshots");
    let keep = std::env::var_os("T2TF_PARITY_KEEP").map(PathBuf::from);
    let tmp = tempfile::tempdir().unwrap();
    let dir = keep.unwrap_or_else(|| tmp.path().to_path_buf());
    std::fs::create_dir_all(&dir).unwrap();

    let vols = [
        Vol {
            id: "neghip",
            path: shared("neghip_64x64x64_uint8.raw"),
            dims: [64, 64, 64],
            u16: false,
            unit_distance: 1.0,
            background: 0.3,
        },
        Vol {
            id: "headsq",
            path: shared("headsq_64x64x93_uint16.raw"),
            dims: [64, 64, 93],
            u16: true,
            unit_distance: 1.0,
            background: 0.1,
        },
        Vol {
            id: "walnut",
            path: shared("walnut_128x96x114_uint16.raw"),
            dims: [128, 96, 114],
            u16: true,
            unit_distance: 2.0,
            background: 0.6,
        },
        write_wide_ct(&dir),
    ];

    let mut cases = Vec::new();
    for (vi, vol) in vols.iter().enumerate() {
        let values = vol.values();
        let min = values.iter().copied().fold(f64::INFINITY, f64::min);
        let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let (a, b) = (percentile(&values, 0.5), percentile(&values, 0.995));
        for (pi, preset) in PRESETS.iter().enumerate() {
            if vol.id == "headsq-wide" {
                // A window 5 % of the range wide over the tissue, opacity a tent inside it.
                // Narrower windows (1 %, 2 %: 25–35 dB with or without --paraview-lut) are
                // dominated by ParaView's own ray sampling, a step of 0.357 voxel here (VTK's
                // SpacingAdjustedSampleDistance) with per-pixel noise that no deterministic
                // render reproduces; measured and argued in BENCHMARKS.md "Render parity with
                // ParaView".
                let w = 0.05 * (max - min);
                let lo = a + 0.2 * (b - a);
                let (hi, mid) = (lo + w, lo + w / 2.0);
                cases.push(Case {
                    name: format!("{}_{}", vol.id, preset.2),
                    vol: vi,
                    preset: pi,
                    window: [lo, hi],
                    opacity: vec![
                        min, 0.0, 0.5, 0.0, lo, 0.0, 0.5, 0.0, mid, 0.8, 0.5, 0.0, hi, 0.0, 0.5,
                        0.0, max, 0.0, 0.5, 0.0,
                    ],
                    narrow: true,
                });
            } else {
                // The preset over the data range, opacity a ramp from the median to the 99.5th
                // percentile of the non-background values.
                cases.push(Case {
                    name: format!("{}_{}", vol.id, preset.2),
                    vol: vi,
                    preset: pi,
                    window: [min, max],
                    opacity: vec![
                        min, 0.0, 0.5, 0.0, a, 0.0, 0.5, 0.0, b, 0.5, 0.5, 0.0, max, 0.5, 0.5, 0.0,
                    ],
                    narrow: false,
                });
            }
        }
    }

    // ParaView's side, one process.
    let mut job_cases = Vec::new();
    for case in &cases {
        let vol = &vols[case.vol];
        let geometry = load(&vol.path, &ReadOptions::default()).unwrap().geometry;
        let views: Vec<Value> = VIEWS
            .iter()
            .enumerate()
            .map(|(k, &(yaw, pitch, distance))| {
                let cam = Camera::orbit(
                    &geometry,
                    Orbit {
                        yaw: yaw.to_radians(),
                        pitch: pitch.to_radians(),
                        distance,
                        up: UpAxis::Z,
                    },
                )
                .unwrap()
                .paraview();
                json!({
                    "position": cam.position,
                    "focal_point": cam.focal_point,
                    "view_up": cam.view_up,
                    "view_angle": cam.view_angle,
                    "out": dir.join(format!("{}_v{k}_paraview.png", case.name)),
                })
            })
            .collect();
        job_cases.push(json!({
            "name": case.name,
            "volume": vol.id,
            "preset": PRESETS[case.preset].0,
            "range": case.window,
            "opacity": case.opacity,
            "unit_distance": vol.unit_distance,
            "background": [vol.background, vol.background, vol.background],
            "export": dir.join(format!("{}.json", case.name)),
            "views": views,
        }));
    }
    let job = json!({
        "size": [SIZE, SIZE],
        "report": dir.join("report.json"),
        "volumes": vols.iter().map(|v| (v.id.to_string(), v.job())).collect::<serde_json::Map<_, _>>(),
        "cases": job_cases,
    });
    let job_path = dir.join("job.json");
    std::fs::write(&job_path, serde_json::to_string_pretty(&job).unwrap()).unwrap();
    let t0 = std::time::Instant::now();
    pvpython(
        &repo().join("tests/fixtures/paraview_parity/parity_shots.py"),
        &[job_path.to_str().unwrap()],
    );
    eprintln!("pvpython: {:.1} s", t0.elapsed().as_secs_f64());
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();

    // Our side: `t2tf render` as a user runs it, exact (the default) and with --paraview-lut.
    let t0 = std::time::Instant::now();
    // Per case and view: (ParaView's screenshot, ours exact, ours --paraview-lut).
    let mut images: Vec<Vec<(Image, Image, Image)>> = Vec::new();
    for case in &cases {
        let vol = &vols[case.vol];
        let tf = dir.join(format!("{}.json", case.name));
        // The file is ParaView's export, in the preset's own colour space.
        let exported: Value = serde_json::from_str(&std::fs::read_to_string(&tf).unwrap()).unwrap();
        assert_eq!(
            exported[0]["ColorSpace"], PRESETS[case.preset].1,
            "{}: ParaView applied {}",
            case.name, report[&case.name]
        );
        let mut per_view = Vec::new();
        for (k, &view) in VIEWS.iter().enumerate() {
            let out = |tag: &str| dir.join(format!("{}_v{k}_{tag}.png", case.name));
            let shot = Image::load_png(&out("paraview")).unwrap();
            assert_eq!((shot.width, shot.height), (SIZE, SIZE));
            let exact = t2tf_render(vol, &tf, view, &out("t2tf"), &[]);
            let pvlut = t2tf_render(vol, &tf, view, &out("t2tf_pvlut"), &["--paraview-lut"]);
            per_view.push((shot, exact, pvlut));
        }
        images.push(per_view);
    }
    eprintln!("t2tf renders: {:.1} s", t0.elapsed().as_secs_f64());

    let mut failures = Vec::new();
    let mut gains = Vec::new();
    for (case, per_view) in cases.iter().zip(&images) {
        let vol = &vols[case.vol];
        for (k, (shot, exact, pvlut)) in per_view.iter().enumerate() {
            let (p_exact, p_lut) = (psnr(shot, exact), psnr(shot, pvlut));
            let covered = lit(shot, vol.background);
            eprintln!(
                "{:28} view {k}: exact {p_exact:5.1} dB, --paraview-lut {p_lut:5.1} dB \
                 ({:+.1} dB), {:.0} % of the pixels show the volume",
                case.name,
                p_lut - p_exact,
                100.0 * covered
            );
            // A picture that is mostly background would pass on the background alone.
            assert!(
                covered > 0.1,
                "{} view {k}: {covered:.2} covered",
                case.name
            );
            if case.narrow {
                gains.push(p_lut - p_exact);
                if p_lut < BAR {
                    failures.push(format!(
                        "{} view {k}: --paraview-lut {p_lut:.1} dB",
                        case.name
                    ));
                }
            } else if p_exact < BAR || p_lut < BAR {
                failures.push(format!(
                    "{} view {k}: exact {p_exact:.1} dB, --paraview-lut {p_lut:.1} dB",
                    case.name
                ));
            }
        }
    }
    let mean_gain = gains.iter().sum::<f64>() / gains.len() as f64;
    eprintln!(
        "narrow window (5 % of a wide range): without --paraview-lut the PSNR is lower by \
         {:.1} to {:.1} dB (mean {mean_gain:.1} dB)",
        gains.iter().copied().fold(f64::INFINITY, f64::min),
        gains.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    );

    // Negative control: the same view with another preset of the four (ParaView's screenshot
    // of preset i against our render of preset i + 1) must be far under the bar, so the bar
    // tells presets (and their colour spaces) apart.
    let mut worst_wrong = f64::NEG_INFINITY;
    for (a, case) in cases.iter().enumerate() {
        let Some(b) = cases
            .iter()
            .position(|c| c.vol == case.vol && c.preset == (case.preset + 1) % PRESETS.len())
        else {
            continue;
        };
        for ((shot, _, _), (_, wrong, _)) in images[a].iter().zip(&images[b]) {
            worst_wrong = worst_wrong.max(psnr(shot, wrong));
        }
    }
    eprintln!("another preset of the four: at most {worst_wrong:.1} dB");
    assert!(
        worst_wrong < BAR - 10.0,
        "a render with the wrong preset reaches {worst_wrong:.1} dB"
    );

    // The colour space matters and is honoured: the same exported files with "ColorSpace"
    // changed to RGB (t2tf then interpolates the points in RGB) are further from ParaView.
    // (A preset with many close points, such as Inferno's 256, is left out of the presets above
    // for this reason too: the space changes nothing there, 58.3 dB either way.)
    for (a, case) in cases.iter().enumerate() {
        let space = PRESETS[case.preset].1;
        if vols[case.vol].id != "headsq" || space == "RGB" {
            continue;
        }
        let vol = &vols[case.vol];
        let mut preset: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(format!("{}.json", case.name))).unwrap(),
        )
        .unwrap();
        preset[0]["ColorSpace"] = json!("RGB");
        let as_rgb = dir.join(format!("{}_as_rgb.json", case.name));
        std::fs::write(&as_rgb, serde_json::to_string(&preset).unwrap()).unwrap();
        let img = t2tf_render(
            vol,
            &as_rgb,
            VIEWS[0],
            &dir.join(format!("{}_as_rgb.png", case.name)),
            &[],
        );
        let (shot, exact, _) = &images[a][0];
        let (right, wrong) = (psnr(shot, exact), psnr(shot, &img));
        eprintln!(
            "{}: interpolated in {space} {right:.1} dB, in RGB {wrong:.1} dB",
            case.name
        );
        assert!(
            wrong < right - 3.0,
            "{}: {space} {right:.1} dB, RGB {wrong:.1} dB",
            case.name
        );
    }

    assert!(
        failures.is_empty(),
        "under {BAR} dB:\n{}",
        failures.join("\n")
    );
    // Where the preset spans 5 % of the range, --paraview-lut predicts ParaView better: measured
    // +0.2 to +1.4 dB per view, mean +0.7 dB (BENCHMARKS.md).
    assert!(
        mean_gain > 0.0,
        "--paraview-lut gains {mean_gain:.2} dB on average"
    );
}
