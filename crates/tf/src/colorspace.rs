//! Colour interpolation between control points in every space ParaView offers, evaluated as
//! `vtkColorTransferFunction::GetColor` does (linear segments: midpoint 0.5, sharpness 0,
//! which is all a preset's `RGBPoints` can say), and its conversion to the RGB-linear
//! polyline that VisIt tables and the renderer's LUT interpolate.

use std::collections::HashMap;
use std::f64::consts::PI;

use super::ciede2000;
use super::color_convert::{hsv_to_rgb, lab_to_rgb, rgb_to_hsv, rgb_to_lab};
use super::simplify_polyline;

/// ParaView's `ColorSpace` values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ColorSpace {
    /// Linear in RGB.
    #[default]
    Rgb,
    /// Linear in HSV (see [`ColorMap::hsv_wrap`]).
    Hsv,
    /// Linear in CIELAB.
    Lab,
    /// Moreland's diverging interpolation in Msh (polar Lab).
    Diverging,
    /// VTK's "Lab/CIEDE2000": the shortest ΔE2000 path through a grid of RGB colours.
    LabCiede2000,
    /// Constant over each segment, at the colour of its end point (VTK's Step).
    Step,
}

impl ColorSpace {
    /// The names ParaView writes (JSON `ColorSpace`, XML `space`), case-insensitive;
    /// "CIELAB" is the Lab spelling some of ParaView's own presets use.
    pub fn parse(name: &str) -> Option<ColorSpace> {
        let all = [
            ("rgb", ColorSpace::Rgb),
            ("hsv", ColorSpace::Hsv),
            ("lab", ColorSpace::Lab),
            ("cielab", ColorSpace::Lab),
            ("diverging", ColorSpace::Diverging),
            ("lab/ciede2000", ColorSpace::LabCiede2000),
            ("step", ColorSpace::Step),
        ];
        all.iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name.trim()))
            .map(|&(_, s)| s)
    }

    /// The name ParaView's `ColorSpace` property takes.
    pub fn paraview_name(self) -> &'static str {
        match self {
            ColorSpace::Rgb => "RGB",
            ColorSpace::Hsv => "HSV",
            ColorSpace::Lab => "Lab",
            ColorSpace::Diverging => "Diverging",
            ColorSpace::LabCiede2000 => "Lab/CIEDE2000",
            ColorSpace::Step => "Step",
        }
    }
}

/// Colour control points (data value, rgb) with the space they are interpolated in.
#[derive(Clone, Debug, PartialEq)]
pub struct ColorMap {
    /// Ascending x; a repeated x is a jump (ParaView keeps duplicates in file order).
    pub points: Vec<(f64, [f64; 3])>,
    /// The space colours are interpolated in between points.
    pub space: ColorSpace,
    /// HSV only: interpolate hue the short way round through red.
    pub hsv_wrap: bool,
}

/// CIEDE2000 paths already found, per pair of end colours (a search costs ~100k ΔE).
type PathCache = HashMap<[u64; 6], ColorMap>;

/// Width of the ramp that stands for a jump in the RGB-linear polyline, as a fraction of the
/// map's range (VisIt stores positions as f32: 1e-6 is still resolved).
const JUMP: f64 = 1e-6;

/// Samples per segment in [`ColorMap::rgb_linear`]: an HSV sector edge (slope ≤ 6 per unit
/// of s) then bends the polyline by at most 6 / 1024 / 4 < 0.0015 between samples.
const SAMPLES_PER_SEGMENT: usize = 1024;

impl ColorMap {
    /// The colour at `x` (outside the points: the end colours, as ParaView clamps).
    pub(crate) fn color_at(&self, x: f64) -> [f64; 3] {
        self.eval(x, &mut PathCache::new())
    }

    /// Colours at many positions (shares the CIEDE2000 path searches).
    pub fn colors_at(&self, xs: &[f64]) -> Vec<[f64; 3]> {
        let mut cache = PathCache::new();
        xs.iter().map(|&x| self.eval(x, &mut cache)).collect()
    }

    fn eval(&self, x: f64, cache: &mut PathCache) -> [f64; 3] {
        let p = &self.points;
        let (Some(first), Some(last)) = (p.first(), p.last()) else {
            return [0.0; 3];
        };
        if x > last.0 {
            return last.1;
        }
        if x < first.0 || x.is_nan() {
            return first.1;
        }
        // VTK's segment: the first point at or after x and the one before it.
        let k = p.partition_point(|q| q.0 < x);
        if k == 0 {
            return first.1;
        }
        let ((x1, c1), (x2, c2)) = (p[k - 1], p[k]);
        let s = if x2 != x1 { (x - x1) / (x2 - x1) } else { 0.0 };
        self.mix(c1, c2, s, cache)
    }

