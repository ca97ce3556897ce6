//! Export-time simplification (DESIGN.md "Conventions"): ParaView interpolates *opacity*
//! linearly between points while our TF is linear in σ, so the opacity curve o(x) =
//! 1 − exp(−σ(x) u/L) is sampled densely, then points are removed while the piecewise-linear
//! curves stay within a tolerance of the dense ones (Douglas–Peucker on max-abs error).

use super::{sigma_to_opacity, ControlPoints};

/// Max-abs tolerance of exported opacity and colour curves against our TF.
pub const EXPORT_TOLERANCE: f64 = 1e-3;

/// Most samples per control-point segment in the dense curves (bounds work and output size).
pub const DENSE_SAMPLES: usize = 1024;

/// Normalized width of the ramp that stands for a jump (collapsed control points) in exports.
pub const JUMP_WIDTH: f64 = 1e-9;

/// The TF's opacity and colour sampled densely, at normalized positions `x` (ascending,
/// including every control point).
#[derive(Clone, Debug, PartialEq)]
pub struct DenseCurves {
    pub x: Vec<f64>,
    pub opacity: Vec<[f64; 1]>,
    pub rgb: Vec<[f64; 3]>,
}

/// Sample opacity and colour for export; `ratio` = u / L.
///
/// Between two control points σ is linear, so o'' = −(ratio·σ')² exp(−ratio·σ) and linear
/// interpolation between samples h apart errs by at most h²/8 · max|o''|. Each segment gets
/// enough samples to keep that below `tol / 4` (capped at [`DENSE_SAMPLES`]), leaving 3/4 of
/// the budget to the simplification. Colours are linear on segments: their samples are exact.
pub fn dense_curves(cp: &ControlPoints, ratio: f64, tol: f64) -> DenseCurves {
    let mut out = DenseCurves {
        x: Vec::new(),
        opacity: Vec::new(),
        rgb: Vec::new(),
    };
    let mut push = |x: f64, v: [f64; 4]| {
        // A repeated position (a jump) cannot be written as is: ParaView replaces a point
        // at an existing x. The right-hand value stays at x (as `eval` has it) and the
        // left-hand one moves JUMP_WIDTH to the left, unless that would pass the point
        // before it (then it is dropped: a jump narrower than the sampling).
        if out.x.last() == Some(&x) {
            let n = out.x.len();
            let moved = x - JUMP_WIDTH;
            if n >= 2 && out.x[n - 2] < moved {
                out.x[n - 1] = moved;
            } else {
                out.x.pop();
                out.opacity.pop();
                out.rgb.pop();
            }
        }
        out.x.push(x);
        out.opacity.push([sigma_to_opacity(v[0], ratio, 1.0)]);
        out.rgb.push([v[1], v[2], v[3]]);
    };
    for i in 0..cp.len() {
        push(cp.x[i], cp.at(i));
        if i + 1 == cp.len() {
            break;
        }
        let (x0, x1) = (cp.x[i], cp.x[i + 1]);
        let len = x1 - x0;
        if len <= 0.0 {
            continue;
        }
        let (s0, s1) = (cp.sigma[i], cp.sigma[i + 1]);
        let slope = ratio * (s1 - s0) / len;
        let curvature = slope * slope * (-ratio * s0.min(s1)).exp();
        let needed = (len * (curvature / (2.0 * tol)).sqrt()).ceil();
        let m = (needed as usize).clamp(1, DENSE_SAMPLES);
        let (a, b) = (cp.at(i), cp.at(i + 1));
        for j in 1..m {
            let w = j as f64 / m as f64;
            push(
                x0 + w * len,
                std::array::from_fn(|c| a[c] + w * (b[c] - a[c])),
            );
        }
    }
    out
}

/// Indices of the points to keep so that the polyline through them stays within `tol` (max
/// abs, every channel) of the polyline through all points; the first and last are kept.
///
/// Douglas–Peucker: both polylines are linear between the dense points, so the error is
/// largest at one of them, and checking the dense points checks the whole curve.
pub fn simplify_polyline<const C: usize>(x: &[f64], v: &[[f64; C]], tol: f64) -> Vec<usize> {
    let n = x.len();
    if n <= 2 {
        return (0..n).collect();
    }
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    let mut stack = vec![(0, n - 1)];
    while let Some((i, j)) = stack.pop() {
        let (mut worst, mut at) = (0.0, 0);
        for m in i + 1..j {
            let w = (x[m] - x[i]) / (x[j] - x[i]);
            for ((a, b), vm) in v[i].iter().zip(&v[j]).zip(&v[m]) {
                let e = (a + w * (b - a) - vm).abs();
                if e > worst {
                    worst = e;
                    at = m;
                }
            }
        }
        if worst > tol {
            keep[at] = true;
            stack.push((i, at));
            stack.push((at, j));
        }
    }
    (0..n).filter(|&i| keep[i]).collect()
}

/// Simplified opacity and colour curves of `cp` for export, in normalized x.
#[derive(Clone, Debug, PartialEq)]
pub struct SimplifiedCurves {
    pub opacity: Vec<(f64, f64)>,
    pub rgb: Vec<(f64, [f64; 3])>,
}

