//! `t2tf render`: one view, or a sheet of orbiting views, of a volume with a TF preset.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use crate::background;
use crate::camera::{Camera, Orbit, UpAxis};
use crate::cli::VolumeArgs;
use crate::formats::read_preset;
use crate::render::{self, RenderOptions, FINAL_LEVEL, FINAL_STEP};

/// Number of LUT entries the CLI renders with (the optimizer uses the same).
pub const LUT_SIZE: usize = 1024;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    t2tf render ../shared/data/volumes/neghip_64x64x64_uint8.raw --tf out/neghip.json --out view.png\n  \
    t2tf render head.vti --tf bone.json --out sheet.png --orbit 8 --size 256 --up -z\n\n\
    The preset's opacity is read with its own ScalarOpacityUnitDistance (t2tf writes it into \
    every file) or --unit-distance; without either, the volume's mean voxel spacing.")]
pub struct RenderArgs {
    /// Volume file (.raw, .vti, .vtk).
    pub volume: PathBuf,
    #[command(flatten)]
    pub read: VolumeArgs,
    /// Transfer function: ParaView JSON preset (.json), ParaView XML (.xml) or VisIt (.ct).
    #[arg(long, value_name = "PRESET")]
    pub tf: PathBuf,
    /// Which preset of a file that holds several (`t2tf convert --list FILE` lists them).
    #[arg(long, value_name = "NAME")]
    pub preset: Option<String>,
    /// Output PNG (the name must end in .png).
    #[arg(long, value_name = "IMG.png")]
    pub out: PathBuf,
    /// Camera yaw around the up axis, degrees.
    #[arg(long, default_value_t = 30.0, allow_negative_numbers = true)]
    pub yaw: f64,
    /// Camera pitch above the orbit plane, degrees (the optimizer samples ±12.9°).
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
    pub pitch: f64,
    /// Camera distance from the box centre in bounding radii (the optimizer samples 2 to 4).
    #[arg(long, default_value_t = 2.5)]
    pub distance: f64,
    /// World axis pointing up on screen: x, y, z, -x, -y or -z.
    #[arg(long, default_value = "z", allow_hyphen_values = true)]
    pub up: UpAxis,
    /// Image width and height in pixels (one view).
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Background: gray, gray:V, white, black, checkerboard, noise, fourier.
    #[arg(long, default_value = "gray:0.3")]
    pub background: String,
    /// Seed for random backgrounds.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Step between samples in voxels of the rendered mip level. The default is for final
    /// pictures: ≥ 37.6 dB from 1/8-voxel sampling on the shared volumes (BENCHMARKS.md).
    #[arg(long, default_value_t = FINAL_STEP)]
    pub step_size: f32,
    /// Mip level to render (0 = full resolution; coarser levels are faster and blurrier).
    #[arg(long, default_value_t = FINAL_LEVEL)]
    pub level: usize,
    /// ScalarOpacityUnitDistance to read the preset's opacity with (world units).
    #[arg(long)]
    pub unit_distance: Option<f64>,
    /// Sample the TF as ParaView's GPU volume mapper does instead of exactly: through a table
    /// of at least 1024 entries over the data range, opacities corrected to the sample
    /// distance per entry and interpolated between entries, so the picture predicts
    /// ParaView's (README, `t2tf render`).
    #[arg(long)]
    pub paraview_lut: bool,
    /// Render N views on a ring (yaw evenly spaced, same pitch and distance) into one sheet.
    #[arg(long, value_name = "N")]
    pub orbit: Option<usize>,
    /// Memory budget for sizes read from files and flags (e.g. 512M, 16G); default: what the
    /// system has available.
    #[arg(long, value_name = "SIZE", value_parser = crate::memory::parse_size)]
    pub max_memory: Option<u64>,
}

/// The images `--size` and `--orbit` ask for must fit the memory budget before any is made:
/// each view (RGB f32, and its transmittance) and the sheet that tiles them.
fn check_image_memory(size: usize, orbit: Option<usize>) -> Result<()> {
    let views = orbit.unwrap_or(1);
    let cols = (views as f64).sqrt().ceil() as usize;
    let cells = cols.checked_mul(views.div_ceil(cols.max(1)));
    let pixels = cells.and_then(|c| crate::memory::product(&[c, size, size]));
    crate::memory::check(
        format!("{views} view(s) of {size}×{size} pixels"),
        pixels,
        // each view's RGB and transmittance, the sheet's RGB, the 8-bit PNG row data
        16 + 12 + 3,
        "lower --size or --orbit",
    )?;
    Ok(())
}

