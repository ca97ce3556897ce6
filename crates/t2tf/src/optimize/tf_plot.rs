//! `tf.png`: the TF as a plot a person reads. Top to bottom: the prompt as the title; the
//! opacity curve (dark line, control points as dots, opacity axis on the left) over the
//! volume's histogram (grey bars, log counts on the right axis); under it, the TF's colour at
//! each value; under that, the data-value axis with ticks in the volume's own units.
//!
//! Opacity is what ParaView shows for the same TF: o = 1 − exp(−σ u / L) for the exported
//! unit distance u and the box's longest side L (docs/DESIGN.md). Sampled per pixel column, so
//! the curve between control points is the true one, not a straight line.
//!
//! Drawn with `plotters` into a pixel buffer, with the DejaVu Sans font this crate ships
//! (`assets/`), so the picture is the same on every machine, fonts installed or not.

use std::path::Path;

use plotters::prelude::*;

use crate::image::Image;
use crate::tf::ControlPoints;

/// Default size of tf.png.
pub(crate) const WIDTH: usize = 720;
pub(crate) const HEIGHT: usize = 420;
/// Height of the colour bar under the plot.
const BAR: u32 = 26;
/// Height of the data-value axis (ticks, numbers, its name) under the colour bar.
const X_AXIS: u32 = 48;
/// Width of each side's axis (numbers and the axis name).
const Y_AXIS: u32 = 64;
/// Margins around the plot, in pixels.
const MARGIN: u32 = 10;
/// Top of the opacity axis: a little above 1, so control points at full opacity show whole.
const Y_TOP: f64 = 1.04;

const BACKGROUND: RGBColor = RGBColor(255, 255, 255);
const BARS: RGBColor = RGBColor(200, 200, 200);
const LINE: RGBColor = RGBColor(25, 25, 25);
const POINT: RGBColor = RGBColor(217, 51, 25);
const TEXT: RGBColor = RGBColor(0, 0, 0);

/// The font's name in plotters' table of fonts.
const FONT: &str = "t2tf DejaVu Sans";
static FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Why tf.png could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The shipped font did not load (a broken build).
    #[error("tf.png: the built-in font does not load")]
    Font,
    /// plotters failed to draw.
    #[error("tf.png: drawing failed: {0}")]
    Draw(String),
    /// The PNG could not be written (names the file).
    #[error(transparent)]
    Image(#[from] crate::image::ImageError),
}

/// The font, registered once: plotters keeps fonts in a process-wide table by name, and the
/// name is this crate's own, so no caller's font is replaced.
fn font() -> Result<FontFamily<'static>, PlotError> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    if ok {
        Ok(FontFamily::Name(FONT))
    } else {
        Err(PlotError::Font)
    }
}

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

    /// The name of the left axis.
    fn name(self) -> &'static str {
        match self {
            Curve::Density => "density σ / 255",
            Curve::Opacity { .. } => "opacity",
        }
    }
}

/// What the plot is of: the title (the prompt) and the data range the normalized values
/// [0, 1] stand for (`Volume::norm_range`), which the value axis is labelled in.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotLabels {
    /// The title: the prompt, or what stood in for it.
    pub title: String,
    /// Data values at normalized 0 and 1.
    pub data_range: [f64; 2],
}

/// A title that fits the picture: one line, at most `max` characters.
fn title_line(title: &str, max: usize) -> String {
    let one: String = title
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let one = one.trim();
    if one.chars().count() <= max {
        one.to_string()
    } else {
        let cut: String = one.chars().take(max.saturating_sub(1)).collect();
        format!("{}…", cut.trim_end())
    }
}

/// A tick value in data units, short: "0", "127.5", "4095", "1.25e6", "3e-4".
fn tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.2e}");
        // 1.50e6 → 1.5e6, 1.00e6 → 1e6.
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        let m = m.trim_end_matches('0').trim_end_matches('.');
        return format!("{m}e{e}");
    }
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// A count on the histogram's log axis, at whole powers of ten only: "1", "10", "1k", "1M".
fn count_label(log10: f64) -> String {
    let k = log10.round();
    if (log10 - k).abs() > 1e-6 || k < 0.0 {
        return String::new();
    }
    match k as i32 {
        0 => "1".into(),
        1 => "10".into(),
        2 => "100".into(),
        k => {
            let (unit, base) = match k {
                3..=5 => ("k", 3),
                6..=8 => ("M", 6),
                _ => ("G", 9),
            };
            format!("{}{unit}", 10u64.pow((k - base) as u32))
        }
    }
}

/// Where things landed, for the tests: pixel ranges (x, y) of the plot and the colour bar.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Layout {
    pub plot: (std::ops::Range<i32>, std::ops::Range<i32>),
    pub bar: (std::ops::Range<i32>, std::ops::Range<i32>),
}

