//! The design loop: `--init` (start from a TF), `--lock MIN,MAX` (keep part of it) and several
//! `--prompt` in one run, through the binary with the tiny random CLIP.
//!
//! Fidelity is judged against ParaView's own numbers: the colour-space fixtures were written
//! by ParaView's exporter and sampled by VTK (tests/fixtures/paraview/colorspace_samples.json,
//! 1024 colours and opacities over each preset's range). With `--steps 0` the written preset
//! must give those numbers again: colour within 1/255, opacity within 2e-3.

use std::path::{Path, PathBuf};
use std::process::Command;

use t2tf::formats::{read_tf, ExportTf};

use crate::colorspace_goldens::goldens;
use t2tf::tf::interpolate;

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const NEGHIP: &str = "../shared/data/volumes/neghip_64x64x64_uint8.raw";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `t2tf optimize VOLUME --model tiny --tokenizer real --threads 2 ARGS…` with the caption
/// cache in `cache`: (success, stderr).
fn optimize(volume: &Path, args: &[&str], cache: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .current_dir(repo())
        .arg("optimize")
        .arg(volume)
        .args(["--model", MODEL, "--tokenizer", TOKENIZER, "--threads", "2"])
        .args(["--negatives-per-step", "8", "--progress", "lines"])
        .args(args)
        .env("XDG_CACHE_HOME", cache)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A 24³ float32 volume whose values span exactly [lo, hi] (a smooth blob plus a ramp).
fn volume(dir: &Path, [lo, hi]: [f32; 2]) -> PathBuf {
    let n = 24;
    let mut bytes = Vec::with_capacity(n * n * n * 4);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let c = |v: usize| (v as f32 - 11.5) / 11.5;
                let r2 = c(x) * c(x) + c(y) * c(y) + c(z) * c(z);
                let t = (0.7 * (-2.0 * r2).exp() + 0.3 * z as f32 / (n - 1) as f32).clamp(0.0, 1.0);
                let t = if (x, y, z) == (0, 0, 0) {
                    0.0
                } else if (x, y, z) == (12, 12, 12) {
                    1.0
                } else {
                    t
                };
                bytes.extend_from_slice(&(lo + t * (hi - lo)).to_le_bytes());
            }
        }
    }
    let path = dir.join(format!("blob_{n}x{n}x{n}_float32.raw"));
    std::fs::write(&path, bytes).unwrap();
    path
}

/// Colour and opacity of `tf` at `x`, as ParaView interpolates the written file (RGB and
/// opacity linear between points, constant outside).
fn at(tf: &ExportTf, x: f64) -> ([f64; 3], f64) {
    let o: Vec<(f64, [f64; 1])> = tf.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
    (interpolate(&tf.rgb_points, x), interpolate(&o, x)[0])
}

/// Max colour and opacity difference of two TFs over `xs`.
fn difference(a: &ExportTf, b: &ExportTf, xs: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut ec, mut eo) = (0.0f64, 0.0f64);
    for x in xs {
        let ((ca, oa), (cb, ob)) = (at(a, x), at(b, x));
        (0..3).for_each(|k| ec = ec.max((ca[k] - cb[k]).abs()));
        eo = eo.max((oa - ob).abs());
    }
    (ec, eo)
}

