//! `tf.png`: the TF over the volume's histogram, drawn with plain pixel code.
//!
//! Layout, top to bottom: the plot (histogram as light gray bars on a log scale, the opacity
//! curve as a dark line with 1 at the top, control points as small squares), then a strip of
//! the TF colour at each value. The x axis is the normalized value, 0 at the left.
//!
//! Opacity is what ParaView shows for the same TF: o = 1 − exp(−σ u / L) for the exported
//! unit distance u and the box's longest side L (docs/DESIGN.md). Sampled per pixel column, so the
//! curve between control points is the true one, not a straight line.

use std::path::Path;

use crate::image::Image;
use crate::tf::ControlPoints;

/// Default size of tf.png.
pub(crate) const WIDTH: usize = 512;
pub(crate) const HEIGHT: usize = 256;
/// Height of the colour strip and of the gap above it.
const STRIP: usize = 32;
const GAP: usize = 4;

const BACKGROUND: [f32; 3] = [1.0, 1.0, 1.0];
const BARS: [f32; 3] = [0.8, 0.8, 0.8];
const LINE: [f32; 3] = [0.1, 0.1, 0.1];
const POINT: [f32; 3] = [0.85, 0.2, 0.1];

/// Which curve the plot shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Curve {
    /// σ / 255 (the optimizer's own quantity).
    Density,
    /// Opacity 1 − exp(−σ · r) with r = u / L (unit distance over the box's longest side).
    Opacity {
        /// ParaView's scalar opacity unit distance u over the box's longest side L.
        unit_over_length: f64,
    },
}

impl Curve {
    /// Height of the curve in [0, 1] for density σ (NaN → 0).
    fn value(self, sigma: f64) -> f64 {
        let v = match self {
            Curve::Density => sigma / 255.0,
            Curve::Opacity { unit_over_length } => 1.0 - (-sigma.max(0.0) * unit_over_length).exp(),
        };
        if v.is_nan() {
            0.0
        } else {
            v.clamp(0.0, 1.0)
        }
    }
}

/// Draw `cp` over `histogram` (counts of equal bins over [0, 1]) into a `width × height` image.
/// Needs width ≥ 2 and height > STRIP + GAP + 2; smaller sizes are raised to that.
pub(crate) fn draw(
    cp: &ControlPoints,
    histogram: &[u64],
    curve: Curve,
    width: usize,
    height: usize,
) -> Image {
    let width = width.max(2);
    let height = height.max(STRIP + GAP + 3);
    let plot_h = height - STRIP - GAP;
    let mut im = Image::filled(width, height, BACKGROUND);
    let col_t = |x: usize| x as f64 / (width - 1) as f64;

    // Histogram bars: height ∝ ln(1 + count) / ln(1 + max count).
    let max = histogram.iter().copied().max().unwrap_or(0);
    if max > 0 {
        let denom = (1.0 + max as f64).ln();
        for x in 0..width {
            let bin = ((col_t(x) * histogram.len() as f64) as usize).min(histogram.len() - 1);
            let frac = (1.0 + histogram[bin] as f64).ln() / denom;
            let bar = (frac * (plot_h - 1) as f64).round() as usize;
            for y in plot_h - bar..plot_h {
                im.set_pixel(x, y, BARS);
            }
        }
    }

    if cp.is_empty() {
        return im;
    }
    // σ line: joins the row of each column to the next one's so steep edges stay connected.
    let row = |sigma: f64| -> usize {
        ((1.0 - curve.value(sigma)) * (plot_h - 1) as f64).round() as usize
    };
    let mut prev = row(cp.eval(0.0)[0]);
    for x in 0..width {
        let r = row(cp.eval(col_t(x))[0]);
        let (a, b) = (prev.min(r), prev.max(r));
        for y in a..=b {
            im.set_pixel(x, y, LINE);
            if y + 1 < plot_h {
                im.set_pixel(x, y + 1, LINE);
            }
        }
        prev = r;
    }
    // Control points: 5 × 5 squares.
    for (&px, &s) in cp.x.iter().zip(&cp.sigma) {
        let cx = (px.clamp(0.0, 1.0) * (width - 1) as f64).round() as i64;
        let cy = row(s) as i64;
        for dy in -2..=2 {
            for dx in -2..=2 {
                let (x, y) = (cx + dx, cy + dy);
                if x >= 0 && y >= 0 && (x as usize) < width && (y as usize) < plot_h {
                    im.set_pixel(x as usize, y as usize, POINT);
                }
            }
        }
    }
    // Colour strip.
    for x in 0..width {
        let c = cp.eval(col_t(x));
        let rgb = [c[1] as f32, c[2] as f32, c[3] as f32].map(|v| {
            if v.is_finite() {
                v.clamp(0.0, 1.0)
            } else {
                0.0
            }
        });
        for y in height - STRIP..height {
            im.set_pixel(x, y, rgb);
        }
    }
    im
}

