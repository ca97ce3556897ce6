//! How a TF file becomes the renderer's lookup table: the one place a preset is sampled for
//! rendering. [`Sampling::Exact`] renders the file's curves (colours in other spaces made RGB
//! segments within the export tolerance, opacity turned into density with the unit
//! distance); [`Sampling::ParaView`] renders what ParaView 5.11's GPU volume mapper samples
//! instead, so a picture predicts ParaView's.

use std::path::Path;

use t2tf_tf::{default_unit_distance, interpolate, Lut};
use t2tf_volume::Volume;

use crate::{ExportTf, FormatError, Preset};

/// Entries of the exact LUT (`t2tf render`'s and the optimizer's exports are sampled with as
/// many or more).
pub const LUT_SIZE: usize = 1024;

/// How a preset is sampled into the renderer's LUT.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sampling {
    /// The preset's own curves through a LUT of [`LUT_SIZE`] entries.
    Exact,
    /// As ParaView's GPU ray caster samples it (see [`ParaViewTables`]) for samples
    /// `sample_distance` world units apart.
    ParaView {
        /// World distance between samples along a ray.
        sample_distance: f64,
    },
}

/// The renderer's LUT for `preset` on `volume`, its opacity read with `unit_distance`, else
/// the preset's own, else the volume's default. `path` names the preset in errors.
pub fn preset_lut(
    preset: &Preset,
    path: &Path,
    volume: &Volume,
    unit_distance: Option<f64>,
    sampling: Sampling,
) -> Result<Lut, FormatError> {
    let tf = preset.rgb_linear();
    // Checks the curves and the unit distance whichever way they are sampled.
    let cp = tf.to_control_points(path, volume, unit_distance)?;
    Ok(match sampling {
        Sampling::Exact => cp.to_lut(LUT_SIZE),
        Sampling::ParaView { sample_distance } => {
            let u = unit_distance
                .or(tf.unit_distance)
                .unwrap_or_else(|| default_unit_distance(&volume.geometry));
            ParaViewTables::new(preset, &tf, volume.norm_range, u)
                .lut(sample_distance, volume.geometry.longest_side())
        }
    })
}

/// What ParaView 5.11's GPU ray caster (VTK's `vtkOpenGLVolumeOpacityTable`,
/// `vtkOpenGLVolumeRGBTable`, `vtkVolumeInputHelper`) samples instead of the TF itself:
/// - each function is tabulated over the data range (the mapper's default "scalar" range
///   mode), entry i at lo + i·(hi − lo)/(W − 1), with W = max(1024, the power of two at or
///   above (hi − lo) / (smallest distance between the function's own nodes)) — 1024 unless
///   nodes are closer than 1/1024 of the range;
/// - each opacity entry o > 1e-4 becomes the opacity of one sample, 1 − (1 − o)^(Δ/u)
///   (Δ the sample distance, u the unit distance); entries ≤ 1e-4 are used as they are;
/// - the table is a linearly filtered, edge-clamped texture addressed by t = (s − lo)/(hi − lo):
///   texel centres are at (i + ½)/W, so t reads entry index clamp(t·W − ½, 0, W − 1), half an
///   entry off i = t·(W − 1) near the ends, and values are interpolated between entries.
///
/// The renderer's LUT has entries at j/(n − 1); with n − 1 = 2·W (W the larger table, a power
/// of two like the other) every texel centre and every midpoint between two is an entry, so the
/// texture is reproduced at its own knots. Between knots the renderer interpolates σ where
/// ParaView interpolates the per-sample opacity; at 2 knots per entry the two agree to well
/// under an 8-bit level.
pub struct ParaViewTables {
    /// Opacity per unit distance, one per entry.
    opacity: Vec<f64>,
    /// Colour, one per entry.
    rgb: Vec<[f64; 3]>,
    unit_distance: f64,
}

/// The smallest power of two ≥ the entries VTK wants for nodes at `xs` over `range`.
fn table_width(xs: impl Iterator<Item = f64>, range: [f64; 2]) -> usize {
    let xs: Vec<f64> = xs.collect();
    let d = xs
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    let ideal = ((range[1] - range[0]) / d).ceil();
    // OpenGL's texture size limit (16384 on Mesa llvmpipe) caps VTK's table.
    let ideal = if ideal.is_finite() {
        ideal.min(16384.0) as usize
    } else {
        1
    };
    ideal.next_power_of_two().max(1024)
}

