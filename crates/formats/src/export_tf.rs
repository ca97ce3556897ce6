//! [`ExportTf`]: a TF in data units, the common form of every file format, with conversions
//! from and to the renderer's normalized [`ControlPoints`].

use std::path::Path;

use sha2::{Digest, Sha256};

use super::FormatError;
use t2tf_tf::{
    default_unit_distance, interpolate, opacity_to_sigma_within, sigma_to_opacity,
    simplified_curves, ControlPoints, EXPORT_TOLERANCE, MIN_GAP, SIGMA_MAX,
};
use t2tf_volume::Volume;

/// A transfer function in data units, as ParaView and VisIt files hold it.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportTf {
    /// Preset name (ParaView's preset list shows it).
    pub name: String,
    /// (data value, rgb in [0, 1]), ascending data values.
    pub rgb_points: Vec<(f64, [f64; 3])>,
    /// (data value, opacity in [0, 1]), ascending; empty for a colour-only file.
    pub opacity_points: Vec<(f64, f64)>,
    /// ParaView's ScalarOpacityUnitDistance the opacities are meant for (world units).
    pub unit_distance: Option<f64>,
}

/// Length of the content hash appended to preset names (hex digits).
const HASH_LEN: usize = 8;

impl ExportTf {
    /// Export `cp` for `volume`: opacity o = 1 − exp(−σ u / L) sampled densely and simplified
    /// to within [`EXPORT_TOLERANCE`] (docs/DESIGN.md "Conventions"), points at least
    /// `tf::MIN_GAP` (1/16000) of the range apart (so ParaView's lookup tables resolve them),
    /// positions denormalized to data values.
    /// `unit_distance` defaults to [`default_unit_distance`]. The name gets a content hash.
    pub fn from_control_points(
        name: &str,
        cp: &ControlPoints,
        volume: &Volume,
        unit_distance: Option<f64>,
    ) -> ExportTf {
        let u = unit_distance.unwrap_or_else(|| default_unit_distance(&volume.geometry));
        let ratio = u / volume.geometry.longest_side();
        let s = simplified_curves(cp, ratio, EXPORT_TOLERANCE, MIN_GAP);
        let mut tf = ExportTf {
            name: name.to_string(),
            rgb_points: s
                .rgb
                .iter()
                .map(|&(x, c)| (volume.denormalize(x), c))
                .collect(),
            opacity_points: s
                .opacity
                .iter()
                .map(|&(x, o)| (volume.denormalize(x), o))
                .collect(),
            unit_distance: Some(u),
        };
        tf.name = tf.unique_name();
        tf
    }

    /// `name` with a short hash of the content appended (replacing an earlier one), so that a
    /// changed TF never reuses a preset name (re-importing a name is fragile in ParaView 5.10+).
    pub fn unique_name(&self) -> String {
        let mut h = Sha256::new();
        for (x, c) in &self.rgb_points {
            h.update(x.to_le_bytes());
            c.iter().for_each(|v| h.update(v.to_le_bytes()));
        }
        h.update(b"|");
        for (x, o) in &self.opacity_points {
            h.update(x.to_le_bytes());
            h.update(o.to_le_bytes());
        }
        if let Some(u) = self.unit_distance {
            h.update(u.to_le_bytes());
        }
        let digest = h.finalize();
        let hex: String = digest
            .iter()
            .take(HASH_LEN / 2)
            .map(|b| format!("{b:02x}"))
            .collect();
        format!("{}-{hex}", base_name(&self.name))
    }

    /// `n` ≥ 2 evenly spaced data values over [`ExportTf::data_range`] and the colour and
    /// ParaView opacity there (RGBA; opacity 1 for a colour-only map), as the file's curves
    /// interpolate linearly: what a plotting or volume tool (PyVista) takes as a table.
    pub fn sample(&self, n: usize) -> (Vec<f64>, Vec<[f64; 4]>) {
        let [lo, hi] = self.data_range();
        let opacity: Vec<(f64, [f64; 1])> =
            self.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
        let values: Vec<f64> = (0..n)
            .map(|i| lo + (hi - lo) * i as f64 / (n.max(2) - 1) as f64)
            .collect();
        let rgba = values
            .iter()
            .map(|&x| {
                let [r, g, b] = if self.rgb_points.is_empty() {
                    [1.0; 3]
                } else {
                    interpolate(&self.rgb_points, x)
                };
                let o = if opacity.is_empty() {
                    1.0
                } else {
                    interpolate(&opacity, x)[0]
                };
                [r, g, b, o]
            })
            .collect();
        (values, rgba)
    }