#[test]
fn steps_0_writes_the_init_as_paraview_samples_it_in_every_colour_space() {
    let dir = tempfile::tempdir().unwrap();
    // The fixtures span -10..60: a volume with exactly that range.
    let vol = volume(dir.path(), [-10.0, 60.0]);
    for g in goldens() {
        let file = &g.file;
        let init = repo().join("tests/fixtures/paraview").join(file);
        let out = dir.path().join(file.trim_end_matches(".json"));
        let (ok, err) = optimize(
            &vol,
            &[
                "--prompt",
                "a blob",
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
        assert!(ok, "{file}: {err}");
        let tf = read_tf(&out.join("start.json")).unwrap();
        let (mut ec, mut eo) = (0.0f64, 0.0f64);
        for (i, &x) in g.x.iter().enumerate() {
            let (c, o) = at(&tf, x);
            (0..3).for_each(|k| ec = ec.max((c[k] - g.rgb[i][k]).abs()));
            eo = eo.max((o - g.opacity[i]).abs());
        }
        eprintln!("{file:32} colour {:.2}/255  opacity {eo:.1e}", ec * 255.0);
        assert!(
            ec <= 1.0 / 255.0,
            "{file}: colour off by {:.2}/255",
            ec * 255.0
        );
        assert!(eo <= 2e-3, "{file}: opacity off by {eo:.1e}");
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        assert!(
            report["init"].as_str().unwrap().contains(file.as_str()),
            "{report}"
        );
    }
}

#[test]
fn a_locked_range_stays_while_the_rest_changes() {
    let dir = tempfile::tempdir().unwrap();
    let vol = repo().join(NEGHIP);
    let init = repo().join("tests/fixtures/paraview/colorspace_RGB.json");
    let common = |out: &Path, steps: &str, lock: Option<&str>| {
        let mut a: Vec<String> = [
            "--prompt",
            "a red molecule",
            "--steps",
            steps,
            "--out",
            out.to_str().unwrap(),
            "--name",
            "tf",
        ]
        .map(String::from)
        .to_vec();
        if let Some(l) = lock {
            a.extend(["--lock".to_string(), l.to_string()]);
        }
        a
    };
    // Without --init: the locked part is the paper's initialization. With it: the preset's
    // (rescaled onto neghip's 0..255 is not needed: the preset's points outside the data
    // are cut, those inside kept).
    for with_init in [false, true] {
        let run = |name: &str, steps: &str, lock: Option<&str>| {
            let out = dir.path().join(format!("{name}-{with_init}"));
            let mut args = common(&out, steps, lock);
            if with_init {
                args.extend(["--init".into(), init.to_str().unwrap().into()]);
            }
            let refs: Vec<&str> = args.iter().map(String::as_str).collect();
            let (ok, err) = optimize(&vol, &refs, dir.path());
            assert!(ok, "{err}");
            read_tf(&out.join("tf.json")).unwrap()
        };
        let start = run("start", "0", Some("40,120"));
        let locked = run("locked", "6", Some("40,120"));
        let free = run("free", "6", None);
        // ParaView samples 1024 values over the data range (0..255 for neghip).
        let samples = |lo: f64, hi: f64| {
            (0..1024)
                .map(move |i| i as f64 * 255.0 / 1023.0)
                .filter(move |&x| lo <= x && x <= hi)
        };
        let (c, o) = difference(&start, &locked, samples(40.0, 120.0));
        assert!(
            c <= 1.0 / 255.0 && o <= 2e-3,
            "locked range moved: colour {c}, opacity {o}"
        );
        let (c_out, o_out) = difference(&start, &locked, samples(125.0, 255.0));
        assert!(
            c_out + o_out > 1e-3,
            "the rest did not change: {c_out} {o_out}"
        );
        // Without the lock the same run changes the range.
        let (c_free, o_free) = difference(&start, &free, samples(40.0, 120.0));
        assert!(
            c_free + o_free > 1e-3,
            "an unlocked run left it alone: {c_free} {o_free}"
        );
    }
}

#[cfg(unix)]
#[test]
fn a_batch_gives_each_prompt_the_tf_of_its_own_run_and_one_library() {
    let dir = tempfile::tempdir().unwrap();
    let vol = repo().join(NEGHIP);
    let prompts = ["a red molecule", "a blue cloud", "a red molecule!"];
    let batch = dir.path().join("batch");
    let mut args = vec!["--steps", "3", "--out", batch.to_str().unwrap()];
    for p in prompts {
        args.extend(["--prompt", p]);
    }
    let (ok, err) = optimize(&vol, &args, dir.path());
    assert!(ok, "{err}");
    let names = ["a-red-molecule", "a-blue-cloud", "a-red-molecule-2"];
    for (p, name) in prompts.iter().zip(names) {
        let alone = dir.path().join(format!("alone-{name}"));
        let (ok, err) = optimize(
            &vol,
            &[
                "--steps",
                "3",
                "--prompt",
                p,
                "--out",
                alone.to_str().unwrap(),
                "--name",
                name,
            ],
            dir.path(),
        );
        assert!(ok, "{err}");
        let a = std::fs::read(alone.join(format!("{name}.json"))).unwrap();
        let b = std::fs::read(batch.join(name).join(format!("{name}.json"))).unwrap();
        assert!(
            a == b,
            "{p}: the batch's TF differs from the TF of its own run"
        );
    }
    let library: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(batch.join("presets.json")).unwrap())
            .unwrap();
    let listed: Vec<&str> = library
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["Name"].as_str().unwrap())
        .collect();
    assert_eq!(listed.len(), 3);
    for (l, n) in listed.iter().zip(names) {
        assert!(l.starts_with(&format!("{n}-")), "{l} for {n}");
    }
    // A symlink planted where a prompt's sub-folder goes is refused before any work.
    let victim = dir.path().join("victim");
    std::fs::create_dir(&victim).unwrap();
    let planted = dir.path().join("planted");
    std::fs::create_dir(&planted).unwrap();
    std::os::unix::fs::symlink(&victim, planted.join("a-red-molecule")).unwrap();
    let (ok, err) = optimize(
        &vol,
        &[
            "--steps",
            "1",
            "--prompt",
            prompts[0],
            "--prompt",
            prompts[1],
            "--out",
            planted.to_str().unwrap(),
        ],
        dir.path(),
    );
    assert!(!ok && err.contains("is a symlink"), "{err}");
    assert_eq!(
        std::fs::read_dir(&victim).unwrap().count(),
        0,
        "wrote through the link"
    );
    // `--name` cannot name several TFs.
    let (ok, err) = optimize(
        &vol,
        &[
            "--prompt",
            "a",
            "--prompt",
            "b",
            "--name",
            "x",
            "--out",
            batch.to_str().unwrap(),
        ],
        dir.path(),
    );
    assert!(!ok && err.contains("--name"), "{err}");
}