/// A table of `w` entries over `range`, read as the texture reads it at t ∈ [0, 1].
fn texture<const N: usize>(table: &[[f64; N]], t: f64) -> [f64; N] {
    let w = table.len();
    let k = (t * w as f64 - 0.5).clamp(0.0, (w - 1) as f64);
    let i = (k.floor() as usize).min(w - 2);
    let f = k - i as f64;
    std::array::from_fn(|c| table[i][c] + f * (table[i + 1][c] - table[i][c]))
}

impl ParaViewTables {
    /// The tables of `preset` (its RGB polyline `rgb_linear`) over the data `range`, opacity
    /// per `unit_distance`.
    pub fn new(
        preset: &Preset,
        rgb_linear: &ExportTf,
        range: [f64; 2],
        unit_distance: f64,
    ) -> ParaViewTables {
        let op: Vec<(f64, [f64; 1])> = rgb_linear
            .opacity_points
            .iter()
            .map(|&(x, o)| (x, [o]))
            .collect();
        // Widths from the preset's own nodes (ParaView's colour function has those, not the
        // RGB polyline `rgb_linear` adds for other colour spaces); values from the polyline,
        // which is within the export tolerance of ParaView's colours.
        let w_op = table_width(op.iter().map(|p| p.0), range);
        let w_rgb = table_width(preset.tf.rgb_points.iter().map(|p| p.0), range);
        let at = |i: usize, w: usize| range[0] + (range[1] - range[0]) * i as f64 / (w - 1) as f64;
        ParaViewTables {
            opacity: (0..w_op)
                .map(|i| interpolate(&op, at(i, w_op))[0])
                .collect(),
            rgb: (0..w_rgb)
                .map(|i| interpolate(&rgb_linear.rgb_points, at(i, w_rgb)))
                .collect(),
            unit_distance,
        }
    }

    /// The renderer's LUT for samples `delta` apart (world units) in a box of longest side
    /// `longest`.
    pub fn lut(&self, delta: f64, longest: f64) -> Lut {
        let per_sample: Vec<[f64; 1]> = self
            .opacity
            .iter()
            .map(|&o| {
                let o = o.clamp(0.0, 1.0);
                if o > 1e-4 {
                    [1.0 - (1.0 - o).powf(delta / self.unit_distance)]
                } else {
                    [o]
                }
            })
            .collect();
        let n = 2 * self.opacity.len().max(self.rgb.len()) + 1;
        let entries = (0..n)
            .map(|j| {
                let t = j as f64 / (n - 1) as f64;
                let a = texture(&per_sample, t)[0].min(1.0 - 1e-12);
                // α = 1 − exp(−σ δ / L) in the renderer.
                let sigma = -(-a).ln_1p() * longest / delta;
                let c = texture(&self.rgb, t);
                [sigma as f32, c[0] as f32, c[1] as f32, c[2] as f32]
            })
            .collect();
        Lut { entries }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_width_is_vtks() {
        let r = [0.0, 100.0];
        // Nodes ≥ 1/1024 of the range apart: 1024 entries.
        assert_eq!(table_width([0.0, 50.0, 100.0].into_iter(), r), 1024);
        // 1/1500 of the range: the next power of two, 2048.
        assert_eq!(table_width([0.0, 0.1 / 1.5, 100.0].into_iter(), r), 2048);
        // A single node has no distance: the minimum.
        assert_eq!(table_width([5.0].into_iter(), r), 1024);
    }

    #[test]
    fn texture_reads_texel_centres_clamped() {
        let t: Vec<[f64; 1]> = (0..4).map(|i| [i as f64]).collect();
        // Centres at (i + ½)/4; clamped to the end entries outside them.
        assert_eq!(texture(&t, 0.0), [0.0]);
        assert_eq!(texture(&t, 0.125), [0.0]);
        assert_eq!(texture(&t, 0.375), [1.0]);
        assert_eq!(texture(&t, 0.5), [1.5]);
        assert_eq!(texture(&t, 1.0), [3.0]);
    }
}
