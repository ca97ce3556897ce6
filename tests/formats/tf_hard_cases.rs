//! Hard cases through TF → export → load: constant and NaN-holding volumes, saturated
//! densities, collapsed control points, extreme parameters. Everything stays finite.

use std::path::Path;

use t2tf::formats::{load_tf, to_paraview_json, write_tf, ExportTf};
use t2tf::tf::{
    default_unit_distance, sigma_to_opacity, ControlPoints, LutGrad, TfParams, EXPORT_TOLERANCE,
};
use t2tf::volume::{Geometry, TypedBuffer, Volume};

fn vol(values: Vec<f64>, dims: [usize; 3]) -> Volume {
    let g = Geometry {
        dims,
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    Volume::from_buffer(Path::new("hard"), g, &TypedBuffer::from_f64(values)).unwrap()
}

fn all_finite(cp: &ControlPoints) -> bool {
    cp.x.iter()
        .chain(&cp.sigma)
        .chain(cp.rgb.iter().flatten())
        .all(|v| v.is_finite())
}

/// In tiny boxes (L of one or a few voxels) a density of 100 is opaque within one voxel step:
/// o = 1 − e^{−100} is 1.0 in f64 and reads back as σ = 255. What must survive is the
/// opacity per unit distance, within the export tolerance.
fn assert_opacity_close(a: &ControlPoints, b: &ControlPoints, v: &Volume) {
    let (u, l) = (
        default_unit_distance(&v.geometry),
        v.geometry.longest_side(),
    );
    for j in 0..=1000 {
        let t = j as f64 / 1000.0;
        let (oa, ob) = (
            sigma_to_opacity(a.eval(t)[0], u, l),
            sigma_to_opacity(b.eval(t)[0], u, l),
        );
        assert!(
            (oa - ob).abs() <= 1.5 * EXPORT_TOLERANCE,
            "t={t}: {oa} vs {ob}"
        );
    }
}

fn round_trip(cp: &ControlPoints, v: &Volume) -> ControlPoints {
    let tf = ExportTf::from_control_points("hard", cp, v, None);
    assert!(to_paraview_json(&tf).len() > 10);
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("h.json");
    write_tf(&p, &tf).unwrap();
    let back = load_tf(&p, v, None).unwrap();
    back.validate().unwrap();
    assert!(all_finite(&back));
    back
}

#[test]
fn constant_volume_exports_over_its_widened_range() {
    let v = vol(vec![7.0; 8], [2, 2, 2]);
    let cp = ControlPoints::evenly_spaced(vec![0.0, 100.0, 255.0], vec![[0.5; 3]; 3]).unwrap();
    let tf = ExportTf::from_control_points("c", &cp, &v, None);
    assert_eq!(
        tf.data_range(),
        [6.5, 7.5],
        "norm_range, not an empty range"
    );
    let back = round_trip(&cp, &v);
    assert_opacity_close(&cp, &back, &v);
}

#[test]
fn nan_voxels_and_huge_ranges_stay_finite() {
    let mut values: Vec<f64> = (0..64).map(|i| i as f64 * 1e300 / 64.0 - 5e299).collect();
    values[3] = f64::NAN;
    values[9] = f64::INFINITY;
    let v = vol(values, [4, 4, 4]);
    let cp = ControlPoints::evenly_spaced(vec![10.0, 200.0], vec![[0.1; 3], [0.9; 3]]).unwrap();
    let back = round_trip(&cp, &v);
    assert_opacity_close(&cp, &back, &v);
}

#[test]
fn saturated_density_round_trips_near_255() {
    let v = vol((0..27).map(|i| i as f64).collect(), [3, 3, 3]);
    let cp = ControlPoints::evenly_spaced(vec![255.0; 4], vec![[1.0; 3]; 4]).unwrap();
    // u = mean spacing = 1, L = 2: o = 1 − e^{−127.5} rounds to 1.0 in f64; reading 1.0
    // back gives σ = 255 by the clamp, not infinity.
    let back = round_trip(&cp, &v);
    assert!(back.sigma.iter().all(|&s| s == 255.0), "{:?}", back.sigma);
}

#[test]
fn collapsed_points_and_extreme_params_export() {
    let v = vol((0..27).map(|i| i as f64).collect(), [3, 3, 3]);
    let p = TfParams {
        spacing: vec![-1e6, 40.0, -1e6, 0.0],
        density: vec![1e9, -1e9, 3.0, 0.0, -2.0],
        colour: vec![[50.0, -50.0, 0.0]; 5],
    };
    let cp = p.control_points();
    cp.validate().unwrap();
    let n = 256;
    let g = cp.lut_backward(
        n,
        &LutGrad {
            entries: vec![[1.0; 4]; n],
        },
    );
    let pg = p.backward(&g);
    assert!(pg.to_flat().iter().all(|v| v.is_finite()));
    round_trip(&cp, &v);
    // Points collapsed exactly (not through the parameters) export too.
    let cp = ControlPoints {
        x: vec![0.0, 0.0, 0.5, 0.5, 1.0, 1.0],
        sigma: vec![0.0, 50.0, 255.0, 0.0, 10.0, 255.0],
        rgb: vec![[0.5; 3]; 6],
    };
    round_trip(&cp, &v);
}