/// Draw at the default size and save atomically.
pub fn save(
    path: &Path,
    cp: &ControlPoints,
    histogram: &[u64],
    curve: Curve,
) -> Result<(), crate::image::ImageError> {
    draw(cp, histogram, curve, WIDTH, HEIGHT).save_png(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tf() -> ControlPoints {
        ControlPoints {
            x: vec![0.0, 0.5, 1.0],
            sigma: vec![0.0, 255.0, 0.0],
            rgb: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        }
    }

    #[test]
    fn draws_bars_line_points_and_strip_where_they_belong() {
        let mut h = vec![0u64; 256];
        h[0] = 1_000_000; // tall bar at the left
        h[200] = 1; // short bar at x ≈ 0.78
        let im = draw(&tf(), &h, Curve::Density, 512, 256);
        assert_eq!((im.width, im.height), (512, 256));
        let plot_h = 256 - STRIP - GAP;
        // Colour strip: red at the left, green in the middle, blue at the right.
        let y = 256 - STRIP / 2;
        assert_eq!(im.pixel(0, y), [1.0, 0.0, 0.0]);
        let mid = im.pixel(255, y);
        assert!(mid[1] > 0.99 && mid[0] < 0.01, "{mid:?}");
        assert_eq!(im.pixel(511, y), [0.0, 0.0, 1.0]);
        // The σ peak reaches the top row at the middle (a control-point square).
        assert_eq!(im.pixel(256, 0), POINT);
        // Line at column 128 (t = 128/511): σ = 255 · 2t → row (1 − 2t)(plot_h − 1).
        let r = ((1.0 - 2.0 * 128.0 / 511.0) * (plot_h - 1) as f64).round() as usize;
        let hit = (r.saturating_sub(3)..r + 3).any(|y| im.pixel(128, y) == LINE);
        assert!(hit, "no line near row {r} at column 128");
        // Tall histogram bar on the left reaches near the top; the log scale makes a count
        // of 1 still visible (ln 2 / ln 1e6 ≈ 5 % of the plot height).
        assert_eq!(im.pixel(1, 30), BARS);
        let col = (200.5 / 256.0 * 511.0) as usize;
        assert_eq!(im.pixel(col, plot_h - 2), BARS);
        assert_eq!(im.pixel(col, plot_h - 30), BACKGROUND);
        // Gap stays background.
        assert_eq!(im.pixel(400, plot_h + 1), BACKGROUND);
    }

    #[test]
    fn opacity_curve_follows_the_unit_distance() {
        // σ = 255 at the middle with u / L = 1/255: o = 1 − e^{−1} ≈ 0.632 there, and the
        // curve between points is concave (above the chord), as ParaView's dense export is.
        let c = Curve::Opacity {
            unit_over_length: 1.0 / 255.0,
        };
        assert!((c.value(255.0) - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
        assert_eq!(c.value(0.0), 0.0);
        assert_eq!(c.value(f64::NAN), 0.0);
        let im = draw(&tf(), &[1; 256], c, 512, 256);
        let plot_h = 256 - STRIP - GAP;
        let top = ((1.0 - c.value(255.0)) * (plot_h - 1) as f64).round() as usize;
        assert_eq!(im.pixel(256, top), POINT);
        assert_eq!(im.pixel(256, 0), BACKGROUND);
        // Quarter column: σ ≈ 127.75 → o ≈ 0.394, above the chord's 0.316.
        let t = 128.0 / 511.0;
        let r = ((1.0 - c.value(255.0 * 2.0 * t)) * (plot_h - 1) as f64).round() as usize;
        assert!((r.saturating_sub(1)..r + 2).any(|y| im.pixel(128, y) == LINE));
    }

    #[test]
    fn degenerate_inputs_draw_without_panicking() {
        let empty = ControlPoints {
            x: vec![],
            sigma: vec![],
            rgb: vec![],
        };
        let im = draw(&empty, &[], Curve::Density, 1, 1);
        assert!(im.data.iter().all(|v| v.is_finite()));
        let nan = ControlPoints {
            x: vec![0.0, 0.0, 1.0],
            sigma: vec![f64::NAN, 300.0, -5.0],
            rgb: vec![[f64::NAN; 3], [2.0, -1.0, 0.5], [0.5; 3]],
        };
        let im = draw(&nan, &[0; 256], Curve::Density, 64, 64);
        assert!(im.data.iter().all(|v| (0.0..=1.0).contains(v)));
        let im = draw(
            &nan,
            &[0; 256],
            Curve::Opacity {
                unit_over_length: 0.01,
            },
            64,
            64,
        );
        assert!(im.data.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn saves_a_png() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tf.png");
        save(&p, &tf(), &[3; 256], Curve::Density).unwrap();
        let back = Image::load_png(&p).unwrap();
        assert_eq!((back.width, back.height), (WIDTH, HEIGHT));
    }
}