    /// Data range covered by the points: [first x, last x] over both curves.
    pub fn data_range(&self) -> [f64; 2] {
        let xs = self
            .rgb_points
            .iter()
            .map(|p| p.0)
            .chain(self.opacity_points.iter().map(|p| p.0));
        let lo = xs.clone().fold(f64::INFINITY, f64::min);
        let hi = xs.fold(f64::NEG_INFINITY, f64::max);
        [lo, hi]
    }

    /// Map the data range linearly onto [min, max] (`t2tf convert --rescale`), keeping the
    /// name: the preset is the user's, and a caller that wants a name of its own for the moved
    /// TF gives one (or asks [`ExportTf::unique_name`]).
    pub fn rescaled(&self, min: f64, max: f64) -> ExportTf {
        let [lo, hi] = self.data_range();
        let map = |x: f64| {
            if hi > lo {
                min + (x - lo) / (hi - lo) * (max - min)
            } else {
                min
            }
        };
        ExportTf {
            name: self.name.clone(),
            rgb_points: self.rgb_points.iter().map(|&(x, c)| (map(x), c)).collect(),
            opacity_points: self
                .opacity_points
                .iter()
                .map(|&(x, o)| (map(x), o))
                .collect(),
            unit_distance: self.unit_distance,
        }
    }

    /// The checks every reader applies: at least one colour point, finite ascending x,
    /// colours and opacities in [0, 1], a positive unit distance.
    pub fn validate(&self, path: &Path) -> Result<(), FormatError> {
        let err = |m: String| Err(FormatError::file(path, m));
        if self.rgb_points.is_empty() {
            return err("has no colour points".into());
        }
        let check_x = |what: &str, xs: &mut dyn Iterator<Item = f64>| {
            let mut prev = f64::NEG_INFINITY;
            for (i, x) in xs.enumerate() {
                if !x.is_finite() {
                    return Err(FormatError::file(
                        path,
                        format!("{what} {i}: x = {x} is not finite"),
                    ));
                }
                if x < prev {
                    return Err(FormatError::file(
                        path,
                        format!("{what} {i}: x = {x} is below the previous point's {prev}"),
                    ));
                }
                prev = x;
            }
            Ok(())
        };
        check_x("colour point", &mut self.rgb_points.iter().map(|p| p.0))?;
        check_x(
            "opacity point",
            &mut self.opacity_points.iter().map(|p| p.0),
        )?;
        for (i, (_, c)) in self.rgb_points.iter().enumerate() {
            if c.iter().any(|v| !(0.0..=1.0).contains(v)) {
                return err(format!("colour point {i}: rgb {c:?} is not in [0, 1]"));
            }
        }
        for (i, (_, o)) in self.opacity_points.iter().enumerate() {
            if !(0.0..=1.0).contains(o) {
                return err(format!("opacity point {i}: opacity {o} is not in [0, 1]"));
            }
        }
        if let Some(u) = self.unit_distance {
            if !(u.is_finite() && u > 0.0) {
                return err(format!("unit distance {u} is not a positive number"));
            }
        }
        Ok(())
    }

    /// Control points in `volume`'s normalized units for the renderer.
    ///
    /// σ = −ln(1 − o) · L / u with u = `unit_distance`, else the file's, else the default.
    /// Between file points ParaView interpolates o linearly while the renderer interpolates
    /// σ linearly; where the two differ by more than half the export tolerance, points are
    /// inserted (bisection) so the renderer sees what ParaView shows. Outside the file's
    /// range the end values continue (ParaView clamps the same way); parts outside the
    /// volume's range are cut off.
    pub fn to_control_points(
        &self,
        path: &Path,
        volume: &Volume,
        unit_distance: Option<f64>,
    ) -> Result<ControlPoints, FormatError> {
        self.to_control_points_within(path, volume, unit_distance, SIGMA_MAX)
    }