#[test]
fn bad_starts_and_locks_are_one_line_errors_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let vol = repo().join(NEGHIP);
    let fixtures = repo().join("tests/fixtures/paraview");
    let rgb = fixtures.join("colorspace_RGB.json");
    // A preset far outside neghip's 0..255.
    let far = dir.path().join("far.json");
    std::fs::write(
        &far,
        r#"[{"Name":"far","RGBPoints":[1000,0,0,0,2000,1,1,1],"Points":[1000,0,0.5,0,2000,1,0.5,0]}]"#,
    )
    .unwrap();
    let library = fixtures.join("paraview_library.json");
    let categorical = t2tf::formats::list_presets(&library, t2tf::formats::DEFAULT_MAX_PRESET_SIZE)
        .unwrap()
        .into_iter()
        .find(|p| p.space.is_none())
        .map(|p| p.name);
    let mut cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["--lock".into(), "120,40".into()], "MIN < MAX"),
        (
            vec!["--lock".into(), "-50,40".into()],
            "outside the data range",
        ),
        (
            vec!["--lock".into(), "40,300".into()],
            "outside the data range",
        ),
        (vec!["--lock".into(), "abc".into()], "MIN,MAX"),
        (
            vec![
                "--lock".into(),
                "10,50".into(),
                "--lock".into(),
                "40,80".into(),
            ],
            "overlap",
        ),
        (
            vec!["--init".into(), far.to_str().unwrap().into()],
            "misses the data range",
        ),
        (
            vec!["--init".into(), "no-such-preset.json".into()],
            "no-such-preset.json",
        ),
        (
            vec![
                "--init".into(),
                rgb.to_str().unwrap().into(),
                "--preset".into(),
                "nope".into(),
            ],
            "nope",
        ),
    ];
    if let Some(name) = &categorical {
        cases.push((
            vec![
                "--init".into(),
                library.to_str().unwrap().into(),
                "--preset".into(),
                name.clone(),
            ],
            "categorical",
        ));
    }
    for (extra, needle) in cases {
        let out = dir.path().join("out");
        let mut args = vec![
            "--prompt".to_string(),
            "x".into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ];
        args.extend(extra.iter().cloned());
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, err) = optimize(&vol, &refs, dir.path());
        assert!(!ok, "{extra:?} accepted");
        assert!(err.contains(needle), "{extra:?}: {err}");
        assert!(
            !err.contains("loading"),
            "{extra:?}: work began before the error: {err}"
        );
        // One line (clap adds its "For more information" hint to a flag it cannot parse).
        let lines = err
            .lines()
            .filter(|l| !l.trim().is_empty() && !l.starts_with("For more information"))
            .count();
        assert_eq!(lines, 1, "{extra:?}: {err}");
        assert!(!out.join("out.json").exists(), "{extra:?} wrote a TF");
    }
}

