//! Helpers shared by the formats that store colour and opacity at the same positions
//! (ParaView XML, VisIt .ct): merging the two curves and un-merging them on read.

use super::ExportTf;
use t2tf_tf::{interpolate, simplify_polyline, ColorMap, ColorSpace};

/// Colour points (data value, rgb) and opacity points (data value, o).
pub(crate) type RgbPoints = Vec<(f64, [f64; 3])>;
pub(crate) type OpacityPoints = Vec<(f64, f64)>;

/// One merged point: data value, rgb, opacity (None when the TF has no opacity).
pub(crate) struct MergedPoint {
    pub x: f64,
    pub rgb: [f64; 3],
    pub opacity: Option<f64>,
}

/// Both curves evaluated at the union of their positions (they are piecewise linear, so the
/// merged polyline is the same function).
/// The RGB map of an [`ExportTf`] (its colours are RGB-linear).
pub(crate) fn rgb_map(tf: &ExportTf) -> ColorMap {
    ColorMap {
        points: tf.rgb_points.clone(),
        space: ColorSpace::Rgb,
        hsv_wrap: false,
    }
}

/// Colours come from `colors` (the map in its own space) at positions only opacity has.
/// Outside RGB the colour points are all kept, repeated x included: in another space a
/// jump cannot be rebuilt from the merged values.
/// `keep_jumps` keeps every colour point in RGB too (XML can hold a repeated x; VisIt
/// tables get one value per position).
pub(crate) fn merge(tf: &ExportTf, colors: &ColorMap, keep_jumps: bool) -> Vec<MergedPoint> {
    let mut xs: Vec<f64> = tf
        .rgb_points
        .iter()
        .map(|p| p.0)
        .chain(tf.opacity_points.iter().map(|p| p.0))
        .collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    let opacity: Vec<(f64, [f64; 1])> = tf.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
    let o_at = |x: f64| (!opacity.is_empty()).then(|| interpolate(&opacity, x)[0]);
    if colors.space == ColorSpace::Rgb && !keep_jumps {
        // RGB keeps the right-hand value at a repeated x, as this format always did.
        return xs
            .into_iter()
            .map(|x| MergedPoint {
                x,
                rgb: interpolate(&tf.rgb_points, x),
                opacity: o_at(x),
            })
            .collect();
    }
    // The colour points ascend: a binary search per position (a preset may hold 10⁶).
    let has_colour = |x: f64| {
        let k = tf.rgb_points.partition_point(|p| p.0 < x);
        tf.rgb_points.get(k).is_some_and(|p| p.0 == x)
    };
    let only_opacity: Vec<f64> = xs.into_iter().filter(|&x| !has_colour(x)).collect();
    let mut points: Vec<MergedPoint> = tf
        .rgb_points
        .iter()
        .map(|&(x, rgb)| MergedPoint {
            x,
            rgb,
            opacity: o_at(x),
        })
        .chain(
            only_opacity
                .iter()
                .zip(colors.colors_at(&only_opacity))
                .map(|(&x, rgb)| MergedPoint {
                    x,
                    rgb,
                    opacity: o_at(x),
                }),
        )
        .collect();
    points.sort_by(|a, b| a.x.total_cmp(&b.x));
    points
}

/// Points whose removal changes a curve by less than this are dropped on read, undoing the
/// merge (values that lay on a line stay on it to ~1e-16; 1e-12 leaves real data alone).
const COLLINEAR: f64 = 1e-12;

/// Split merged points back into separate colour and opacity curves without the points that
/// only the merge added.
pub(crate) fn split(points: &[MergedPoint]) -> (RgbPoints, OpacityPoints) {
    let x: Vec<f64> = points.iter().map(|p| p.x).collect();
    let rgb: Vec<[f64; 3]> = points.iter().map(|p| p.rgb).collect();
    let rgb_points = simplify_polyline(&x, &rgb, COLLINEAR)
        .into_iter()
        .map(|i| (x[i], rgb[i]))
        .collect();
    let opacity_points = if points.iter().all(|p| p.opacity.is_some()) && !points.is_empty() {
        let o: Vec<[f64; 1]> = points.iter().map(|p| [p.opacity.unwrap_or(0.0)]).collect();
        simplify_polyline(&x, &o, COLLINEAR)
            .into_iter()
            .map(|i| (x[i], o[i][0]))
            .collect()
    } else {
        Vec::new()
    };
    (rgb_points, opacity_points)
}