/// `t2tf render` writes PNG only: refuse another extension before any work, rather than
/// write PNG bytes under a name that promises JPEG.
fn check_png_name(out: &Path) -> Result<()> {
    let ext = out.extension().and_then(|e| e.to_str());
    if ext.is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        return Ok(());
    }
    let what = ext.map_or("no extension".to_string(), |e| format!("extension .{e}"));
    bail!(
        "{}: --out must end in .png (t2tf render writes PNG images only; {what} given)",
        out.display()
    )
}

pub fn run(args: RenderArgs) -> Result<()> {
    check_png_name(&args.out)?;
    if args.size == 0 || args.size > 8192 {
        bail!("--size {} must be between 1 and 8192", args.size);
    }
    if !(args.step_size.is_finite() && args.step_size > 0.0) {
        bail!("--step-size {} must be a positive number", args.step_size);
    }
    crate::memory::set_limit(args.max_memory);
    check_image_memory(args.size, args.orbit)?;
    // Before any work: the name is free or a regular file, and its folder takes new files.
    crate::fs::check_writable(&args.out)?;
    let volume = args.read.load(&args.volume)?;
    // Colours interpolated in the preset's own space (HSV, Lab, Diverging, …) become RGB
    // segments within the export tolerance, as the renderer's LUT needs.
    let preset = read_preset(&args.tf, args.preset.as_deref())?;
    let tf = preset.rgb_linear();
    let cp = tf.to_control_points(&args.tf, &volume, args.unit_distance)?;
    let level = volume.levels.get(args.level).with_context(|| {
        format!(
            "--level {}: this volume has levels 0..={}",
            args.level,
            volume.levels.len() - 1
        )
    })?;
    let lut = if args.paraview_lut {
        let u = args
            .unit_distance
            .or(tf.unit_distance)
            .unwrap_or_else(|| crate::tf::default_unit_distance(&volume.geometry));
        let voxel = level.spacing.iter().copied().fold(f64::INFINITY, f64::min);
        let tables = ParaViewTables::new(&preset, &tf, volume.norm_range, u);
        tables.lut(
            args.step_size as f64 * voxel,
            volume.geometry.longest_side(),
        )
    } else {
        cp.to_lut(LUT_SIZE)
    };
    let bg = background::from_name(&args.background, args.size, args.size, args.seed)
        .context("--background")?;
    let opts = RenderOptions {
        step: args.step_size,
        level: Some(args.level),
        ..RenderOptions::final_quality()
    };
    let (pitch, distance) = (args.pitch.to_radians(), args.distance);
    let image = match args.orbit {
        Some(0) => bail!("--orbit needs at least one view"),
        Some(n) => {
            let cams = Camera::ring(&volume.geometry, n, pitch, distance, args.up)?;
            render::orbit_sheet(&volume, &lut, &cams, &bg, &opts)?
        }
        None => {
            let orbit = Orbit {
                yaw: args.yaw.to_radians(),
                pitch,
                distance,
                up: args.up,
            };
            let cam = Camera::orbit(&volume.geometry, orbit)?;
            render::forward(&volume, &lut, &cam, &bg, &opts)?.image
        }
    };
    image.save_png(&args.out)?;
    eprintln!(
        "wrote {} ({}x{})",
        args.out.display(),
        image.width,
        image.height
    );
    Ok(())
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
struct ParaViewTables {
    /// Opacity per unit distance, one per entry.
    opacity: Vec<f64>,
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

/// Piecewise-linear interpolation through `points` (ascending x), ends clamped.
fn interp<const N: usize>(points: &[(f64, [f64; N])], x: f64) -> [f64; N] {
    let Some(first) = points.first() else {
        return [0.0; N];
    };
    if x <= first.0 {
        return first.1;
    }
    for w in points.windows(2) {
        let ((x0, a), (x1, b)) = (w[0], w[1]);
        if x <= x1 {
            let f = if x1 > x0 { (x - x0) / (x1 - x0) } else { 1.0 };
            return std::array::from_fn(|c| a[c] + f * (b[c] - a[c]));
        }
    }
    points[points.len() - 1].1
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
    fn new(
        preset: &crate::formats::Preset,
        rgb_linear: &crate::formats::ExportTf,
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
            opacity: (0..w_op).map(|i| interp(&op, at(i, w_op))[0]).collect(),
            rgb: (0..w_rgb)
                .map(|i| interp(&rgb_linear.rgb_points, at(i, w_rgb)))
                .collect(),
            unit_distance,
        }
    }

    /// The renderer's LUT for samples `delta` apart (world units) in a box of longest side
    /// `longest`.
    fn lut(&self, delta: f64, longest: f64) -> crate::tf::Lut {
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
        crate::tf::Lut { entries }
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