/// Dense sampling then simplification, each with its share of `tol` (see [`dense_curves`]):
/// the result is within `tol` of the true opacity 1 − exp(−σ(x)·ratio) and colour everywhere.
pub fn simplified_curves(cp: &ControlPoints, ratio: f64, tol: f64) -> SimplifiedCurves {
    let d = dense_curves(cp, ratio, tol);
    let simplify_tol = 0.75 * tol;
    let o = simplify_polyline(&d.x, &d.opacity, simplify_tol);
    let c = simplify_polyline(&d.x, &d.rgb, simplify_tol);
    SimplifiedCurves {
        opacity: o.iter().map(|&i| (d.x[i], d.opacity[i][0])).collect(),
        rgb: c.iter().map(|&i| (d.x[i], d.rgb[i])).collect(),
    }
}

/// Value at `t` of a piecewise-linear curve given by ascending points (constant outside).
pub fn interpolate<const C: usize>(points: &[(f64, [f64; C])], t: f64) -> [f64; C] {
    let k = points.partition_point(|p| p.0 <= t);
    if k == 0 {
        return points[0].1;
    }
    if k >= points.len() {
        return points[points.len() - 1].1;
    }
    let ((x0, a), (x1, b)) = (points[k - 1], points[k]);
    let w = if x1 > x0 { (t - x0) / (x1 - x0) } else { 1.0 };
    std::array::from_fn(|c| a[c] + w * (b[c] - a[c]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Max error of the simplified curves against the true TF on a grid finer than any
    /// dense sampling, so the check does not share the code's own sample positions.
    fn max_error(cp: &ControlPoints, s: &SimplifiedCurves, ratio: f64) -> (f64, f64) {
        let o: Vec<(f64, [f64; 1])> = s.opacity.iter().map(|&(x, o)| (x, [o])).collect();
        let (mut eo, mut ec) = (0.0f64, 0.0f64);
        let n = 200_000;
        for j in 0..=n {
            let t = j as f64 / n as f64;
            let v = cp.eval(t);
            eo = eo.max((interpolate(&o, t)[0] - sigma_to_opacity(v[0], ratio, 1.0)).abs());
            let c = interpolate(&s.rgb, t);
            for k in 0..3 {
                ec = ec.max((c[k] - v[k + 1]).abs());
            }
        }
        (eo, ec)
    }

    #[test]
    fn smooth_tf_is_simplified_within_tolerance() {
        let k = 48;
        let sigma: Vec<f64> = (0..k)
            .map(|i| 127.5 * (1.0 + (i as f64 * 0.3).sin()))
            .collect();
        let rgb: Vec<[f64; 3]> = (0..k)
            .map(|i| {
                let t = i as f64 / (k - 1) as f64;
                [t, 1.0 - t, 0.5 + 0.4 * (t * 9.0).sin()]
            })
            .collect();
        let cp = ControlPoints::evenly_spaced(sigma, rgb).unwrap();
        for ratio in [1.0 / 63.0, 1.0 / 10.0, 1.0] {
            let d = dense_curves(&cp, ratio, EXPORT_TOLERANCE);
            let s = simplified_curves(&cp, ratio, EXPORT_TOLERANCE);
            let (eo, ec) = max_error(&cp, &s, ratio);
            assert!(eo <= EXPORT_TOLERANCE, "ratio {ratio}: opacity error {eo}");
            assert!(ec <= EXPORT_TOLERANCE, "ratio {ratio}: colour error {ec}");
            assert!(
                s.opacity.len() < d.x.len(),
                "{} !< {}",
                s.opacity.len(),
                d.x.len()
            );
            // r and g are linear in x: only the blue channel's kinks need points.
            assert!(s.rgb.len() < k, "{} colour points", s.rgb.len());
            assert_eq!(s.opacity[0].0, 0.0);
            assert_eq!(s.opacity.last().unwrap().0, 1.0);
        }
    }

    #[test]
    fn steep_and_collapsed_tfs_stay_within_tolerance() {
        let cp = ControlPoints {
            x: vec![0.0, 0.3, 0.3, 0.3005, 0.7, 1.0],
            sigma: vec![0.0, 0.0, 255.0, 0.0, 255.0, 255.0],
            rgb: vec![
                [0.0; 3],
                [1.0; 3],
                [0.0, 1.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.2; 3],
                [0.9; 3],
            ],
        };
        let ratio = 1.0 / 63.0;
        let s = simplified_curves(&cp, ratio, EXPORT_TOLERANCE);
        assert!(
            s.opacity.windows(2).all(|w| w[1].0 > w[0].0),
            "strictly ascending x"
        );
        let o: Vec<(f64, [f64; 1])> = s.opacity.iter().map(|&(x, o)| (x, [o])).collect();
        // Away from the jump at 0.3 (which ParaView cannot represent exactly) the curve holds.
        for j in 0..=100_000 {
            let t = j as f64 / 100_000.0;
            if (t - 0.3).abs() < 1e-9 {
                continue;
            }
            let want = sigma_to_opacity(cp.eval(t)[0], ratio, 1.0);
            assert!(
                (interpolate(&o, t)[0] - want).abs() <= EXPORT_TOLERANCE,
                "t={t}"
            );
        }
    }

    #[test]
    fn douglas_peucker_keeps_only_needed_points() {
        let x: Vec<f64> = (0..11).map(|i| i as f64 / 10.0).collect();
        let v: Vec<[f64; 1]> = x
            .iter()
            .map(|&t| [if t <= 0.5 { t } else { 1.0 - t }])
            .collect();
        assert_eq!(simplify_polyline(&x, &v, 1e-9), vec![0, 5, 10]);
    }
}
