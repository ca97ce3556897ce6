//! Where a run starts and what it keeps: `Job::init` (a TF file to refine) and `Job::locks`
//! (data ranges whose TF does not change), checked and turned into the loop's start and
//! parameterization (`optimize::start`).

use std::path::{Path, PathBuf};

use super::PipelineError;
use crate::camera::UpAxis;
use crate::formats::Preset;
use crate::memory::Budget;
use crate::optimize::adapters::{PaperTf, VolumeRenderer};
use crate::optimize::start::{self, Lock, StartTf};
use crate::optimize::ValidSettings;
use crate::render::{CpuBackend, RenderOptions};
use crate::tf::ControlPoints;
use crate::volume::Volume;

/// Entries of the LUT a run with a given start or locks samples at least: the width of the
/// table ParaView 5.11's volume mapper samples a TF into (VTK takes more when points are
/// closer than 1/1024 of the range). Every value ParaView samples is then a LUT entry, so
/// the written preset is the TF the loop rendered at each of them.
pub const PARAVIEW_TABLE: usize = 1024;

/// A TF to start from: a preset of a TF file (ParaView JSON or XML, VisIt `.ct`).
#[derive(Clone, Debug, PartialEq)]
pub struct InitTf {
    /// The preset, in its own colour space.
    pub preset: Preset,
    /// The file it came from (named in errors and in report.json).
    pub source: PathBuf,
}

impl InitTf {
    /// Read preset `name` (the file's only one when `None`) of the TF file `path`, a file of
    /// at most `max_size` bytes (`formats::DEFAULT_MAX_PRESET_SIZE` by default).
    pub fn read(path: &Path, name: Option<&str>, max_size: u64) -> Result<InitTf, PipelineError> {
        let preset = crate::formats::read_preset_within(path, name, max_size)?;
        InitTf::new(preset, path.to_path_buf())
    }

    /// A start from `preset`, read from `source`: checked, and a preset of more points than a
    /// run has control points (`limits::CONTROL_POINTS`) simplified first, each curve within
    /// `tf::EXPORT_TOLERANCE`; one that still has more is refused, so that a start never costs
    /// more than the largest run.
    pub fn new(mut preset: Preset, source: PathBuf) -> Result<InitTf, PipelineError> {
        preset.tf.validate(&source)?;
        let limit = crate::optimize::settings::limits::CONTROL_POINTS;
        let tf = &mut preset.tf;
        let count = tf.rgb_points.len() + tf.opacity_points.len();
        if count > limit {
            let tol = crate::tf::EXPORT_TOLERANCE;
            tf.opacity_points = simplified(&tf.opacity_points, |p| [p.1], tol);
            // Colours interpolated in another space are not linear in RGB: kept as they are.
            if preset.space == crate::tf::ColorSpace::Rgb {
                tf.rgb_points = simplified(&tf.rgb_points, |p| p.1, tol);
            }
            let left = tf.rgb_points.len() + tf.opacity_points.len();
            if left > limit {
                return Err(PipelineError::Job(format!(
                    "{}: preset \"{}\" has {count} colour and opacity points, {left} after \
                     dropping those within {tol} of their neighbours' line; a start takes at \
                     most {limit}",
                    source.display(),
                    tf.name
                )));
            }
        }
        Ok(InitTf { preset, source })
    }

    /// A colour map without opacity: the run takes its colours, spread over the data range
    /// as ParaView applies a library preset, and the paper's densities.
    pub fn colours_only(&self) -> bool {
        self.preset.tf.opacity_points.is_empty()
    }