fn draw_error<E: std::fmt::Display>(e: E) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// Draw `cp` over `histogram` (counts of equal bins over [0, 1]) into a `width × height`
/// image. Sizes below 200 × 160 are raised to that (the axes need the room).
pub(crate) fn draw(
    cp: &ControlPoints,
    histogram: &[u64],
    curve: Curve,
    labels: &PlotLabels,
    width: usize,
    height: usize,
) -> Result<(Image, Layout), PlotError> {
    let (w, h) = (width.max(200), height.max(160));
    let family = font()?;
    let [mut lo, mut hi] = labels.data_range;
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        (lo, hi) = (0.0, 1.0);
    }
    let data = |t: f64| lo + t * (hi - lo);
    let mut buf = vec![255u8; w * h * 3];
    let layout;
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        root.fill(&BACKGROUND).map_err(draw_error)?;
        // About 9 px per character of the 17 px title.
        let title = title_line(&labels.title, (w / 9).max(8));
        let root = root
            .titled(&title, (family, 17).into_font().color(&TEXT))
            .map_err(draw_error)?;
        let (_, area_h) = root.dim_in_pixel();
        let (top, bottom) = root.split_vertically(area_h.saturating_sub(BAR + X_AXIS));

        // The histogram: log10(1 + count) per bin, on the right axis.
        let max = histogram.iter().copied().max().unwrap_or(0);
        let decades = ((1.0 + max as f64).log10().ceil()).max(1.0);
        let mut chart = ChartBuilder::on(&top)
            .margin_left(MARGIN)
            .margin_right(MARGIN)
            .margin_top(4)
            .set_label_area_size(LabelAreaPosition::Left, Y_AXIS)
            .set_label_area_size(LabelAreaPosition::Right, Y_AXIS)
            .build_cartesian_2d(lo..hi, 0.0..Y_TOP)
            .map_err(draw_error)?
            .set_secondary_coord(lo..hi, 0.0..decades * Y_TOP);
        chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc(curve.name())
            .y_labels(7)
            .y_label_formatter(&|v| format!("{v:.1}"))
            .label_style((family, 13).into_font().color(&TEXT))
            .axis_desc_style((family, 14).into_font().color(&TEXT))
            .draw()
            .map_err(draw_error)?;
        chart
            .configure_secondary_axes()
            .y_desc("voxels per bin (log scale)")
            .y_labels(decades as usize + 2)
            .y_label_formatter(&|v| count_label(*v))
            .label_style((family, 13).into_font().color(&TEXT))
            .axis_desc_style((family, 14).into_font().color(&TEXT))
            .draw()
            .map_err(draw_error)?;
        let bins = histogram.len().max(1) as f64;
        chart
            .draw_secondary_series(histogram.iter().enumerate().filter(|(_, &c)| c > 0).map(
                |(i, &c)| {
                    let (x0, x1) = (data(i as f64 / bins), data((i + 1) as f64 / bins));
                    Rectangle::new([(x0, 0.0), (x1, (1.0 + c as f64).log10())], BARS.filled())
                },
            ))
            .map_err(draw_error)?;
        let (px, py) = chart.plotting_area().get_pixel_range();
        if !cp.is_empty() {
            let columns = (px.end - px.start).max(2) as usize;
            let line = (0..columns).map(|i| {
                let t = i as f64 / (columns - 1) as f64;
                (data(t), curve.value(cp.eval(t)[0]))
            });
            chart
                .draw_series(LineSeries::new(line, LINE.stroke_width(2)))
                .map_err(draw_error)?;
            let points = cp.x.iter().zip(&cp.sigma).map(|(&x, &s)| {
                let x = if x.is_finite() {
                    x.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                Circle::new((data(x), curve.value(s)), 4, POINT.filled())
            });
            chart.draw_series(points).map_err(draw_error)?;
        }

        // The colour bar, on the plot's x pixels, and the value axis under it.
        let mut bar = ChartBuilder::on(&bottom)
            .margin_left(MARGIN)
            .margin_right(MARGIN)
            .set_label_area_size(LabelAreaPosition::Left, Y_AXIS)
            .set_label_area_size(LabelAreaPosition::Right, Y_AXIS)
            .set_label_area_size(LabelAreaPosition::Bottom, X_AXIS)
            .build_cartesian_2d(lo..hi, 0.0..1.0)
            .map_err(draw_error)?;
        bar.configure_mesh()
            .disable_mesh()
            .disable_y_axis()
            .x_desc("data value")
            .x_labels(8)
            .x_label_formatter(&|v| tick(*v))
            .label_style((family, 13).into_font().color(&TEXT))
            .axis_desc_style((family, 14).into_font().color(&TEXT))
            .draw()
            .map_err(draw_error)?;
        let (bx, by) = bar.plotting_area().get_pixel_range();
        let columns = (bx.end - bx.start).max(1) as usize;
        let colours = (0..columns).map(|i| {
            let (t0, t1) = (i as f64 / columns as f64, (i + 1) as f64 / columns as f64);
            let c = cp.eval((t0 + t1) / 2.0);
            let [r, g, b] = [c[1], c[2], c[3]].map(|v| {
                let v = if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (v * 255.0).round() as u8
            });
            Rectangle::new(
                [(data(t0), 0.0), (data(t1), 1.0)],
                RGBColor(r, g, b).filled(),
            )
        });
        if !cp.is_empty() {
            bar.draw_series(colours).map_err(draw_error)?;
        }
        root.present().map_err(draw_error)?;
        layout = Layout {
            plot: (px, py),
            bar: (bx, by),
        };
    }
    let mut im = Image::new(w, h);
    for (d, &b) in im.data.iter_mut().zip(&buf) {
        *d = b as f32 / 255.0;
    }
    Ok((im, layout))
}

