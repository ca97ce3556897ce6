//! Transfer functions: control points, the dense lookup table the renderer reads, the paper's
//! parameterization, the backward passes between them, the σ ↔ opacity conversion and the
//! simplification used for export.
//!
//! All positions here are *normalized* scalar values in [0, 1] (the renderer's input);
//! exporters map them to data units with `Volume::denormalize`.

#![warn(missing_docs)]

mod ciede2000;
mod color_convert;
mod colorspace;
mod lut;
mod opacity;
mod params;
mod simplify;

pub use colorspace::{ColorMap, ColorSpace};
pub use lut::ControlPointsGrad;
pub use opacity::{
    default_unit_distance, opacity_to_sigma, opacity_to_sigma_within, sigma_to_opacity,
};
pub use params::{Anchors, TfParams, TfParamsGrad};
pub use simplify::MIN_GAP;
pub use simplify::{interpolate, EXPORT_TOLERANCE};
pub use simplify::{simplified_curves, simplify_polyline};

/// Largest density of the paper's parameterization: σ = 255 · (tanh(p) + 1) / 2 (Appendix A).
/// A run that starts from a denser TF scales it (`t2tf::optimize::start`); a TF itself only
/// needs σ ≥ 0.
pub const SIGMA_MAX: f64 = 255.0;

/// Why a TF could not be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TfError {
    /// Fewer than two control points (the count given).
    #[error("a transfer function needs at least 2 control points, got {0}")]
    TooFewPoints(usize),
    /// The position, density and colour arrays differ in length.
    #[error(
        "control point arrays differ in length: {x} positions, {sigma} densities, {rgb} colours"
    )]
    LengthMismatch {
        /// Positions.
        x: usize,
        /// Densities.
        sigma: usize,
        /// Colours.
        rgb: usize,
    },
    /// One control point is out of range or out of order.
    #[error("control point {index}: {message}")]
    BadPoint {
        /// Its index.
        index: usize,
        /// What is wrong with it.
        message: String,
    },
}

/// A piecewise-linear TF: density σ and RGB colour at ascending positions.
///
/// σ is an extinction coefficient per unit of normalized length (docs/DESIGN.md "Conventions").
#[derive(Clone, Debug, PartialEq)]
pub struct ControlPoints {
    /// Ascending positions in [0, 1]; the first is 0 and the last 1.
    pub x: Vec<f64>,
    /// Density at each point, in [0, 255].
    pub sigma: Vec<f64>,
    /// Colour at each point, each channel in [0, 1].
    pub rgb: Vec<[f64; 3]>,
}

/// The TF sampled at `n` equally spaced normalized values: entry j is at x_j = j / (n - 1).
/// The renderer interpolates linearly between entries.
#[derive(Clone, Debug, PartialEq)]
pub struct Lut {
    /// (σ, r, g, b) per entry.
    pub entries: Vec<[f32; 4]>,
}

/// Gradient of a loss with respect to every LUT entry, accumulated in f64.
#[derive(Clone, Debug, PartialEq)]
pub struct LutGrad {
    /// ∂L/∂(σ, r, g, b) per entry.
    pub entries: Vec<[f64; 4]>,
}

impl LutGrad {
    /// A zero gradient for a LUT of `n` entries.
    pub fn zeros(n: usize) -> LutGrad {
        LutGrad {
            entries: vec![[0.0; 4]; n],
        }
    }

    /// Add another gradient entry-wise (reduction of per-thread or per-view gradients).
    pub fn add(&mut self, other: &LutGrad) {
        for (a, b) in self.entries.iter_mut().zip(&other.entries) {
            for c in 0..4 {
                a[c] += b[c];
            }
        }
    }
}

impl ControlPoints {
    /// Number of control points.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// No control points.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// `k` evenly spaced points (x_i = i / (k − 1)) with the given densities and colours.
    pub fn evenly_spaced(sigma: Vec<f64>, rgb: Vec<[f64; 3]>) -> Result<ControlPoints, TfError> {
        let k = sigma.len();
        let x = (0..k).map(|i| i as f64 / (k.max(2) - 1) as f64).collect();
        let cp = ControlPoints { x, sigma, rgb };
        cp.validate()?;
        Ok(cp)
    }

