//! Round trips through every TF format, load_tf, and the ParaView-written fixture.

use std::path::{Path, PathBuf};

use t2tf::formats::{
    from_paraview_json, load_tf, read_tf, to_paraview_json, to_paraview_xml, to_visit_ct, write_tf,
    ExportTf,
};
use t2tf::tf::{interpolate, sigma_to_opacity, ControlPoints, EXPORT_TOLERANCE};
use t2tf::volume::{Geometry, TypedBuffer, Volume};

/// A small volume with non-unit spacing and a data range of [-3, 40].
fn volume() -> Volume {
    let dims = [16, 12, 10];
    let n = dims.iter().product::<usize>();
    let values: Vec<f64> = (0..n)
        .map(|i| -3.0 + 43.0 * (i as f64 / (n - 1) as f64))
        .collect();
    let g = Geometry {
        dims,
        spacing: [1.0, 2.0, 0.5],
        origin: [0.0; 3],
    };
    Volume::from_buffer(Path::new("synthetic"), g, &TypedBuffer::from_f64(values)).unwrap()
}

fn smooth_cp(k: usize) -> ControlPoints {
    let sigma = (0..k)
        .map(|i| 127.5 * (1.0 + (i as f64 * 0.7).sin()))
        .collect();
    let rgb = (0..k)
        .map(|i| {
            let t = i as f64 / (k - 1) as f64;
            [t, (t * 5.0).cos().abs(), 0.3 + 0.4 * t * t]
        })
        .collect();
    ControlPoints::evenly_spaced(sigma, rgb).unwrap()
}

fn opacity_curve(tf: &ExportTf) -> Vec<(f64, [f64; 1])> {
    tf.opacity_points.iter().map(|&(x, o)| (x, [o])).collect()
}

/// Max difference of two TFs' opacity and colour curves over `grid` data values.
fn curve_distance(a: &ExportTf, b: &ExportTf, lo: f64, hi: f64) -> (f64, f64) {
    let (oa, ob) = (opacity_curve(a), opacity_curve(b));
    let (mut eo, mut ec) = (0.0f64, 0.0f64);
    for j in 0..=20_000 {
        let x = lo + (hi - lo) * j as f64 / 20_000.0;
        eo = eo.max((interpolate(&oa, x)[0] - interpolate(&ob, x)[0]).abs());
        let (ca, cb) = (interpolate(&a.rgb_points, x), interpolate(&b.rgb_points, x));
        for c in 0..3 {
            ec = ec.max((ca[c] - cb[c]).abs());
        }
    }
    (eo, ec)
}

fn tmp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join(name);
    (d, p)
}

#[test]
fn export_follows_design_conventions() {
    let v = volume();
    let cp = smooth_cp(24);
    let tf = ExportTf::from_control_points("smooth", &cp, &v, None);
    // Default unit distance: the mean voxel spacing, written into the export.
    assert_eq!(tf.unit_distance, Some((1.0 + 2.0 + 0.5) / 3.0));
    // Both curves span the volume's data range exactly (ParaView rescales each over its own).
    assert_eq!(tf.rgb_points[0].0, -3.0);
    assert_eq!(tf.opacity_points[0].0, -3.0);
    assert_eq!(tf.rgb_points.last().unwrap().0, 40.0);
    assert_eq!(tf.opacity_points.last().unwrap().0, 40.0);
    // o = 1 − exp(−σ u / L) within the export tolerance everywhere, L = 22 (y: 11 · 2).
    let l = v.geometry.longest_side();
    assert_eq!(l, 22.0);
    let o = opacity_curve(&tf);
    for j in 0..=5000 {
        let t = j as f64 / 5000.0;
        let want = sigma_to_opacity(cp.eval(t)[0], 3.5 / 3.0, l);
        let got = interpolate(&o, v.denormalize(t))[0];
        assert!(
            (got - want).abs() <= EXPORT_TOLERANCE,
            "t={t}: {got} vs {want}"
        );
    }
    // The name carries a content hash; a different TF gets a different one.
    assert!(tf.name.starts_with("smooth-") && tf.name.len() == "smooth-".len() + 8);
    let other = ExportTf::from_control_points("smooth", &smooth_cp(25), &v, None);
    assert_ne!(tf.name, other.name);
    assert_eq!(tf.unique_name(), tf.name, "hash is stable");
}