    /// Colour at fraction `s` between `c1` and `c2` in this map's space.
    fn mix(&self, c1: [f64; 3], c2: [f64; 3], s: f64, cache: &mut PathCache) -> [f64; 3] {
        let lerp = |a: [f64; 3], b: [f64; 3]| std::array::from_fn(|i| (1.0 - s) * a[i] + s * b[i]);
        match self.space {
            ColorSpace::Rgb => lerp(c1, c2),
            ColorSpace::Step => c2,
            ColorSpace::Hsv => {
                let (mut h1, mut h2) = (rgb_to_hsv(c1), rgb_to_hsv(c2));
                if self.hsv_wrap && (h1[0] - h2[0] > 0.5 || h2[0] - h1[0] > 0.5) {
                    if h1[0] > h2[0] {
                        h1[0] -= 1.0;
                    } else {
                        h2[0] -= 1.0;
                    }
                }
                let mut h: [f64; 3] = lerp(h1, h2);
                if h[0] < 0.0 {
                    h[0] += 1.0;
                }
                hsv_to_rgb(h)
            }
            ColorSpace::Lab => lab_to_rgb(lerp(rgb_to_lab(c1), rgb_to_lab(c2))),
            ColorSpace::Diverging => diverging(c1, c2, s),
            ColorSpace::LabCiede2000 => ciede2000_mix(c1, c2, s, cache),
        }
    }

    /// The map as an RGB-linear polyline within `tol` (max abs per channel, at the samples)
    /// of this map: each segment sampled `SAMPLES_PER_SEGMENT` times, jumps as ramps of
    /// `JUMP` of the range, then simplified. RGB maps without a repeated x come back
    /// unchanged.
    pub fn rgb_linear(&self, tol: f64) -> Vec<(f64, [f64; 3])> {
        let jumps = self.points.windows(2).any(|w| w[0].0 == w[1].0);
        if (self.space == ColorSpace::Rgb && !jumps) || self.points.len() < 2 {
            return self.points.clone();
        }
        let xs = self.dense_positions();
        let colors = self.colors_at(&xs);
        simplify_polyline(&xs, &colors, tol)
            .into_iter()
            .map(|i| (xs[i], colors[i]))
            .collect()
    }

    /// Sample positions: the first point, then per segment one just after its start (the
    /// value right of a point can differ from the value at it) and evenly to its end.
    fn dense_positions(&self) -> Vec<f64> {
        let p = &self.points;
        let width = JUMP * (p[p.len() - 1].0 - p[0].0);
        let mut xs = vec![p[0].0];
        for w in p.windows(2) {
            let (a, b) = (w[0].0, w[1].0);
            if b <= a {
                continue;
            }
            let step = (b - a) / SAMPLES_PER_SEGMENT as f64;
            if width > 0.0 && width < step {
                xs.push(a + width);
            }
            xs.extend((1..=SAMPLES_PER_SEGMENT).map(|j| a + step * j as f64));
            // `a + step·n` may round past b; the segment's end is b exactly.
            *xs.last_mut().expect("pushed") = b;
        }
        xs
    }
}

/// Moreland's diverging interpolation in Msh (polar Lab) as `vtkColorTransferFunction` has it:
/// ends both saturated (s > 0.05) with hues more than 0.33π apart get a white midpoint
/// (M = max(M1, M2, 88), s = 0) that each half runs to; an unsaturated end (s < 0.05) next to a
/// saturated one takes the saturated end's hue, spun for a near-constant perceptual change
/// when its M is larger; then M, s and h are interpolated linearly.
fn diverging(c1: [f64; 3], c2: [f64; 3], s: f64) -> [f64; 3] {
    let (mut m1, mut m2) = (lab_to_msh(rgb_to_lab(c1)), lab_to_msh(rgb_to_lab(c2)));
    let mut s = s;
    if m1[1] > 0.05 && m2[1] > 0.05 && angle_diff(m1[2], m2[2]).abs() > 0.33 * PI {
        let mid = m1[0].max(m2[0]).max(88.0);
        if s < 0.5 {
            m2 = [mid, 0.0, 0.0];
            s *= 2.0;
        } else {
            m1 = [mid, 0.0, 0.0];
            s = 2.0 * s - 1.0;
        }
    }
    if m1[1] < 0.05 && m2[1] > 0.05 {
        m1[2] = adjust_hue(m2, m1[0]);
    } else if m2[1] < 0.05 && m1[1] > 0.05 {
        m2[2] = adjust_hue(m1, m2[0]);
    }
    // Every component linearly, hue included: VTK does not take the short way round, so
    // ends whose hues straddle ±π sweep through the hues between (as ParaView shows them).
    let msh = [
        (1.0 - s) * m1[0] + s * m2[0],
        (1.0 - s) * m1[1] + s * m2[1],
        (1.0 - s) * m1[2] + s * m2[2],
    ];
    lab_to_rgb(msh_to_lab(msh))
}