    /// Check the invariants the renderer and exporters rely on: ≥ 2 points, equal lengths,
    /// finite ascending x from 0 to 1, finite σ ≥ 0, colours in [0, 1].
    pub fn validate(&self) -> Result<(), TfError> {
        let k = self.x.len();
        if self.sigma.len() != k || self.rgb.len() != k {
            return Err(TfError::LengthMismatch {
                x: k,
                sigma: self.sigma.len(),
                rgb: self.rgb.len(),
            });
        }
        if k < 2 {
            return Err(TfError::TooFewPoints(k));
        }
        let bad = |index: usize, message: String| Err(TfError::BadPoint { index, message });
        for i in 0..k {
            let x = self.x[i];
            if !x.is_finite() || !(0.0..=1.0).contains(&x) {
                return bad(i, format!("position {x} is not in [0, 1]"));
            }
            if i > 0 && x < self.x[i - 1] {
                return bad(i, format!("position {x} is below the previous one"));
            }
            let s = self.sigma[i];
            if !(s.is_finite() && s >= 0.0) {
                return bad(i, format!("density {s} is not a finite number ≥ 0"));
            }
            if self.rgb[i].iter().any(|c| !(0.0..=1.0).contains(c)) {
                return bad(i, format!("colour {:?} is not in [0, 1]", self.rgb[i]));
            }
        }
        if self.x[0] != 0.0 || self.x[k - 1] != 1.0 {
            return bad(0, "the first position must be 0 and the last 1".into());
        }
        Ok(())
    }

    /// (σ, r, g, b) at normalized value `t`, linear between points, constant outside. At a
    /// repeated position (a jump) the value is the right-hand one.
    pub fn eval(&self, t: f64) -> [f64; 4] {
        let k = self.x.partition_point(|&x| x <= t);
        if k == 0 {
            return self.at(0);
        }
        if k >= self.len() {
            return self.at(self.len() - 1);
        }
        let (x0, x1) = (self.x[k - 1], self.x[k]);
        let w = if x1 > x0 { (t - x0) / (x1 - x0) } else { 1.0 };
        let (a, b) = (self.at(k - 1), self.at(k));
        std::array::from_fn(|c| a[c] + w * (b[c] - a[c]))
    }

    /// (σ, r, g, b) of point `i`.
    pub(crate) fn at(&self, i: usize) -> [f64; 4] {
        [
            self.sigma[i],
            self.rgb[i][0],
            self.rgb[i][1],
            self.rgb[i][2],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lut_interpolates_control_points() {
        let cp = ControlPoints {
            x: vec![0.0, 0.5, 1.0],
            sigma: vec![0.0, 100.0, 50.0],
            rgb: vec![[0.0; 3], [1.0, 0.5, 0.0], [0.0, 0.0, 1.0]],
        };
        let lut = cp.to_lut(5);
        assert_eq!(lut.entries[0], [0.0, 0.0, 0.0, 0.0]);
        assert_eq!(lut.entries[1], [50.0, 0.5, 0.25, 0.0]);
        assert_eq!(lut.entries[2], [100.0, 1.0, 0.5, 0.0]);
        assert_eq!(lut.entries[4], [50.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn validate_names_the_broken_point() {
        let mut cp = ControlPoints::evenly_spaced(vec![1.0; 3], vec![[0.5; 3]; 3]).unwrap();
        assert_eq!(cp.x, vec![0.0, 0.5, 1.0]);
        cp.sigma[1] = f64::NAN;
        let e = cp.validate().unwrap_err().to_string();
        assert!(e.starts_with("control point 1: density NaN"), "{e}");
        cp.sigma[1] = 1.0;
        cp.x[1] = 1.5;
        assert!(cp.validate().is_err());
        assert_eq!(
            ControlPoints::evenly_spaced(vec![1.0], vec![[0.5; 3]]).unwrap_err(),
            TfError::TooFewPoints(1)
        );
    }
}