#[test]
fn json_round_trip_is_exact_and_strict() {
    let v = volume();
    let tf = ExportTf::from_control_points("json test", &smooth_cp(16), &v, Some(0.37));
    let text = to_paraview_json(&tf);
    let parsed: serde_json::Value = serde_json::from_str(&text).expect("strict JSON");
    let preset = &parsed.as_array().expect("top-level array")[0];
    assert_eq!(preset["ColorSpace"], "RGB");
    assert_eq!(preset["RGBPoints"].as_array().unwrap().len() % 4, 0);
    let pts = preset["Points"].as_array().unwrap();
    assert_eq!(pts[2], 0.5);
    assert_eq!(pts[3], 0.0);
    let (_d, p) = tmp("t.json");
    write_tf(&p, &tf).unwrap();
    assert_eq!(read_tf(&p).unwrap(), tf, "bit-exact round trip");
}

#[test]
fn xml_round_trip_keeps_curves() {
    let v = volume();
    let tf = ExportTf::from_control_points("xml <&> test", &smooth_cp(16), &v, None);
    let (_d, p) = tmp("t.xml");
    write_tf(&p, &tf).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains("<ColorMap name=\"xml &lt;&amp;&gt; test-"));
    assert!(text.contains(" o=\""));
    let back = read_tf(&p).unwrap();
    assert_eq!(back.name, tf.name);
    assert_eq!(back.unit_distance, tf.unit_distance);
    // The merge onto common x adds points; the reader removes those that lie on a line.
    assert_eq!(back.rgb_points.len(), tf.rgb_points.len());
    assert_eq!(back.opacity_points.len(), tf.opacity_points.len());
    let (eo, ec) = curve_distance(&tf, &back, -5.0, 42.0);
    assert!(eo < 1e-12 && ec < 1e-12, "{eo} {ec}");
}

#[test]
fn ct_round_trip_within_8_bits() {
    let v = volume();
    let tf = ExportTf::from_control_points("ct", &smooth_cp(12), &v, None);
    let (_d, p) = tmp("t.ct");
    write_tf(&p, &tf).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains("<Object name=\"ColorTable\">"));
    assert!(text.contains("type=\"unsignedCharArray\" length=\"4\""));
    let back = read_tf(&p).unwrap();
    assert_eq!(back.data_range(), [-3.0, 40.0], "data range restored");
    assert_eq!(back.unit_distance, tf.unit_distance);
    // Colours and alpha are bytes (±0.5/255); positions are f32 (±3e-6 data units here,
    // times the steepest slope ≈ 0.1 per data unit).
    let (eo, ec) = curve_distance(&tf, &back, -3.0, 40.0);
    let tol = 0.5 / 255.0 + 1e-6;
    assert!(eo <= tol && ec <= tol, "{eo} {ec}");
}

#[test]
fn load_tf_reproduces_what_paraview_shows() {
    let v = volume();
    let cp = smooth_cp(20);
    let tf = ExportTf::from_control_points("load", &cp, &v, None);
    let l = v.geometry.longest_side();
    let u = tf.unit_distance.unwrap();
    for ext in ["json", "xml"] {
        let (_d, p) = tmp(&format!("t.{ext}"));
        write_tf(&p, &tf).unwrap();
        let back = load_tf(&p, &v, None).unwrap();
        back.validate().unwrap();
        // The renderer's σ-linear TF, seen as opacity, stays within the export tolerance of
        // the original (simplification ≤ 1e-3, refinement on load ≤ 5e-4 of what ParaView
        // interpolates): compare on a grid finer than either's points.
        for j in 0..=10_000 {
            let t = j as f64 / 10_000.0;
            let (a, b) = (cp.eval(t), back.eval(t));
            let (oa, ob) = (sigma_to_opacity(a[0], u, l), sigma_to_opacity(b[0], u, l));
            assert!(
                (oa - ob).abs() <= 1.5 * EXPORT_TOLERANCE,
                "{ext} t={t}: {oa} {ob}"
            );
            for c in 1..4 {
                assert!(
                    (a[c] - b[c]).abs() <= EXPORT_TOLERANCE,
                    "{ext} colour t={t}"
                );
            }
        }
    }
    // Another unit distance given explicitly scales σ: o fixed, σ ∝ 1/u.
    let (_d, p) = tmp("t.json");
    write_tf(&p, &tf).unwrap();
    let a = load_tf(&p, &v, None).unwrap();
    let b = load_tf(&p, &v, Some(2.0 * u)).unwrap();
    let mid = a.len() / 2;
    assert_eq!(a.x[mid], b.x[mid]);
    assert!((a.sigma[mid] - 2.0 * b.sigma[mid]).abs() < 1e-9 * (1.0 + a.sigma[mid]));
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/paraview")
        .join(name)
}

