//! `t2tf render`: one view, or a sheet of orbiting views, of a volume with a TF preset.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use crate::background;
use crate::camera::{Camera, Orbit, UpAxis};
use crate::formats::{preset_lut, read_preset_within, ExportTf, Preset, Sampling, LUT_SIZE};
use crate::memory::Budget;
use crate::optimize::Settings;
use crate::pipeline::InitTf;
use crate::render::{CpuBackend, RenderOptions, FINAL_LEVEL, FINAL_STEP};
use crate::volume::Volume;
use crate::VolumeArgs;
use t2tf::tf::Lut;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    t2tf render ../shared/data/volumes/neghip_64x64x64_uint8.raw --tf out/neghip.json --out view.png\n  \
    t2tf render head.vti --tf bone.json --out sheet.png --orbit 8 --size 256 --up -z\n\n\
    The preset's opacity is read with its own ScalarOpacityUnitDistance (t2tf writes it into \
    every file) or --unit-distance; without either, the volume's mean voxel spacing. A colour \
    map without opacity (a ParaView library preset such as \"Cool to Warm\") is drawn with the \
    densities `t2tf optimize --init` starts it from: the paper's initial ones.")]
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
    #[arg(long, default_value_t = 2.5, allow_negative_numbers = true)]
    pub distance: f64,
    /// World axis pointing up on screen: x, y, z, -x, -y or -z.
    #[arg(long, default_value = "z", allow_hyphen_values = true)]
    pub up: UpAxis,
    /// Image width and height in pixels (one view), 1 to 8192.
    // Signed, as are the other whole numbers: a negative one reaches `run`'s check, which says
    // what is allowed, instead of clap taking it for a flag.
    #[arg(long, default_value_t = 512, allow_negative_numbers = true)]
    pub size: i64,
    /// Background: gray, gray:V, white, black, checkerboard, noise, fourier.
    #[arg(long, default_value = "gray:0.3")]
    pub background: String,
    /// Seed for random backgrounds.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub seed: i128,
    /// Step between samples in voxels of the rendered mip level. The default is for final
    /// pictures: ≥ 37.6 dB from 1/8-voxel sampling on the shared volumes (BENCHMARKS.md).
    #[arg(long, default_value_t = FINAL_STEP, allow_negative_numbers = true)]
    pub step_size: f32,
    /// Mip level to render (0 = full resolution; coarser levels are faster and blurrier).
    #[arg(long, default_value_t = FINAL_LEVEL as i64, allow_negative_numbers = true)]
    pub level: i64,
    /// ScalarOpacityUnitDistance to read the preset's opacity with (world units).
    #[arg(long, allow_negative_numbers = true)]
    pub unit_distance: Option<f64>,
    /// Sample the TF as ParaView's GPU volume mapper does instead of exactly: through a table
    /// of at least 1024 entries over the data range, opacities corrected to the sample
    /// distance per entry and interpolated between entries, so the picture predicts
    /// ParaView's (README, `t2tf render`).
    #[arg(long)]
    pub paraview_lut: bool,
    /// Render N views on a ring (yaw evenly spaced, same pitch and distance) into one sheet.
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    pub orbit: Option<i64>,
    /// Memory budget for sizes read from files and flags (e.g. 512M, 16G); default: what the
    /// system has available.
    #[arg(long, value_name = "SIZE", value_parser = crate::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
    #[command(flatten)]
    pub preset_file: crate::PresetFileArgs,
}