/// Draw at the default size and save atomically.
pub fn save(
    path: &Path,
    cp: &ControlPoints,
    histogram: &[u64],
    curve: Curve,
    labels: &PlotLabels,
) -> Result<(), PlotError> {
    let (im, _) = draw(cp, histogram, curve, labels, WIDTH, HEIGHT)?;
    Ok(im.save_png(path)?)
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

    fn labels() -> PlotLabels {
        PlotLabels {
            title: "a red and blue ramp".into(),
            data_range: [0.0, 4095.0],
        }
    }

    fn rgb(c: RGBColor) -> [f32; 3] {
        [c.0, c.1, c.2].map(|v| v as f32 / 255.0)
    }

    /// Whether any pixel of the box has the colour.
    fn any(im: &Image, xs: std::ops::Range<i32>, ys: std::ops::Range<i32>, c: [f32; 3]) -> bool {
        ys.flat_map(|y| xs.clone().map(move |x| (x, y)))
            .any(|(x, y)| im.pixel(x as usize, y as usize) == c)
    }

    /// Whether the box has a dark (text or line) pixel.
    fn dark(im: &Image, xs: std::ops::Range<i32>, ys: std::ops::Range<i32>) -> bool {
        ys.flat_map(|y| xs.clone().map(move |x| (x, y)))
            .any(|(x, y)| im.pixel(x as usize, y as usize).iter().all(|&v| v < 0.4))
    }

    #[test]
    fn draws_bars_curve_points_bar_and_text_where_they_belong() {
        let mut h = vec![0u64; 256];
        h[10] = 1_000_000; // a tall bar at the left
        h[200] = 1; // a short one at x ≈ 0.78
        let (im, l) = draw(&tf(), &h, Curve::Density, &labels(), 720, 420).unwrap();
        assert_eq!((im.width, im.height), (720, 420));
        let (px, py) = l.plot.clone();
        let (bx, by) = l.bar.clone();
        // The colour bar spans the plot's x pixels, under the plot.
        assert_eq!(px, bx);
        assert!(by.start >= py.end, "{l:?}");
        let mid_y = ((by.start + by.end) / 2) as usize;
        // Each column shows the colour at its middle: within 1/100 of the end colours.
        let near =
            |p: [f32; 3], want: [f32; 3]| p.iter().zip(want).all(|(a, b)| (a - b).abs() < 0.01);
        let left = im.pixel(bx.start as usize, mid_y);
        assert!(near(left, [1.0, 0.0, 0.0]), "{left:?}");
        let mid = im.pixel(((bx.start + bx.end) / 2) as usize, mid_y);
        assert!(mid[1] > 0.95 && mid[0] < 0.05, "{mid:?}");
        let right = im.pixel(bx.end as usize - 3, mid_y);
        assert!(near(right, [0.0, 0.0, 1.0]), "{right:?}");
        // Histogram: the tall bar reaches the upper half; a count of 1 still shows (log
        // scale); the empty bins show nothing.
        let col = |t: f64| px.start + ((px.end - px.start) as f64 * t) as i32;
        let tall = col(10.5 / 256.0);
        assert!(any(
            &im,
            tall..tall + 1,
            py.start..(py.start + py.end) / 2,
            rgb(BARS)
        ));
        let short = col(200.5 / 256.0);
        assert!(any(&im, short..short + 1, py.end - 4..py.end, rgb(BARS)));
        let empty = col(100.5 / 256.0);
        assert!(!any(&im, empty..empty + 1, py.clone(), rgb(BARS)));
        // The curve's peak (a control point) at 1 in the middle.
        let row = |v: f64| py.start + ((1.0 - v / Y_TOP) * (py.end - py.start) as f64) as i32;
        let c = col(0.5);
        assert!(any(
            &im,
            c - 2..c + 3,
            row(1.0) - 2..row(1.0) + 3,
            rgb(POINT)
        ));
        // At a quarter, σ = 127.5: the line is half-way up.
        let q = col(0.25);
        let y = row(0.5);
        assert!(any(&im, q - 1..q + 2, y - 4..y + 5, rgb(LINE)));
        // Text: the title above the plot, numbers left, right and under the bar.
        assert!(dark(&im, 0..720, 0..py.start));
        assert!(dark(&im, 0..px.start - 4, py.clone()));
        assert!(dark(&im, px.end + 4..720, py.clone()));
        assert!(dark(&im, px.clone(), by.end + 2..420));
    }

    #[test]
    fn the_same_input_draws_the_same_picture() {
        let h: Vec<u64> = (0..256).map(|i| (i * 37 % 101) as u64).collect();
        let (a, _) = draw(&tf(), &h, Curve::Density, &labels(), 720, 420).unwrap();
        let (b, _) = draw(&tf(), &h, Curve::Density, &labels(), 720, 420).unwrap();
        assert_eq!(a.data, b.data);
        // And the title and the axis numbers are drawn from the text given.
        let other = PlotLabels {
            title: "something else entirely".into(),
            data_range: [-1.0, 1.0],
        };
        let (c, _) = draw(&tf(), &h, Curve::Density, &other, 720, 420).unwrap();
        assert_ne!(a.data, c.data);
    }

    #[test]
    fn ticks_and_counts_read_well() {
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(127.5), "127.5");
        assert_eq!(tick(4095.0), "4095");
        assert_eq!(tick(1_250_000.0), "1.25e6");
        assert_eq!(tick(-0.0003), "-3e-4");
        assert_eq!(count_label(0.0), "1");
        assert_eq!(count_label(3.0), "1k");
        assert_eq!(count_label(4.0), "10k");
        assert_eq!(count_label(6.0), "1M");
        assert_eq!(count_label(2.5), "");
        assert_eq!(title_line("a\nb", 10), "a b");
        assert_eq!(title_line("abcdefghijkl", 6), "abcde…");
    }

    #[test]
    fn opacity_curve_follows_the_unit_distance() {
        // σ = 255 at the middle with u / L = 1/255: o = 1 − e^{−1} ≈ 0.632 there.
        let c = Curve::Opacity {
            unit_over_length: 1.0 / 255.0,
        };
        assert!((c.value(255.0) - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
        assert_eq!(c.value(0.0), 0.0);
        assert_eq!(c.value(f64::NAN), 0.0);
        let (im, l) = draw(&tf(), &[1; 256], c, &labels(), 720, 420).unwrap();
        let (px, py) = l.plot;
        let x = (px.start + px.end) / 2;
        let row = |v: f64| py.start + ((1.0 - v / Y_TOP) * (py.end - py.start) as f64) as i32;
        let y = row(c.value(255.0));
        assert!(any(&im, x - 2..x + 3, y - 3..y + 4, rgb(POINT)));
        assert!(!any(
            &im,
            x - 2..x + 3,
            row(1.0) - 3..row(1.0) + 3,
            rgb(POINT)
        ));
    }

    #[test]
    fn degenerate_inputs_draw_without_panicking() {
        let empty = ControlPoints {
            x: vec![],
            sigma: vec![],
            rgb: vec![],
        };
        let nothing = PlotLabels {
            title: String::new(),
            data_range: [f64::NAN, f64::INFINITY],
        };
        let (im, _) = draw(&empty, &[], Curve::Density, &nothing, 1, 1).unwrap();
        assert!(im.data.iter().all(|v| v.is_finite()));
        let nan = ControlPoints {
            x: vec![0.0, 0.0, 1.0],
            sigma: vec![f64::NAN, 300.0, -5.0],
            rgb: vec![[f64::NAN; 3], [2.0, -1.0, 0.5], [0.5; 3]],
        };
        let flat = PlotLabels {
            title: "x".repeat(500),
            data_range: [3.0, 3.0],
        };
        for curve in [
            Curve::Density,
            Curve::Opacity {
                unit_over_length: 0.01,
            },
        ] {
            let (im, _) = draw(&nan, &[0; 256], curve, &flat, 64, 64).unwrap();
            assert!(im.data.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }

    #[test]
    fn saves_a_png() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tf.png");
        save(&p, &tf(), &[3; 256], Curve::Density, &labels()).unwrap();
        let back = Image::load_png(&p).unwrap();
        assert_eq!((back.width, back.height), (WIDTH, HEIGHT));
    }
}