#[test]
fn a_colour_map_without_opacity_starts_with_its_colours_over_the_data_range() {
    // Library presets hold colours only, over their own range (Cividis: 256 points in Lab,
    // Turbo: 256 in RGB): the start spreads them over the data range, as ParaView applies a
    // preset, with the paper's densities.
    let dir = tempfile::tempdir().unwrap();
    let vol = repo().join(NEGHIP);
    let library = repo().join("tests/fixtures/paraview/paraview_library.json");
    for name in ["Cividis", "Turbo"] {
        let out = dir.path().join(name);
        let (ok, err) = optimize(
            &vol,
            &[
                "--prompt",
                "x",
                "--steps",
                "0",
                "--init",
                library.to_str().unwrap(),
                "--preset",
                name,
                "--out",
                out.to_str().unwrap(),
                "--name",
                "tf",
            ],
            dir.path(),
        );
        assert!(ok, "{name}: {err}");
        let tf = read_tf(&out.join("tf.json")).unwrap();
        let preset = t2tf::formats::read_preset(&library, Some(name)).unwrap();
        let [a, b] = preset.tf.data_range();
        let xs: Vec<f64> = (0..1024).map(|i| i as f64 / 1023.0).collect();
        let want = preset
            .color_map()
            .colors_at(&xs.iter().map(|t| a + t * (b - a)).collect::<Vec<_>>());
        let mut err = 0.0f64;
        for (t, w) in xs.iter().zip(&want) {
            let c = at(&tf, t * 255.0).0;
            (0..3).for_each(|k| err = err.max((c[k] - w[k]).abs()));
        }
        eprintln!("{name}: colour {:.2}/255", err * 255.0);
        assert!(
            err <= 1.0 / 255.0,
            "{name}: colour off by {:.2}/255",
            err * 255.0
        );
        let o_max = (0..=255)
            .map(|v| at(&tf, v as f64).1)
            .fold(0.0f64, f64::max);
        assert!(o_max > 0.0, "{name}: no opacity");
    }
}

#[test]
fn an_opaque_start_is_kept_beyond_the_papers_densities() {
    // Opacity 0.9 to 1 per voxel on a 64-voxel box: far denser than σ = 255 reaches there
    // (0.98 per voxel). The start is kept as it is (an opacity of 1 as 1 − 1e-3).
    let dir = tempfile::tempdir().unwrap();
    let vol = repo().join(NEGHIP);
    let init = dir.path().join("opaque.json");
    std::fs::write(
        &init,
        r#"[{"Name":"opaque","ColorSpace":"RGB","RGBPoints":[0,0,0,1, 255,1,0,0],
            "Points":[0,0,0.5,0, 60,0.9,0.5,0, 100,1,0.5,0, 255,1,0.5,0],
            "t2tfScalarOpacityUnitDistance":1.0}]"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    for steps in ["0", "3"] {
        let (ok, err) = optimize(
            &vol,
            &[
                "--prompt",
                "x",
                "--steps",
                steps,
                "--init",
                init.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--name",
                "tf",
            ],
            dir.path(),
        );
        assert!(ok, "{err}");
        assert!(!err.contains("warning"), "{err}");
        let tf = read_tf(&out.join("tf.json")).unwrap();
        assert_eq!(tf.unit_distance, Some(1.0));
        if steps == "0" {
            let want = read_tf(&init).unwrap();
            let (c, o) = difference(&want, &tf, (0..1024).map(|i| i as f64 * 255.0 / 1023.0));
            assert!(c <= 1.0 / 255.0 && o <= 2e-3, "colour {c}, opacity {o}");
        }
    }
}