fn lab_to_msh(lab: [f64; 3]) -> [f64; 3] {
    let [l, a, b] = lab;
    let m = (l * l + a * a + b * b).sqrt();
    let s = if m > 0.001 { (l / m).acos() } else { 0.0 };
    let h = if s > 0.001 { b.atan2(a) } else { 0.0 };
    [m, s, h]
}

fn msh_to_lab(msh: [f64; 3]) -> [f64; 3] {
    let [m, s, h] = msh;
    [m * s.cos(), m * s.sin() * h.cos(), m * s.sin() * h.sin()]
}

/// a1 − a2 folded into [−π, π] the way VTK folds it.
fn angle_diff(a1: f64, a2: f64) -> f64 {
    let mut d = a1 - a2;
    if d >= 0.0 {
        while d >= 2.0 * PI {
            d -= 2.0 * PI;
        }
        if d > PI {
            d = 2.0 * PI - d;
        }
    } else {
        while d <= -2.0 * PI {
            d += 2.0 * PI;
        }
        if d < -PI {
            d += 2.0 * PI;
        }
    }
    d
}

/// Hue for an unsaturated end of magnitude `unsat_m`, spun so the perceptual change along
/// the segment is near constant (away from 0, except for purple hues).
fn adjust_hue(msh: [f64; 3], unsat_m: f64) -> f64 {
    if msh[0] >= unsat_m - 0.1 {
        return msh[2];
    }
    let spin = msh[1] * (unsat_m * unsat_m - msh[0] * msh[0]).sqrt() / (msh[0] * msh[1].sin());
    if msh[2] > -0.3 * PI {
        msh[2] + spin
    } else {
        msh[2] - spin
    }
}

/// VTK snaps both ends to its grid, follows the shortest ΔE2000 path in Lab, and returns
/// the colour rounded to 8 bits (it evaluates the path with `MapValue`).
fn ciede2000_mix(c1: [f64; 3], c2: [f64; 3], s: f64, cache: &mut PathCache) -> [f64; 3] {
    let (a, b) = (ciede2000::snap(c1), ciede2000::snap(c2));
    let key = [a[0], a[1], a[2], b[0], b[1], b[2]].map(f64::to_bits);
    let path = cache.entry(key).or_insert_with(|| ColorMap {
        points: ciede2000::color_path(a, b),
        space: ColorSpace::Lab,
        hsv_wrap: false,
    });
    let c = if path.points.len() == 1 {
        path.points[0].1
    } else {
        path.color_at(s)
    };
    c.map(|v| (255.0 * v + 0.5).floor().clamp(0.0, 255.0) / 255.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for s in [
            ColorSpace::Rgb,
            ColorSpace::Hsv,
            ColorSpace::Lab,
            ColorSpace::Diverging,
            ColorSpace::LabCiede2000,
            ColorSpace::Step,
        ] {
            assert_eq!(ColorSpace::parse(s.paraview_name()), Some(s));
        }
        assert_eq!(ColorSpace::parse("CIELAB"), Some(ColorSpace::Lab));
        assert_eq!(ColorSpace::parse("XYZ"), None);
    }

    #[test]
    fn diverging_interpolates_hue_linearly_as_vtk_does() {
        // Two neighbouring points of ParaView's "Viridis (matplotlib)" (kept in Diverging):
        // their hues straddle ±π, and VTK sweeps through the hues between rather than taking
        // the short way. ParaView 5.11's own GetColor at x = 0.5474095796676441.
        let m = ColorMap {
            points: vec![
                (0.545098, [0.119512, 0.607464, 0.540218]),
                (0.54902, [0.119423, 0.611141, 0.538982]),
            ],
            space: ColorSpace::Diverging,
            hsv_wrap: false,
        };
        let paraview = [0.7783606720329149, 0.4564742371221619, 0.41693334769779306];
        let ours = m.color_at(0.5474095796676441);
        for k in 0..3 {
            assert!(
                (ours[k] - paraview[k]).abs() < 1e-6,
                "{ours:?} vs {paraview:?}"
            );
        }
    }

    #[test]
    fn step_takes_the_next_points_colour() {
        let m = ColorMap {
            points: vec![(0.0, [0.0; 3]), (1.0, [1.0; 3]), (2.0, [0.5; 3])],
            space: ColorSpace::Step,
            hsv_wrap: false,
        };
        assert_eq!(m.color_at(0.0), [0.0; 3]);
        assert_eq!(m.color_at(0.5), [1.0; 3]);
        assert_eq!(m.color_at(1.0), [1.0; 3]);
        assert_eq!(m.color_at(1.5), [0.5; 3]);
        let lin = m.rgb_linear(1e-3);
        assert!(lin.len() <= 6, "{lin:?}");
    }
}
