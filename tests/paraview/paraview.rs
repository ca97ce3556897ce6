//! Our files in real ParaView (`xvfb-run -a pvpython --dr`): presets import and apply with
//! exactly our points (read back: ParaView's return values lie), the XML's colours, the
//! preset helper in `paraview/`, and the generated script's screenshot of a real volume.
//!
//! Without pvpython these tests say so and pass, unless T2TF_REQUIRE_PARAVIEW=1.

use crate::paraview_util;

use paraview_util::{
    assert_volume_only_inside, floats, neghip, neghip_path, projected_box, pvpython, repo,
    require_paraview, test_tf,
};
use std::path::Path;

use t2tf::camera::ParaViewCamera;
use t2tf::formats::{to_paraview_json, to_paraview_xml, write_all, ExportTf};
use t2tf::image::{psnr, Image};
use t2tf::volume::{Geometry, SourceFormat, TypedBuffer, Volume, VolumeSource};

/// neghip 64³ uint8 from ../shared, read directly (the volume readers are separate work).
const PRESET_CHECK: &str = r#"
import json, sys
import paraview.simple as pvs
from paraview import servermanager
json_path, xml_path, json_name, xml_name, helper_dir, out = sys.argv[1:7]
presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
res = {}
pvs.ImportPresets(json_path)
pvs.ImportPresets(xml_path)
res["has_json"] = bool(presets.HasPreset(json_name))
res["has_xml"] = bool(presets.HasPreset(xml_name))
res["has_bogus"] = bool(presets.HasPreset(json_name + "-not-there"))
lut = pvs.GetColorTransferFunction("a")
pwf = pvs.GetOpacityTransferFunction("a")
lut.ApplyPreset(json_name, False)
pwf.ApplyPreset(json_name, False)
res["json_rgb"] = list(lut.RGBPoints)
res["json_points"] = list(pwf.Points)
lut2 = pvs.GetColorTransferFunction("b")
lut2.ApplyPreset(xml_name, False)
res["xml_rgb"] = list(lut2.RGBPoints)
sys.path.insert(0, helper_dir)
import t2tf_apply_preset
src = pvs.Wavelet()
disp = t2tf_apply_preset.apply_preset(json_path, source=src)
res["helper_rgb"] = list(pvs.GetColorTransferFunction("RTData").RGBPoints)
res["helper_points"] = list(pvs.GetOpacityTransferFunction("RTData").Points)
res["helper_unit_distance"] = disp.ScalarOpacityUnitDistance
res["helper_representation"] = disp.GetProperty("Representation").GetElement(0)
with open(out, "w") as f:
    json.dump(res, f)
"#;

