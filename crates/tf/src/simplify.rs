//! Export-time simplification (docs/DESIGN.md "Conventions"): ParaView interpolates *opacity*
//! linearly between points while our TF is linear in σ, so the opacity curve o(x) =
//! 1 − exp(−σ(x) u/L) is sampled densely, then points are removed while the piecewise-linear
//! curves stay within a tolerance of the dense ones (Douglas–Peucker on max-abs error).
//!
//! Exported points are also kept [`MIN_GAP`] apart, so that ParaView's lookup tables resolve
//! them (see there).

use super::{sigma_to_opacity, ControlPoints};

/// Max-abs tolerance of exported opacity and colour curves against our TF.
pub const EXPORT_TOLERANCE: f64 = 1e-3;

/// Most samples per control-point segment in the dense curves (bounds work and output size).
const DENSE_SAMPLES: usize = 1024;

/// Normalized width of the ramp that stands for a jump (collapsed control points) when no
/// larger gap is asked for.
const JUMP_WIDTH: f64 = 1e-9;

/// Widest 1D lookup table ParaView's GPU volume mapper can count on: VTK
/// (`vtkOpenGLVolumeLookupTable`) sizes the opacity and colour tables as the next power of
/// two ≥ ceil(range / smallest gap between points), at least 1024, and past the GPU's largest
/// texture it warns ("falling back to maximum allowed") and uses that. 16384 is the limit
/// ParaView 5.11 reports with Mesa (its warning names it); a GPU with a larger one only
/// leaves room to spare.
const PARAVIEW_TABLE_SIZE: usize = 16384;

/// Smallest gap between exported points, as a fraction of the TF's range: 1/16000 keeps
/// ceil(range / gap) ≤ 16384 (the widest table ParaView's GPU volume mapper can count on) with a 2 % margin for the rounding of
/// positions into data units. Finer detail is lost in ParaView's table anyway.
pub const MIN_GAP: f64 = 1.0 / 16000.0;

// The margin above, checked when compiling.
const _: () = assert!(1.0 / MIN_GAP <= 0.98 * PARAVIEW_TABLE_SIZE as f64);

/// The TF's opacity and colour sampled densely, at normalized positions `x` (ascending,
/// including every control point).
#[derive(Clone, Debug, Default, PartialEq)]
struct DenseCurves {
    x: Vec<f64>,
    opacity: Vec<[f64; 1]>,
    rgb: Vec<[f64; 3]>,
}

impl DenseCurves {
    fn push(&mut self, x: f64, opacity: f64, rgb: [f64; 3]) {
        self.x.push(x);
        self.opacity.push([opacity]);
        self.rgb.push(rgb);
    }

    fn pop(&mut self) {
        self.x.pop();
        self.opacity.pop();
        self.rgb.pop();
    }

    /// Append a point at least `gap` after the last one. A closer point (a jump: repeated x,
    /// or control points nearly collapsed) keeps its value at its x; the last point moves left
    /// to `x − gap`, or is dropped if that is too close to the one before it (then the one
    /// before is tried). The first point stays at the range's start and takes the new value.
    /// So the curve changes only within about two gaps of detail narrower than `gap`.
    fn push_spaced(&mut self, x: f64, opacity: f64, rgb: [f64; 3], gap: f64) {
        loop {
            let n = self.x.len();
            if n == 0 || x - self.x[n - 1] >= gap {
                return self.push(x, opacity, rgb);
            }
            if n == 1 {
                self.opacity[0] = [opacity];
                self.rgb[0] = rgb;
                return;
            }
            let moved = x - gap;
            if moved - self.x[n - 2] >= gap {
                self.x[n - 1] = moved;
                return self.push(x, opacity, rgb);
            }
            self.pop();
        }
    }
}