    /// [`ExportTf::to_control_points`] with densities up to `sigma_max` instead of the
    /// paper's 255 (a refine that starts from a denser TF).
    pub fn to_control_points_within(
        &self,
        path: &Path,
        volume: &Volume,
        unit_distance: Option<f64>,
        sigma_max: f64,
    ) -> Result<ControlPoints, FormatError> {
        self.validate(path)?;
        if self.opacity_points.is_empty() {
            return Err(FormatError::file(
                path,
                "has no opacity points (a colour-only map cannot be rendered)",
            ));
        }
        let u = unit_distance
            .or(self.unit_distance)
            .unwrap_or_else(|| default_unit_distance(&volume.geometry));
        if !(u.is_finite() && u > 0.0) {
            return Err(FormatError::file(
                path,
                format!("unit distance {u} is not positive"),
            ));
        }
        let ratio = u / volume.geometry.longest_side();
        let [lo, hi] = volume.norm_range;
        let norm = |x: f64| (x - lo) / (hi - lo);
        let opacity: Vec<(f64, [f64; 1])> = self
            .opacity_points
            .iter()
            .map(|&(x, o)| (norm(x), [o]))
            .collect();
        let rgb: Vec<(f64, [f64; 3])> =
            self.rgb_points.iter().map(|&(x, c)| (norm(x), c)).collect();

        let mut xs: Vec<f64> = vec![0.0, 1.0];
        xs.extend(
            opacity
                .iter()
                .map(|p| p.0)
                .chain(rgb.iter().map(|p| p.0))
                .filter(|t| (0.0..=1.0).contains(t)),
        );
        xs.sort_by(f64::total_cmp);
        xs.dedup();

        let sigma_at =
            |t: f64| opacity_to_sigma_within(interpolate(&opacity, t)[0], ratio, 1.0, sigma_max);
        let mut refined = vec![xs[0]];
        for w in xs.windows(2) {
            refine(
                w[0],
                w[1],
                &sigma_at,
                &|t| interpolate(&opacity, t)[0],
                (ratio, sigma_max),
                0,
                &mut refined,
            );
            refined.push(w[1]);
        }
        let cp = ControlPoints {
            sigma: refined.iter().map(|&t| sigma_at(t)).collect(),
            rgb: refined.iter().map(|&t| interpolate(&rgb, t)).collect(),
            x: refined,
        };
        cp.validate()
            .map_err(|e| FormatError::file(path, e.to_string()))?;
        Ok(cp)
    }
}

/// Insert points strictly between `a` and `b` until σ-linear interpolation reproduces the
/// o-linear curve within EXPORT_TOLERANCE / 2 at the quarter points (depth ≤ 12, so at most
/// 4096 sub-points per file segment).
fn refine(
    a: f64,
    b: f64,
    sigma_at: &dyn Fn(f64) -> f64,
    o_at: &dyn Fn(f64) -> f64,
    (ratio, sigma_max): (f64, f64),
    depth: u32,
    out: &mut Vec<f64>,
) {
    if depth >= 12 {
        return;
    }
    let (sa, sb) = (sigma_at(a), sigma_at(b));
    // σ is capped at 255, so opacities above o_max cannot be matched by any refinement:
    // compare with what is reachable, or a saturated segment would always split to depth 12.
    let o_max = sigma_to_opacity(sigma_max, ratio, 1.0);
    let bad = [0.25, 0.5, 0.75].iter().any(|&w| {
        let t = a + w * (b - a);
        let ours = sigma_to_opacity(sa + w * (sb - sa), ratio, 1.0);
        (ours - o_at(t).min(o_max)).abs() > 0.5 * EXPORT_TOLERANCE
    });
    if bad {
        let m = 0.5 * (a + b);
        if m <= a || m >= b {
            return;
        }
        refine(a, m, sigma_at, o_at, (ratio, sigma_max), depth + 1, out);
        out.push(m);
        refine(m, b, sigma_at, o_at, (ratio, sigma_max), depth + 1, out);
    }
}

/// `name` without a trailing `-` + 8 hex digits (a hash we appended earlier).
fn base_name(name: &str) -> &str {
    if let Some((base, tail)) = name.rsplit_once('-') {
        if tail.len() == HASH_LEN && tail.bytes().all(|b| b.is_ascii_hexdigit()) {
            return base;
        }
    }
    name
}

/// Read a TF file (any of [`FORMATS`](super::FORMATS), by extension) and turn it into
/// control points for `volume`: opacity → σ = −ln(1 − o)·L/u, data x → normalized.
/// `unit_distance` overrides the file's (and the default, the mean voxel spacing).
pub fn load_tf(
    path: &Path,
    volume: &Volume,
    unit_distance: Option<f64>,
) -> Result<ControlPoints, FormatError> {
    super::read_tf(path)?.to_control_points(path, volume, unit_distance)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_interpolate_the_curves_over_the_range() {
        let tf = ExportTf {
            name: "t".into(),
            rgb_points: vec![(0.0, [1.0, 0.0, 0.0]), (10.0, [0.0, 0.0, 1.0])],
            opacity_points: vec![(0.0, 0.0), (5.0, 1.0), (10.0, 0.5)],
            unit_distance: None,
        };
        let (values, rgba) = tf.sample(3);
        assert_eq!(values, [0.0, 5.0, 10.0]);
        assert_eq!(rgba[0], [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(rgba[1], [0.5, 0.0, 0.5, 1.0]);
        assert_eq!(rgba[2], [0.0, 0.0, 1.0, 0.5]);
        // A colour-only map is opaque.
        let colour_only = ExportTf {
            opacity_points: Vec::new(),
            ..tf
        };
        assert!(colour_only.sample(4).1.iter().all(|p| p[3] == 1.0));
    }
}