    /// The control points a run from this colour-only start begins with on `volume` (what
    /// `optimize --init` with 0 steps writes): the preset's colours over the paper's initial
    /// densities ([`crate::optimize::initialize`] with `settings`, its start view rendered at
    /// `size` pixels, CLIP's input size in a run, with the loop's default step and `up`).
    /// `t2tf render` draws a colour-only preset with them. A preset with opacity is an error:
    /// its own densities are the start.
    pub fn colours_only_points(
        &self,
        volume: &Volume,
        settings: &ValidSettings,
        size: usize,
        up: UpAxis,
        budget: Budget,
    ) -> Result<ControlPoints, PipelineError> {
        use crate::optimize::Parameterization;
        if !self.colours_only() {
            return Err(PipelineError::Job(format!(
                "{}: preset \"{}\" has opacity points: a start takes its own densities",
                self.source.display(),
                self.preset.tf.name
            )));
        }
        // As a run renders its start view (`pipeline::run`).
        let backend = CpuBackend::new(budget);
        let renderer = VolumeRenderer {
            backend: &backend,
            volume,
            series: None,
            options: RenderOptions {
                step: crate::render::DEFAULT_STEP,
                level: None,
                ..Default::default()
            },
            up,
            size,
            render_size: size,
            jitter: false,
        };
        let paper = PaperTf {
            k: settings.control_points,
            lut_size: super::LUT_SIZE,
        };
        let (_, found) =
            crate::optimize::initialize(&renderer, &paper, &volume.histogram, settings)?;
        let planned = plan(
            volume,
            Some(self),
            Some(&found.control_points),
            &[],
            settings.control_points,
        )?;
        // What the run's exports hold: the points through the LUT the loop samples.
        Ok(planned
            .control_points
            .to_lut(planned.tf.lut_size())
            .to_control_points())
    }

    /// "FILE (preset NAME)", for report.json.
    pub fn describe(&self) -> String {
        format!("{} (preset {})", self.source.display(), self.preset.tf.name)
    }
}

/// The points of a curve that keep it within `tol` of all of them (`tf::simplify_polyline`).
fn simplified<P: Copy, const C: usize>(
    points: &[(f64, P)],
    values: impl Fn(&(f64, P)) -> [f64; C],
    tol: f64,
) -> Vec<(f64, P)> {
    let x: Vec<f64> = points.iter().map(|p| p.0).collect();
    let v: Vec<[f64; C]> = points.iter().map(values).collect();
    crate::tf::simplify_polyline(&x, &v, tol)
        .into_iter()
        .map(|i| points[i])
        .collect()
}

/// The checks of `locks` that need no volume: finite, increasing, not overlapping.
pub fn check_locks(locks: &[[f64; 2]]) -> Result<(), PipelineError> {
    for &[lo, hi] in locks {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(PipelineError::Job(format!(
                "locked range {},{}: must be MIN,MAX with MIN < MAX",
                crate::units::number(lo),
                crate::units::number(hi)
            )));
        }
    }
    let mut sorted = locks.to_vec();
    sorted.sort_by(|a, b| a[0].total_cmp(&b[0]));
    if let Some(w) = sorted.windows(2).find(|w| w[1][0] < w[0][1]) {
        return Err(PipelineError::Job(format!(
            "locked ranges {},{} and {},{} overlap",
            crate::units::number(w[0][0]),
            crate::units::number(w[0][1]),
            crate::units::number(w[1][0]),
            crate::units::number(w[1][1])
        )));
    }
    Ok(())
}

/// The checks that need the volume: every lock inside the data range, the init's range
/// meeting it.
pub fn check_against(
    volume: &Volume,
    init: Option<&InitTf>,
    locks: &[[f64; 2]],
) -> Result<(), PipelineError> {
    let [lo, hi] = volume.norm_range;
    let n = crate::units::number;
    for &[a, b] in locks {
        if a < lo || b > hi {
            return Err(PipelineError::Job(format!(
                "locked range {},{} is outside the data range {}..{}",
                n(a),
                n(b),
                n(lo),
                n(hi)
            )));
        }
        // As the run will see it: narrower than a double resolves within the range.
        if normalized(b, [lo, hi]) <= normalized(a, [lo, hi]) {
            return Err(PipelineError::Job(format!(
                "locked range {},{} is narrower than the data range {}..{} resolves: \
                 widen it",
                n(a),
                n(b),
                n(lo),
                n(hi)
            )));
        }
    }
    if let Some(init) = init.filter(|i| !i.colours_only()) {
        let [a, b] = init.preset.tf.data_range();
        if b < lo || a > hi || (a == b && hi > lo) {
            return Err(PipelineError::Job(format!(
                "{}: preset \"{}\" covers {}..{}, which misses the data range {}..{}",
                init.source.display(),
                init.preset.tf.name,
                n(a),
                n(b),
                n(lo),
                n(hi)
            )));
        }
    }
    Ok(())
}

/// A data value as the run's normalized value, in [0, 1].
fn normalized(v: f64, [lo, hi]: [f64; 2]) -> f64 {
    ((v - lo) / (hi - lo)).clamp(0.0, 1.0)
}