/// Samples for one control-point segment of length `len` from density `s0` to `s1`: enough
/// to keep linear interpolation within `tol / 4` (see [`dense_curves`]), at most
/// [`DENSE_SAMPLES`] and at most one per `gap`.
fn segment_samples(len: f64, s0: f64, s1: f64, ratio: f64, tol: f64, gap: f64) -> usize {
    let slope = ratio * (s1 - s0) / len;
    let curvature = slope * slope * (-ratio * s0.min(s1)).exp();
    let needed = (len * (curvature / (2.0 * tol)).sqrt()).ceil() as usize;
    let room = (len / gap).floor() as usize;
    needed.min(DENSE_SAMPLES).min(room).max(1)
}

/// Sample opacity and colour for export; `ratio` = u / L; consecutive samples are at least
/// `min_gap` apart (at least [`JUMP_WIDTH`]: a jump is a steep ramp, as ParaView replaces a
/// point at an existing x).
///
/// Between two control points σ is linear, so o'' = −(ratio·σ')² exp(−ratio·σ) and linear
/// interpolation between samples h apart errs by at most h²/8 · max|o''|. Each segment gets
/// enough samples to keep that below `tol / 4` (capped at [`DENSE_SAMPLES`], and at one per
/// `min_gap`, which only a segment steeper than ParaView's table resolves reaches), leaving
/// 3/4 of the budget to the simplification. Colours are linear on segments: their samples
/// are exact.
fn dense_curves(cp: &ControlPoints, ratio: f64, tol: f64, min_gap: f64) -> DenseCurves {
    // A hair wider than asked, so that rounding in `x − gap` and in the sample positions
    // (≤ 1e-16 for x ≤ 1) never leaves two points less than `min_gap` apart.
    let gap = min_gap.max(JUMP_WIDTH) * (1.0 + 1e-9);
    let mut out = DenseCurves::default();
    let mut push = |x: f64, v: [f64; 4]| {
        let o = sigma_to_opacity(v[0], ratio, 1.0);
        out.push_spaced(x, o, [v[1], v[2], v[3]], gap);
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
        let m = segment_samples(len, cp.sigma[i], cp.sigma[i + 1], ratio, tol, gap);
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

/// Polylines of up to this many points are simplified whole (Douglas–Peucker's worst case,
/// every split peeling one point, is then n²/2 = 1.3·10⁸ point checks); export curves spaced
/// by [`MIN_GAP`] always are.
const WHOLE: usize = 16384;

/// Longer polylines (a preset file's 10⁶ points) are simplified in pieces of this many points
/// whose ends are kept: at most `PIECE`/2 checks per point, so linear time, for a few more
/// points kept than the whole curve would need.
const PIECE: usize = 1024;

/// Indices of the points to keep so that the polyline through them stays within `tol` (max
/// abs, every channel) of the polyline through all points; the first and last are kept.
///
/// Douglas–Peucker: both polylines are linear between the dense points, so the error is
/// largest at one of them, and checking the dense points checks the whole curve. Past
/// 16384 points, piece by piece (1024 points a piece), which bounds the time by 512 n.
pub fn simplify_polyline<const C: usize>(x: &[f64], v: &[[f64; C]], tol: f64) -> Vec<usize> {
    let n = x.len();
    if n <= 2 {
        return (0..n).collect();
    }
    let mut keep = vec![false; n];
    let pieces: Vec<(usize, usize)> = if n <= WHOLE {
        vec![(0, n - 1)]
    } else {
        (0..n - 1)
            .step_by(PIECE - 1)
            .map(|i| (i, (i + PIECE - 1).min(n - 1)))
            .collect()
    };
    for &(i, j) in &pieces {
        keep[i] = true;
        keep[j] = true;
    }
    let mut stack = pieces;
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
    /// (x, opacity) points.
    pub opacity: Vec<(f64, f64)>,
    /// (x, rgb) points.
    pub rgb: Vec<(f64, [f64; 3])>,
}

/// Dense sampling then simplification, each with its share of `tol` (see `dense_curves`):
/// the result is within `tol` of the true opacity 1 − exp(−σ(x)·ratio) and colour everywhere
/// except near detail narrower than `min_gap` (there it follows the true curve to within a
/// few gaps). The kept points are dense samples, so no two of either curve, nor of both
/// together, are closer than `min_gap` (export: [`MIN_GAP`]; 0 for the tolerance alone).
pub fn simplified_curves(
    cp: &ControlPoints,
    ratio: f64,
    tol: f64,
    min_gap: f64,
) -> SimplifiedCurves {
    let d = dense_curves(cp, ratio, tol, min_gap);
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
        // The table spacing changes nothing here: no detail is narrower than MIN_GAP.
        let cases = [1.0 / 63.0, 1.0 / 10.0, 1.0].map(|r| [(r, 0.0), (r, MIN_GAP)]);
        for (ratio, gap) in cases.into_iter().flatten() {
            let d = dense_curves(&cp, ratio, EXPORT_TOLERANCE, gap);
            let s = simplified_curves(&cp, ratio, EXPORT_TOLERANCE, gap);
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

    /// A jump at 0.3 followed by a fall from 255 to 0 within 5e-4.
    fn steep_and_collapsed() -> ControlPoints {
        ControlPoints {
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
        }
    }

    #[test]
    fn steep_and_collapsed_tfs_stay_within_tolerance() {
        let cp = steep_and_collapsed();
        let ratio = 1.0 / 63.0;
        // The tolerance alone (no table spacing; that is the next test).
        let s = simplified_curves(&cp, ratio, EXPORT_TOLERANCE, 0.0);
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

    /// VTK's table width for points whose smallest gap is `gap` over a range of 1
    /// (vtkOpenGLVolumeLookupTable: next power of two of ceil(range / gap), at least 1024).
    fn vtk_table_width(gap: f64) -> usize {
        ((1.0 / gap).ceil() as usize).next_power_of_two().max(1024)
    }

    fn smallest_gap(x: impl IntoIterator<Item = f64>) -> f64 {
        let mut x: Vec<f64> = x.into_iter().collect();
        x.sort_by(f64::total_cmp);
        x.windows(2).map(|w| w[1] - w[0]).fold(f64::MAX, f64::min)
    }

    /// Check `s` against the true opacity of `cp`: within `EXPORT_TOLERANCE` outside the
    /// `narrow` intervals (detail finer than the table), and everywhere between the least and
    /// largest true value within 3 gaps (the curve is only smeared by the spacing).
    fn assert_follows(cp: &ControlPoints, s: &SimplifiedCurves, ratio: f64, narrow: &[[f64; 2]]) {
        let o: Vec<(f64, [f64; 1])> = s.opacity.iter().map(|&(x, o)| (x, [o])).collect();
        let n = 400_000; // grid step 2.5e-6 = MIN_GAP / 25
        let truth: Vec<f64> = (0..=n)
            .map(|j| sigma_to_opacity(cp.eval(j as f64 / n as f64)[0], ratio, 1.0))
            .collect();
        let reach = (3.0 * MIN_GAP * n as f64).ceil() as usize;
        let tol = EXPORT_TOLERANCE;
        for (j, want) in truth.iter().enumerate() {
            let t = j as f64 / n as f64;
            let got = interpolate(&o, t)[0];
            let near = &truth[j.saturating_sub(reach)..(j + reach + 1).min(n + 1)];
            let lo = near.iter().fold(f64::MAX, |a, &b| a.min(b));
            let hi = near.iter().fold(f64::MIN, |a, &b| a.max(b));
            assert!(
                got >= lo - tol && got <= hi + tol,
                "t={t}: {got} not in [{lo}, {hi}]"
            );
            let excused = narrow
                .iter()
                .any(|w| t > w[0] - 3.0 * MIN_GAP && t < w[1] + 3.0 * MIN_GAP);
            assert!(
                excused || (got - want).abs() <= tol,
                "t={t}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn exported_points_are_resolvable_by_paraview_tables() {
        let colours = |n: usize| (0..n).map(|i| [i as f64 / n as f64, 0.5, 1.0]).collect();
        let near = |x: Vec<f64>, sigma: Vec<f64>| ControlPoints {
            rgb: colours(x.len()),
            x,
            sigma,
        };
        // (TF, its detail narrower than the table)
        let cases = [
            (steep_and_collapsed(), vec![[0.3, 0.3005]]),
            // Two points 1e-6 apart.
            (
                near(
                    vec![0.0, 0.5, 0.5 + 1e-6, 1.0],
                    vec![0.0, 0.0, 200.0, 200.0],
                ),
                vec![[0.5, 0.5]],
            ),
            // Jumps at both ends, a cluster of points inside one gap, one just over a gap.
            (
                near(
                    vec![
                        0.0,
                        0.0,
                        0.2,
                        0.2 + 2e-5,
                        0.2 + 4e-5,
                        0.6,
                        0.6 + 7e-5,
                        1.0,
                        1.0,
                    ],
                    vec![0.0, 90.0, 10.0, 250.0, 0.0, 40.0, 180.0, 20.0, 255.0],
                ),
                vec![[0.0, 0.0], [0.2, 0.2 + 4e-5], [0.6, 0.6 + 7e-5], [1.0, 1.0]],
            ),
        ];
        for (cp, narrow) in &cases {
            for ratio in [1.0 / 63.0, 1.0 / 10.0] {
                let s = simplified_curves(cp, ratio, EXPORT_TOLERANCE, MIN_GAP);
                let ox = s.opacity.iter().map(|p| p.0);
                let cx = s.rgb.iter().map(|p| p.0);
                for (what, gap) in [
                    ("opacity", smallest_gap(ox.clone())),
                    ("colour", smallest_gap(cx.clone())),
                ] {
                    assert!(gap >= MIN_GAP, "{what} points {gap} apart");
                    assert!(vtk_table_width(gap) <= PARAVIEW_TABLE_SIZE, "{what}: {gap}");
                }
                // Formats that merge both curves (XML, .ct) keep the spacing too.
                let mut both: Vec<f64> = ox.chain(cx).collect();
                both.sort_by(f64::total_cmp);
                both.dedup();
                assert!(smallest_gap(both) >= MIN_GAP);
                assert_eq!((s.opacity[0].0, s.opacity.last().unwrap().0), (0.0, 1.0));
                assert_follows(cp, &s, ratio, narrow);
            }
        }
        // Without the spacing (the export before), the steep segment of the second case is
        // sampled 1.4e-8 apart: a table of 2^27 entries, far past what ParaView gets.
        let s = simplified_curves(&cases[1].0, 1.0 / 63.0, EXPORT_TOLERANCE, 0.0);
        let gap = smallest_gap(s.opacity.iter().map(|p| p.0));
        assert_eq!(vtk_table_width(gap), 1 << 27);
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

    /// A polyline of 10⁶ points (a hostile preset's) in linear time: every point of an
    /// opacity alternating 0, 1 is needed (Douglas–Peucker on the whole would peel them one by
    /// one, 5·10¹¹ checks), and a smooth curve of as many points keeps few and stays within
    /// the tolerance at every point.
    #[test]
    fn a_million_points_simplify_in_linear_time() {
        let n = 1_000_000;
        let x: Vec<f64> = (0..n).map(|i| i as f64 / (n - 1) as f64).collect();
        let alternating: Vec<[f64; 1]> = (0..n).map(|i| [(i % 2) as f64]).collect();
        assert_eq!(simplify_polyline(&x, &alternating, 1e-3).len(), n);
        let smooth: Vec<[f64; 1]> = x.iter().map(|&t| [(6.0 * t).sin()]).collect();
        let kept = simplify_polyline(&x, &smooth, 1e-3);
        assert!(kept.len() < 2_000, "{} points kept", kept.len());
        let curve: Vec<(f64, [f64; 1])> = kept.iter().map(|&i| (x[i], smooth[i])).collect();
        for (t, v) in x.iter().zip(&smooth).step_by(97) {
            let e = (crate::interpolate(&curve, *t)[0] - v[0]).abs();
            assert!(e <= 1e-3, "error {e} at {t}");
        }
    }
}