/// The images `--size` and `--orbit` ask for must fit the memory budget before any is made:
/// each view (RGB f32, and its transmittance) and the sheet that tiles them.
fn check_image_memory(budget: Budget, size: usize, orbit: Option<usize>) -> Result<()> {
    let views = orbit.unwrap_or(1);
    let cols = (views as f64).sqrt().ceil() as usize;
    let cells = cols.checked_mul(views.div_ceil(cols.max(1)));
    let pixels = cells.and_then(|c| crate::memory::product(&[c, size, size]));
    budget.check(
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

/// The whole-number flags, checked.
struct Counts {
    size: usize,
    seed: u64,
    level: usize,
    orbit: Option<usize>,
}

fn check_counts(args: &RenderArgs) -> Result<Counts> {
    let size = usize::try_from(args.size)
        .ok()
        .filter(|s| (1..=8192).contains(s))
        .with_context(|| format!("--size {} must be between 1 and 8192", args.size))?;
    let seed = u64::try_from(args.seed).ok().with_context(|| {
        format!(
            "--seed {} must be a whole number from 0 to {}",
            args.seed,
            u64::MAX
        )
    })?;
    let level = usize::try_from(args.level)
        .ok()
        .with_context(|| format!("--level {} must be 0 or more", args.level))?;
    let orbit = match args.orbit {
        None => None,
        Some(n) => Some(
            usize::try_from(n)
                .ok()
                .filter(|&n| n > 0)
                .with_context(|| format!("--orbit {n}: needs at least one view"))?,
        ),
    };
    if !(args.step_size.is_finite() && args.step_size > 0.0) {
        bail!("--step-size {} must be a positive number", args.step_size);
    }
    if !(args.distance.is_finite() && args.distance > 0.0) {
        bail!("--distance {} must be a positive number", args.distance);
    }
    if let Some(u) = args.unit_distance.filter(|u| !(u.is_finite() && *u > 0.0)) {
        bail!("--unit-distance {u} must be a positive number");
    }
    Ok(Counts {
        size,
        seed,
        level,
        orbit,
    })
}

/// Input size of the default CLIP model (ViT-B/32): a colour-only preset's densities are those
/// a default `optimize --init` run starts from, whose start view is rendered at this size.
const DEFAULT_CLIP_SIZE: usize = 224;

/// The LUT of a preset without opacity (a ParaView colour map such as "Cool to Warm"): its
/// colours over the densities `optimize --init` starts such a preset from, the paper's initial
/// ones with the default settings, said on stderr.
fn colours_only_lut(
    args: &RenderArgs,
    preset: Preset,
    volume: &Volume,
    sampling: Sampling,
    budget: Budget,
) -> Result<Lut> {
    errln!(
        "t2tf: note: preset \"{}\" has no opacity: drawn with the paper's initial densities, as \
         `t2tf optimize --init` starts from it",
        preset.tf.name
    );
    let settings = Settings::default()
        .validate()
        .map_err(crate::flags::optimize)?;
    let init = InitTf::new(preset, args.tf.clone()).map_err(crate::flags::pipeline)?;
    let cp = init
        .colours_only_points(volume, &settings, DEFAULT_CLIP_SIZE, args.up, budget)
        .map_err(crate::flags::pipeline)?;
    Ok(match sampling {
        Sampling::Exact => cp.to_lut(LUT_SIZE),
        // What ParaView draws of the TF an optimize run writes for this start.
        Sampling::ParaView { .. } => {
            let tf = ExportTf::from_control_points(&init.preset.tf.name, &cp, volume, None);
            preset_lut(&Preset::rgb(tf), &args.tf, volume, None, sampling)?
        }
    })
}

pub fn run(args: RenderArgs) -> Result<()> {
    check_png_name(&args.out)?;
    let Counts {
        size,
        seed,
        level: level_index,
        orbit,
    } = check_counts(&args)?;
    let budget = Budget::new(args.max_memory);
    check_image_memory(budget, size, orbit)?;
    // Before any work: the name is free or a regular file, and its folder takes new files.
    crate::fs::check_writable(&args.out)?;
    let volume = args
        .read
        .load_within(&args.volume, budget)
        .map_err(crate::flags::volume)?;
    // Colours interpolated in the preset's own space (HSV, Lab, Diverging, …) become RGB
    // segments within the export tolerance, as the renderer's LUT needs.
    let limit = args.preset_file.limit();
    let preset = read_preset_within(&args.tf, args.preset.as_deref(), limit)?;
    let level = volume.levels.get(level_index).with_context(|| {
        format!(
            "--level {level_index}: this volume has levels 0..={}",
            volume.levels.len() - 1
        )
    })?;
    let sampling = if args.paraview_lut {
        let voxel = level.spacing.iter().copied().fold(f64::INFINITY, f64::min);
        Sampling::ParaView {
            sample_distance: args.step_size as f64 * voxel,
        }
    } else {
        Sampling::Exact
    };
    let lut = if preset.tf.opacity_points.is_empty() {
        colours_only_lut(&args, preset, &volume, sampling, budget)?
    } else {
        preset_lut(&preset, &args.tf, &volume, args.unit_distance, sampling)?
    };
    let backend = CpuBackend::new(budget);
    let bg = background::from_name(&args.background, size, size, seed).context("--background")?;
    let opts = RenderOptions {
        step: args.step_size,
        level: Some(level_index),
        ..RenderOptions::final_quality()
    };
    let (pitch, distance) = (args.pitch.to_radians(), args.distance);
    let image = match orbit {
        Some(n) => {
            let cams = Camera::ring(&volume.geometry, n, pitch, distance, args.up)?;
            backend.orbit_sheet(&volume, &lut, &cams, &bg, &opts)?
        }
        None => {
            let orbit = Orbit {
                yaw: args.yaw.to_radians(),
                pitch,
                distance,
                up: args.up,
            };
            let cam = Camera::orbit(&volume.geometry, orbit)?;
            backend.render(&volume, &lut, &cam, &bg, &opts)?.image
        }
    };
    image.save_png(&args.out)?;
    errln!(
        "wrote {} ({}x{})",
        args.out.display(),
        image.width,
        image.height
    );
    Ok(())
}