#[test]
fn reads_preset_written_by_paraview() {
    // Values as set in make_paraview_preset.py (ParaView prints them with 17 digits).
    let tf = read_tf(&fixture("paraview_written_preset.json")).unwrap();
    assert_eq!(tf.name, "ParaViewWritten");
    assert_eq!(
        tf.rgb_points,
        vec![
            (-2.5, [0.1, 0.2, 0.9]),
            (10.0, [0.95, 0.6, 0.05]),
            (40.25, [1.0, 1.0, 1.0])
        ]
    );
    assert_eq!(
        tf.opacity_points,
        vec![(-2.5, 0.0), (3.0, 0.125), (40.25, 0.75)]
    );
    assert_eq!(tf.unit_distance, None);

    // As control points for a volume whose range is the preset's: x normalized, σ from o,
    // and the o-linear segments refined so the σ-linear TF matches them.
    let n = 64;
    let values: Vec<f64> = (0..n)
        .map(|i| -2.5 + 42.75 * i as f64 / (n - 1) as f64)
        .collect();
    let g = Geometry {
        dims: [n, 1, 1],
        spacing: [0.5, 1.0, 1.0],
        origin: [0.0; 3],
    };
    let v = Volume::from_buffer(Path::new("line"), g, &TypedBuffer::from_f64(values)).unwrap();
    let cp = load_tf(&fixture("paraview_written_preset.json"), &v, Some(1.0)).unwrap();
    let l = v.geometry.longest_side();
    assert_eq!(cp.x[0], 0.0);
    assert_eq!(*cp.x.last().unwrap(), 1.0);
    assert!((cp.sigma.last().unwrap() - (-(0.25f64).ln() * l)).abs() < 1e-9);
    let o = opacity_curve(&tf);
    for j in 0..=4000 {
        let t = j as f64 / 4000.0;
        let ours = sigma_to_opacity(cp.eval(t)[0], 1.0, l);
        let pv = interpolate(&o, v.denormalize(t))[0];
        assert!((ours - pv).abs() <= 0.5 * EXPORT_TOLERANCE + 1e-12, "t={t}");
    }
    assert!(cp.len() > 4, "o-linear segments were refined");
}

#[test]
fn json_midpoints_become_points_and_rescale_maps_range() {
    let text = r#"[{"Name":"m","ColorSpace":"RGB","RGBPoints":[0,0,0,0, 10,1,1,1],
        "Points":[0,0,0.25,0, 10,1,0.5,0]}]"#;
    let tf = from_paraview_json(text, Path::new("m.json")).unwrap();
    assert_eq!(tf.opacity_points, vec![(0.0, 0.0), (2.5, 0.5), (10.0, 1.0)]);
    let r = tf.rescaled(100.0, 300.0);
    assert_eq!(r.data_range(), [100.0, 300.0]);
    assert_eq!(r.opacity_points[1], (150.0, 0.5));
    assert_eq!(r.name, "m", "a moved TF keeps its name");
    // Colours-only XML/CT output of the same TF also works; alpha defaults to opaque.
    let mut colour_only = tf.clone();
    colour_only.opacity_points.clear();
    assert!(!to_paraview_xml(&colour_only).contains(" o=\""));
    assert!(to_visit_ct(&colour_only).contains("255 255 255 255"));
}

#[test]
fn load_tf_extends_clips_and_handles_saturation() {
    let v = volume(); // data range [-3, 40], L = 22, default u = 7/6
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("narrow.json");
    // A preset on [10, 20] inside the volume's range, reaching opacity 1 (σ = ∞ → 255).
    std::fs::write(
        &p,
        r#"[{"Name":"n","RGBPoints":[10,1,0,0, 20,0,0,1],"Points":[10,0,0.5,0, 20,1,0.5,0]}]"#,
    )
    .unwrap();
    let cp = load_tf(&p, &v, None).unwrap();
    let t10 = 13.0 / 43.0;
    assert!(cp.x.iter().any(|&x| (x - t10).abs() < 1e-15));
    assert_eq!(
        cp.eval(0.0),
        cp.eval(t10),
        "constant below the preset's range"
    );
    assert_eq!(cp.eval(1.0)[0], 255.0, "o = 1 reads as the largest density");
    assert_eq!(cp.eval(1.0)[1..], [0.0, 0.0, 1.0]);
    // Saturation must not make the refinement split down to its depth limit.
    assert!(cp.len() < 200, "{} points", cp.len());
    // A preset wider than the volume is cut at the volume's range.
    std::fs::write(
        &p,
        r#"[{"RGBPoints":[-100,0,0,0, 100,1,1,1],"Points":[-100,0,0.5,0, 100,0,0.5,0]}]"#,
    )
    .unwrap();
    let cp = load_tf(&p, &v, None).unwrap();
    assert_eq!((cp.x[0], *cp.x.last().unwrap()), (0.0, 1.0));
    let want = (-3.0 + 100.0) / 200.0;
    assert!((cp.rgb[0][0] - want).abs() < 1e-12, "{:?}", cp.rgb[0]);
}
