//! Transfer functions: control points, the dense lookup table the renderer reads, and (being
//! written, issue 3) the paper's parameterization and the backward passes between them.
//!
//! All positions here are *normalized* scalar values in [0, 1] (the renderer's input);
//! exporters map them to data units with `Volume::denormalize`.

/// A piecewise-linear TF: density σ and RGB colour at ascending positions.
///
/// σ is an extinction coefficient per unit of normalized length (DESIGN.md "Conventions").
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
    pub entries: Vec<[f64; 4]>,
}

impl LutGrad {
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
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// (σ, r, g, b) at normalized value `t`, linear between points, constant outside.
    pub fn eval(&self, t: f64) -> [f64; 4] {
        let k = self.x.partition_point(|&x| x <= t);
        let at = |i: usize| {
            [
                self.sigma[i],
                self.rgb[i][0],
                self.rgb[i][1],
                self.rgb[i][2],
            ]
        };
        if k == 0 {
            return at(0);
        }
        if k >= self.len() {
            return at(self.len() - 1);
        }
        let (x0, x1) = (self.x[k - 1], self.x[k]);
        let w = if x1 > x0 { (t - x0) / (x1 - x0) } else { 1.0 };
        let (a, b) = (at(k - 1), at(k));
        std::array::from_fn(|c| a[c] + w * (b[c] - a[c]))
    }

    /// Sample the TF into an `n`-entry lookup table.
    pub fn to_lut(&self, n: usize) -> Lut {
        let n = n.max(2);
        Lut {
            entries: (0..n)
                .map(|j| self.eval(j as f64 / (n - 1) as f64).map(|v| v as f32))
                .collect(),
        }
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
}