/// A run's start: the control points, the parameterization (with the LUT it samples) and the
/// opacity unit distance of its exports.
pub(crate) struct Planned {
    pub control_points: ControlPoints,
    pub tf: StartTf,
    pub unit_distance: f64,
}

/// The densest opacity a start is represented up to: 1 − 1e-3 (σ is finite; an opacity of 1
/// reads as this, 1e-3 below).
const OPAQUE: f64 = 1.0 - 1e-3;

/// ParaView's table width for a TF with points at data values `xs` over `range` (see
/// [`PARAVIEW_TABLE`]): a power of two, at least 1024, at most 16384.
fn table_width(xs: &[f64], [lo, hi]: [f64; 2]) -> usize {
    let gap = xs
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    let ideal = ((hi - lo) / gap).ceil();
    let ideal = if ideal.is_finite() {
        ideal.min(16384.0) as usize
    } else {
        1
    };
    ideal.next_power_of_two().max(PARAVIEW_TABLE)
}

/// Plan a run that starts from `init`, or from `paper` (the paper's initialization, made by
/// the caller) with `locks`; a colour-only `init` takes its densities from `paper`.
/// `min_points`: the run's control points at least.
pub(crate) fn plan(
    volume: &Volume,
    init: Option<&InitTf>,
    paper: Option<&ControlPoints>,
    locks: &[[f64; 2]],
    min_points: usize,
) -> Result<Planned, PipelineError> {
    check_against(volume, init, locks)?;
    let norm = |v: f64| normalized(v, volume.norm_range);
    let normalized: Vec<Lock> = locks
        .iter()
        .map(|&[a, b]| Lock {
            lo: norm(a),
            hi: norm(b),
        })
        .collect();
    let default_u = crate::tf::default_unit_distance(&volume.geometry);
    let (cp, lut_size, unit_distance) = match (init, paper) {
        (Some(init), Some(paper)) if init.colours_only() => {
            let tf = init.preset.rgb_linear();
            let [a, b] = tf.data_range();
            let spread = |x: f64| if b > a { (x - a) / (b - a) } else { 0.5 };
            let rgb: Vec<(f64, [f64; 3])> =
                tf.rgb_points.iter().map(|&(x, c)| (spread(x), c)).collect();
            let mut x: Vec<f64> = paper.x.clone();
            x.extend(rgb.iter().map(|p| p.0).filter(|t| (0.0..=1.0).contains(t)));
            x.sort_by(f64::total_cmp);
            x.dedup();
            let cp = ControlPoints {
                sigma: x.iter().map(|&t| paper.eval(t)[0]).collect(),
                rgb: x.iter().map(|&t| crate::tf::interpolate(&rgb, t)).collect(),
                x,
            };
            let xs: Vec<f64> = init.preset.tf.rgb_points.iter().map(|p| p.0).collect();
            (cp, table_width(&xs, [a, b]), default_u)
        }
        (Some(init), _) => {
            let tf = init.preset.rgb_linear();
            let u = tf.unit_distance.unwrap_or(default_u);
            // Densities as dense as the start's opacity needs (the paper's 255 at least).
            let highest = tf.opacity_points.iter().map(|p| p.1).fold(0.0, f64::max);
            let sigma_max = crate::tf::opacity_to_sigma_within(
                highest.min(OPAQUE),
                u,
                volume.geometry.longest_side(),
                f64::INFINITY,
            )
            .max(crate::tf::SIGMA_MAX);
            let cp = tf.to_control_points_within(&init.source, volume, None, sigma_max)?;
            let mut xs: Vec<f64> = init.preset.tf.rgb_points.iter().map(|p| p.0).collect();
            xs.extend(tf.opacity_points.iter().map(|p| p.0));
            xs.sort_by(f64::total_cmp);
            (cp, table_width(&xs, volume.norm_range), u)
        }
        (None, Some(paper)) => (paper.clone(), PARAVIEW_TABLE, default_u),
        (None, None) => {
            return Err(PipelineError::Job(
                "a start needs a TF to start from".into(),
            ))
        }
    };
    let sigma_max = cp
        .sigma
        .iter()
        .cloned()
        .fold(crate::tf::SIGMA_MAX, f64::max);
    let (control_points, tf) = start::prepare(&cp, &normalized, min_points, lut_size, sigma_max)
        .map_err(|e| PipelineError::Job(e.to_string()))?;
    Ok(Planned {
        control_points,
        tf,
        unit_distance,
    })
}