fn assert_close(got: &[f64], want: &[f64], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: {got:?} vs {want:?}");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        // ParaView keeps doubles; 1e-12 relative allows only printing-level differences.
        assert!(
            (g - w).abs() <= 1e-12 * (1.0 + w.abs()),
            "{what}[{i}]: {g} vs {w}"
        );
    }
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn presets_import_and_apply_exactly() {
    require_paraview("presets_import_and_apply_exactly");
    let v = neghip();
    let tf = ExportTf::from_control_points("t2tf-test", &test_tf(), &v, None);
    let dir = tempfile::tempdir().unwrap();
    let (json, xml) = (dir.path().join("p.json"), dir.path().join("p.xml"));
    std::fs::write(&json, to_paraview_json(&tf)).unwrap();
    // The XML carries a different name so the two imports do not collide.
    let mut xml_tf = tf.clone();
    xml_tf.name = format!("{}-xml", tf.name);
    std::fs::write(&xml, to_paraview_xml(&xml_tf)).unwrap();
    let script = dir.path().join("check.py");
    std::fs::write(&script, PRESET_CHECK).unwrap();
    let out = dir.path().join("out.json");
    let helper = repo().join("paraview/scripts");
    pvpython(
        &script,
        &[
            json.to_str().unwrap(),
            xml.to_str().unwrap(),
            &tf.name,
            &xml_tf.name,
            helper.to_str().unwrap(),
            out.to_str().unwrap(),
        ],
    );
    let res: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(res["has_json"], true);
    assert_eq!(res["has_xml"], true);
    assert_eq!(res["has_bogus"], false, "HasPreset can say no");

    let rgb: Vec<f64> = tf
        .rgb_points
        .iter()
        .flat_map(|&(x, c)| [x, c[0], c[1], c[2]])
        .collect();
    let opacity: Vec<f64> = tf
        .opacity_points
        .iter()
        .flat_map(|&(x, o)| [x, o, 0.5, 0.0])
        .collect();
    assert_close(&floats(&res["json_rgb"]), &rgb, "JSON preset colours");
    assert_close(
        &floats(&res["json_points"]),
        &opacity,
        "JSON preset opacity",
    );
    assert_close(&floats(&res["helper_rgb"]), &rgb, "helper colours");
    assert_close(&floats(&res["helper_points"]), &opacity, "helper opacity");
    assert_eq!(res["helper_unit_distance"].as_f64(), tf.unit_distance);
    assert_eq!(res["helper_representation"], "Volume");

    // XML: ParaView keeps only the colours, at the merged positions; compare as curves.
    let xml_rgb = floats(&res["xml_rgb"]);
    assert_eq!(xml_rgb.len() % 4, 0);
    assert!(xml_rgb.len() >= rgb.len());
    for q in xml_rgb.chunks_exact(4) {
        let want = t2tf::tf::interpolate(&tf.rgb_points, q[0]);
        for c in 0..3 {
            assert!((q[c + 1] - want[c]).abs() < 1e-12, "XML colour at {}", q[0]);
        }
    }
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn generated_script_renders_the_volume_in_paraview() {
    require_paraview("generated_script_renders_the_volume_in_paraview");
    let v = neghip();
    let dir = tempfile::tempdir().unwrap();
    // An oblique view so the box projects to a hexagon-ish region, not the whole frame.
    let c = v.geometry.center();
    let r = v.geometry.bounding_radius();
    let view = ParaViewCamera {
        position: [c[0] + 2.2 * r, c[1] - 2.2 * r, c[2] + 1.0 * r],
        focal_point: c,
        view_up: [0.0, 0.0, 1.0],
        view_angle: 45.0,
    };
    let background = [0.1, 0.2, 0.3];
    let files = write_all(
        dir.path(),
        "neghip",
        &test_tf(),
        &v,
        &view,
        background,
        None,
    )
    .unwrap();
    let script = files.paraview_script.expect("script written");
    let shot = dir.path().join("shot.png");
    let (w, h) = (200usize, 150usize);
    let log = pvpython(
        &script,
        &[
            "--screenshot",
            shot.to_str().unwrap(),
            "--size",
            &w.to_string(),
            &h.to_string(),
        ],
    );
    let img = Image::load_png(&shot).unwrap_or_else(|e| panic!("{e}\n{log}"));
    assert_eq!((img.width, img.height), (w, h));
    // For a look by eye: T2TF_PARAVIEW_SHOT=/some/file.png keeps the screenshot.
    if let Ok(keep) = std::env::var("T2TF_PARAVIEW_SHOT") {
        std::fs::copy(&shot, keep).unwrap();
    }
    let b = projected_box(&v, &view, w, h);
    assert!(
        b[0] > 2.0 && b[1] > 2.0 && b[2] < w as f64 - 2.0 && b[3] < h as f64 - 2.0,
        "{b:?}"
    );
    assert_volume_only_inside(&img, b, background);
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn unit_distance_does_not_change_the_paraview_image() {
    // docs/DESIGN.md: with o = 1 − exp(−σu/L) and ScalarOpacityUnitDistance = u, VTK renders
    // 1 − exp(−σΔ/L) whatever u is. Two exports for u = 0.5 and u = 4 must render alike
    // (differences: the export tolerance and VTK's 1024-entry opacity table); a wrong
    // conversion (e.g. o = σu without the exponential) changes the image grossly.
    require_paraview("unit_distance_does_not_change_the_paraview_image");
    let v = neghip();
    let view = ParaViewCamera::front(&v.geometry, 2.5);
    let dir = tempfile::tempdir().unwrap();
    let mut shots = Vec::new();
    for (name, u) in [("u05", 0.5), ("u4", 4.0)] {
        let files = write_all(dir.path(), name, &test_tf(), &v, &view, [0.0; 3], Some(u)).unwrap();
        let shot = dir.path().join(format!("{name}.png"));
        pvpython(
            &files.paraview_script.unwrap(),
            &[
                "--screenshot",
                shot.to_str().unwrap(),
                "--size",
                "160",
                "160",
            ],
        );
        shots.push(Image::load_png(&shot).unwrap());
    }
    let p = psnr(&shots[0], &shots[1]);
    eprintln!("PSNR between u = 0.5 and u = 4 exports: {p:.1} dB");
    assert!(p > 40.0, "PSNR {p:.1} dB");
    // The images are not blank (otherwise any PSNR would be high).
    let lit = shots[0].data.iter().filter(|&&c| c > 0.05).count();
    assert!(lit > 1000, "{lit} lit channel values");
}

const WRITE_WAVELET: &str = r#"
import sys
import paraview.simple as pvs
out_dir = sys.argv[1]
w = pvs.Wavelet()
pvs.SaveData(out_dir + "/wavelet.vti", proxy=w)
pvs.SaveData(out_dir + "/wavelet.vtk", proxy=w)
lo, hi = w.PointData["RTData"].GetRange()
print("RANGE %r %r" % (lo, hi))
"#;

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn generated_script_opens_vti_and_legacy_vtk() {
    // ParaView writes its Wavelet source (21³ points from −10 to 10, array RTData) as .vti
    // and legacy .vtk; our script must open each with the right reader and array and show it.
    require_paraview("generated_script_opens_vti_and_legacy_vtk");
    let dir = tempfile::tempdir().unwrap();
    let writer = dir.path().join("write.py");
    std::fs::write(&writer, WRITE_WAVELET).unwrap();
    let log = pvpython(&writer, &[dir.path().to_str().unwrap()]);
    let range: Vec<f64> = log
        .lines()
        .find_map(|l| l.strip_prefix("RANGE "))
        .expect("range printed")
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let g = Geometry {
        dims: [21, 21, 21],
        spacing: [1.0; 3],
        origin: [-10.0; 3],
    };
    // The script needs geometry, range and source only; a ramp over the range stands in
    // for the values (our .vti/.vtk readers are tested on their own).
    let n = g.voxel_count();
    let ramp = (0..n)
        .map(|i| range[0] + (range[1] - range[0]) * i as f64 / (n - 1) as f64)
        .collect();
    let base = Volume::from_buffer(Path::new("wavelet"), g, &TypedBuffer::from_f64(ramp)).unwrap();
    let view = ParaViewCamera::front(&base.geometry, 2.5);
    for (file, format) in [
        (
            "wavelet.vti",
            SourceFormat::Vti {
                array: "RTData".into(),
            },
        ),
        (
            "wavelet.vtk",
            SourceFormat::LegacyVtk {
                array: "RTData".into(),
            },
        ),
    ] {
        let mut v = base.clone();
        v.source = Some(VolumeSource {
            path: dir.path().join(file),
            format,
        });
        let name = file.replace('.', "_");
        let files = write_all(dir.path(), &name, &test_tf(), &v, &view, [0.0; 3], None).unwrap();
        let shot = dir.path().join(format!("{name}.png"));
        pvpython(
            &files.paraview_script.unwrap(),
            &[
                "--screenshot",
                shot.to_str().unwrap(),
                "--size",
                "120",
                "120",
            ],
        );
        let img = Image::load_png(&shot).unwrap();
        let b = projected_box(&v, &view, 120, 120);
        let (mut lit_in, mut lit_out) = (0, 0);
        for y in 0..120 {
            for x in 0..120 {
                let lit = img.pixel(x, y).iter().any(|&c| c > 1.5 / 255.0);
                let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
                if cx > b[0] - 2.0 && cx < b[2] + 2.0 && cy > b[1] - 2.0 && cy < b[3] + 2.0 {
                    lit_in += lit as usize;
                } else {
                    lit_out += lit as usize;
                }
            }
        }
        assert_eq!(lit_out, 0, "{file}: pixels outside the box lit");
        assert!(
            lit_in > 1000,
            "{file}: only {lit_in} pixels show the volume"
        );
    }
    // The helper's command line: open the .vti, apply the preset, save a screenshot.
    let shot = dir.path().join("helper.png");
    pvpython(
        &repo().join("paraview/scripts/t2tf_apply_preset.py"),
        &[
            dir.path().join("wavelet_vti.json").to_str().unwrap(),
            dir.path().join("wavelet.vti").to_str().unwrap(),
            "--array",
            "RTData",
            "--screenshot",
            shot.to_str().unwrap(),
        ],
    );
    let img = Image::load_png(&shot).unwrap();
    let bg = img.pixel(0, 0);
    let differs = (0..img.height)
        .flat_map(|y| (0..img.width).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = img.pixel(x, y);
            (0..3).any(|c| (p[c] - bg[c]).abs() > 2.0 / 255.0)
        })
        .count();
    assert!(
        differs > 1000,
        "helper screenshot shows {differs} non-background pixels"
    );
}

/// Imports a preset library into ParaView and reports what its preset manager then holds
/// for each given name: the points, and 1024 samples of the colour and opacity functions
/// after applying it (vtkColorTransferFunction's and vtkPiecewiseFunction's own evaluation).
const LIBRARY_CHECK: &str = r#"
import json, sys
import paraview.simple as pvs
from paraview import servermanager
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction
library, out = sys.argv[1], sys.argv[2]
names = sys.argv[3:]
presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
before = presets.GetNumberOfPresets()
pvs.ImportPresets(library)
res = {"added": presets.GetNumberOfPresets() - before, "presets": {}}
for i, name in enumerate(names):
    if not presets.HasPreset(name):
        res["presets"][name] = None
        continue
    lut = pvs.GetColorTransferFunction("a%d" % i)
    pwf = pvs.GetOpacityTransferFunction("a%d" % i)
    lut.ApplyPreset(name, False)
    pwf.ApplyPreset(name, False)
    lo, hi = lut.RGBPoints[0], lut.RGBPoints[-4]
    xs = [lo + (hi - lo) * k / 1023 for k in range(1024)]
    c_lut, c_pwf = lut.GetClientSideObject(), pwf.GetClientSideObject()
    rgb = []
    for x in xs:
        c = [0.0, 0.0, 0.0]
        vtkColorTransferFunction.GetColor(c_lut, x, c)
        rgb.append(c)
    res["presets"][name] = {"x": xs, "rgb": rgb, "opacity": [c_pwf.GetValue(x) for x in xs]}
with open(out, "w") as f:
    json.dump(res, f)
"#;

/// `t2tf optimize` with the tiny test CLIP, quick settings: panics with its stderr on failure.
fn quick_optimize(volume: &Path, args: &[&str], cache: &Path) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .current_dir(repo())
        .arg("optimize")
        .arg(volume)
        .args(["--model", "tests/fixtures/clip/quick_gelu"])
        .args(["--tokenizer", "../shared/data/clip/tokenizer.json"])
        .args([
            "--threads",
            "2",
            "--views",
            "1",
            "--negatives-per-step",
            "8",
        ])
        .args(args)
        .env("XDG_CACHE_HOME", cache)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn a_batchs_library_imports_as_one_preset_per_prompt() {
    require_paraview("a_batchs_library_imports_as_one_preset_per_prompt");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("batch");
    let prompts = ["bone", "skin", "vessels"];
    let mut args = vec!["--steps", "2", "--out", out.to_str().unwrap()];
    for p in prompts {
        args.extend(["--prompt", p]);
    }
    quick_optimize(&neghip_path(), &args, dir.path());
    let library = out.join("presets.json");
    let names: Vec<String> =
        t2tf::formats::list_presets(&library, t2tf::formats::DEFAULT_MAX_PRESET_SIZE)
            .unwrap()
            .into_iter()
            .map(|p| p.name)
            .collect();
    assert_eq!(names.len(), 3);
    let script = dir.path().join("library.py");
    std::fs::write(&script, LIBRARY_CHECK).unwrap();
    let json = dir.path().join("library.json");
    let mut a = vec![library.to_str().unwrap(), json.to_str().unwrap()];
    a.extend(names.iter().map(String::as_str));
    pvpython(&script, &a);
    let res: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(res["added"], 3, "{res}");
    for (name, prompt) in names.iter().zip(prompts) {
        assert!(name.starts_with(&format!("{prompt}-")), "{name}");
        let sampled = &res["presets"][name];
        assert!(!sampled.is_null(), "{name} not in ParaView's presets");
        // ParaView's samples of the imported preset = the prompt's own TF file.
        let own = t2tf::formats::read_tf(&out.join(prompt).join(format!("{prompt}.json"))).unwrap();
        let o: Vec<(f64, [f64; 1])> = own.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
        for (i, x) in floats(&sampled["x"]).iter().enumerate() {
            let c = t2tf::tf::interpolate(&own.rgb_points, *x);
            let pv = floats(&sampled["rgb"][i]);
            for k in 0..3 {
                assert!((c[k] - pv[k]).abs() < 1e-6, "{name} colour at {x}");
            }
            let po = sampled["opacity"][i].as_f64().unwrap();
            assert!(
                (t2tf::tf::interpolate(&o, *x)[0] - po).abs() < 1e-6,
                "{name} opacity at {x}"
            );
        }
    }
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn a_start_written_with_steps_0_is_the_init_as_paraview_samples_it() {
    // ParaView itself samples what `--init X --steps 0` wrote, against its own samples of X
    // (colorspace_samples.json): the check the optimize tests make with our interpolation,
    // made here by VTK.
    require_paraview("a_start_written_with_steps_0_is_the_init_as_paraview_samples_it");
    let dir = tempfile::tempdir().unwrap();
    // A 24³ float volume spanning the fixtures' -10..60.
    let n = 24usize;
    let mut bytes = Vec::new();
    for i in 0..n * n * n {
        let t = if i == 0 {
            0.0
        } else if i == n * n * n - 1 {
            1.0
        } else {
            ((i * 7919) % 1000) as f32 / 1000.0
        };
        bytes.extend_from_slice(&(-10.0 + 70.0 * t).to_le_bytes());
    }
    let vol = dir.path().join(format!("v_{n}x{n}x{n}_float32.raw"));
    std::fs::write(&vol, bytes).unwrap();
    let fixtures = repo().join("tests/fixtures/paraview");
    let goldens: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(fixtures.join("colorspace_samples.json")).unwrap(),
    )
    .unwrap();
    let script = dir.path().join("library.py");
    std::fs::write(&script, LIBRARY_CHECK).unwrap();
    for (file, golden) in goldens.as_object().unwrap() {
        let out = dir.path().join(file.trim_end_matches(".json"));
        let init = fixtures.join(file);
        quick_optimize(
            &vol,
            &[
                "--prompt",
                "x",
                "--steps",
                "0",
                "--init",
                init.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--name",
                "start",
            ],
            dir.path(),
        );
        let written = out.join("start.json");
        let name = t2tf::formats::read_tf(&written).unwrap().name;
        let json = dir.path().join(format!("{file}.samples.json"));
        pvpython(
            &script,
            &[written.to_str().unwrap(), json.to_str().unwrap(), &name],
        );
        let res: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let s = &res["presets"][&name];
        let (xs, gx) = (floats(&s["x"]), floats(&golden["x"]));
        assert_eq!(xs.len(), gx.len());
        let (mut ec, mut eo) = (0.0f64, 0.0f64);
        for i in 0..xs.len() {
            assert!(
                (xs[i] - gx[i]).abs() < 1e-9,
                "{file}: sampled at other values"
            );
            let (c, g) = (floats(&s["rgb"][i]), floats(&golden["rgb"][i]));
            (0..3).for_each(|k| ec = ec.max((c[k] - g[k]).abs()));
            eo = eo.max(
                (s["opacity"][i].as_f64().unwrap() - golden["opacity"][i].as_f64().unwrap()).abs(),
            );
        }
        eprintln!(
            "{file:32} ParaView: colour {:.2}/255, opacity {eo:.1e}",
            ec * 255.0
        );
        assert!(
            ec <= 1.0 / 255.0 && eo <= 2e-3,
            "{file}: colour {ec}, opacity {eo}"
        );
    }
}

/// What `xvfb-run` leaves when it dies without cleaning up (killed outright): its Xvfb, in the
/// process group the test started. The group's guard stops it, so no X server outlives the
/// test that started it.
#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn an_xvfb_left_by_a_killed_xvfb_run_is_stopped_with_its_group() {
    paraview_util::require_tools(
        "an_xvfb_left_by_a_killed_xvfb_run_is_stopped_with_its_group",
        &["xvfb-run", "Xvfb"],
    );
    let mut command = std::process::Command::new("timeout");
    command
        .args(["60", "xvfb-run"])
        .args(paraview_util::xvfb_display_args())
        // The client kills xvfb-run (its parent) with SIGKILL, which no script can clean up
        // after.
        .args(["sh", "-c", "kill -9 $PPID"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    let (mut child, group) = paraview_util::spawn_in_group(&mut command).unwrap();
    child.wait().unwrap();
    let id = group.0;
    let xvfb_in = |g: libc::pid_t| {
        std::fs::read_dir("/proc").unwrap().flatten().any(|e| {
            let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
            let fields: Vec<&str> = stat.split(' ').collect();
            // A zombie has ended; its parent (now init) reaps it.
            stat.contains("(Xvfb) ")
                && fields.get(2) != Some(&"Z")
                && fields.get(4).and_then(|f| f.parse().ok()) == Some(g)
        })
    };
    // Without the guard it would run on: the leak is real.
    assert!(xvfb_in(id), "xvfb-run took its Xvfb with it");
    assert!(paraview_util::group_alive(id));
    drop(group);
    assert!(
        !paraview_util::group_alive(id),
        "the group outlived its guard"
    );
    assert!(!xvfb_in(id));
}
