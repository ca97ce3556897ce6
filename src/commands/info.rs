//! `t2tf info`: what a volume file holds, as our renderer will see it.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use serde_json::json;

use crate::units::human_bytes;
use crate::volume::{self, ByteOrder, SourceFormat, Summary, HISTOGRAM_BINS};
use crate::VolumeArgs;

/// Width of the longest histogram bar, in characters.
const BAR_WIDTH: usize = 40;

#[derive(clap::Args, Debug)]
#[command(after_help = "Example:\n  \
    t2tf info ../shared/data/volumes/aneurism_256x256x256_uint8.raw\n  \
    t2tf info scan.bin --dims 512,512,128 --dtype int16 --byte-order big --json")]
pub struct InfoArgs {
    /// Volume file: .raw (NAME_XxYxZ_DTYPE.raw or with --dims/--dtype), .vti or .vtk; or a
    /// time series: .pvd, .series, a quoted pattern such as 'name_*.vti'
    pub volume: PathBuf,
    /// More files of a time series that begins with VOLUME
    #[arg(value_name = "MORE")]
    pub more_volumes: Vec<PathBuf>,
    #[command(flatten)]
    pub read: VolumeArgs,
    #[command(flatten)]
    pub series: crate::SeriesArgs,
    /// Histogram rows (1-256)
    // A negative count reaches the range check (which says what is allowed) instead of clap
    // taking it for a flag.
    #[arg(
        long,
        default_value_t = 32,
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(u16).range(1..=256)
    )]
    pub bins: u16,
    /// Histogram bars proportional to counts (default: to log(1 + count), since most volumes
    /// are dominated by empty space)
    #[arg(long)]
    pub linear: bool,
    /// Print one JSON object instead of text
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: InfoArgs) -> Result<()> {
    let start = Instant::now();
    let mut paths = vec![args.volume.clone()];
    paths.extend(args.more_volumes.iter().cloned());
    if let Some(series) = args.series.series(&paths)? {
        return series_info(&args, &series);
    }
    // Statistics only: no f32 copy and no pyramid, and the file is read as a load reads it
    // (mapped or block by block), so a volume larger than memory can be inspected
    // (volume::summarize).
    let volume = volume::summarize(&args.volume, &args.read.read_options())?;
    args.read.warn_thin(&args.volume, volume.geometry.dims);
    let seconds = start.elapsed().as_secs_f64();
    let file_bytes = std::fs::metadata(&args.volume)
        .map(|m| m.len())
        .unwrap_or(0);
    let rows = histogram_rows(&volume, args.bins as usize);
    let text = if args.json {
        json_report(&args, &volume, file_bytes, &rows, seconds)
    } else {
        text_report(&args, &volume, file_bytes, &rows, seconds)
    };
    crate::out::out(format_args!("{text}"))?;
    Ok(())
}

/// A time series: its steps (time, file, range) and the range over all of them, each step
/// read as `info` reads one file.
fn series_info(args: &InfoArgs, series: &volume::Series) -> Result<()> {
    let n = series.steps.len();
    let stats = series.scan(&args.read.read_options(), &mut |_| {})?;
    let text = if args.json {
        let steps: Vec<_> = series
            .steps
            .iter()
            .zip(&stats.step_ranges)
            .map(|(s, r)| json!({"time": s.time, "path": s.path, "range": r}))
            .collect();
        let v = json!({
            "time_series": {
                "collection": series.collection,
                "total_steps": series.total_steps,
                "steps": steps,
            },
            "range": stats.range,
            "non_finite": stats.non_finite,
        });
        format!("{}\n", serde_json::to_string_pretty(&v)?)
    } else {
        let mut t = String::new();
        let from = series.collection.as_ref().map_or_else(
            || "a list of files".to_string(),
            |c| c.display().to_string(),
        );
        let _ = writeln!(
            t,
            "time series: {n} of {} steps, from {from}",
            series.total_steps
        );
        let _ = writeln!(t, "  {:>5}  {:>14}  {:>27}  file", "step", "time", "range");
        for (i, (s, r)) in series.steps.iter().zip(&stats.step_ranges).enumerate() {
            let range = format!("{} .. {}", r[0], r[1]);
            let _ = writeln!(
                t,
                "  {i:>5}  {:>14}  {range:>27}  {}",
                s.time,
                s.path.display()
            );
        }
        let _ = writeln!(
            t,
            "range over all steps: {} .. {} (one TF covers it)",
            stats.range[0], stats.range[1]
        );
        if stats.non_finite > 0 {
            let _ = writeln!(t, "non-finite values: {} over all steps", stats.non_finite);
        }
        t
    };
    crate::out::out(format_args!("{text}"))?;
    Ok(())
}

/// One histogram row: the data-unit interval [lo, hi) and its voxel count.
struct Row {
    lo: f64,
    hi: f64,
    count: u64,
}

/// Merge the volume's 256 normalized bins into `rows` rows (as even as integer division
/// allows), labelled in data units.
fn histogram_rows(v: &Summary, rows: usize) -> Vec<Row> {
    let rows = rows.clamp(1, HISTOGRAM_BINS);
    (0..rows)
        .map(|r| {
            let (a, b) = (r * HISTOGRAM_BINS / rows, (r + 1) * HISTOGRAM_BINS / rows);
            Row {
                lo: v.denormalize(a as f64 / HISTOGRAM_BINS as f64),
                hi: v.denormalize(b as f64 / HISTOGRAM_BINS as f64),
                count: v.histogram[a..b].iter().sum(),
            }
        })
        .collect()
}

fn format_name(v: &Summary) -> String {
    match &v.source.format {
        SourceFormat::Raw { byte_order, .. } => format!(
            "raw, {}-endian",
            match byte_order {
                ByteOrder::Little => "little",
                ByteOrder::Big => "big",
            }
        ),
        SourceFormat::Vti { array } => format!("VTK XML image data, array '{array}'"),
        SourceFormat::LegacyVtk { array } => {
            format!("legacy VTK structured points, array '{array}'")
        }
    }
}

/// A number for people: shortest form, but no float noise (201.60000000000002 → 201.6) and
/// exponents for very large or small magnitudes.
fn num(x: f64) -> String {
    let a = x.abs();
    if a != 0.0 && !(1e-4..1e12).contains(&a) {
        return format!("{x:e}");
    }
    let short = format!("{x}");
    if short.len() <= 12 {
        return short;
    }
    let fixed = format!("{x:.6}");
    fixed
        .trim_end_matches('0')
        .trim_end_matches('.')
        .to_string()
}

fn triple(v: [f64; 3]) -> String {
    format!("{} {} {}", num(v[0]), num(v[1]), num(v[2]))
}

fn text_report(a: &InfoArgs, v: &Summary, file_bytes: u64, rows: &[Row], secs: f64) -> String {
    let g = &v.geometry;
    let [x, y, z] = g.dims;
    let n = g.voxel_count();
    let level0 = v.level0_bytes as u64;
    let pyramid = v.pyramid_bytes as u64;
    let mut s = String::new();
    let _ = writeln!(s, "file        {}", a.volume.display());
    let _ = writeln!(s, "format      {}", format_name(v));
    let _ = writeln!(s, "dims        {x} x {y} x {z} ({n} points)");
    let _ = writeln!(s, "spacing     {}", triple(g.spacing));
    let _ = writeln!(s, "origin      {}", triple(g.origin));
    let _ = writeln!(s, "box size    {}", triple(g.extent()));
    let _ = writeln!(s, "dtype       {}", v.scalar_type);
    let _ = writeln!(s, "range       {} .. {}", num(v.range[0]), num(v.range[1]));
    let _ = writeln!(
        s,
        "non-finite  {} NaN/Inf voxels (rendered as empty)",
        v.non_finite
    );
    let _ = writeln!(
        s,
        "memory      file {}, values {}; ours: f32 {} + pyramid {}",
        human_bytes(file_bytes as u128),
        human_bytes((n * v.scalar_type.size()) as u128),
        human_bytes(level0 as u128),
        human_bytes(pyramid as u128)
    );
    let dims: Vec<String> = v
        .levels
        .iter()
        .map(|l| format!("{}x{}x{}", l[0], l[1], l[2]))
        .collect();
    let _ = writeln!(
        s,
        "pyramid     {} level(s): {}",
        v.levels.len(),
        dims.join(", ")
    );
    let _ = writeln!(s, "read time   {:.3} s", secs);
    let _ = writeln!(
        s,
        "histogram   {} rows over the range, bars {}",
        rows.len(),
        if a.linear {
            "linear in count"
        } else {
            "linear in log(1 + count)"
        }
    );
    let weight = |c: u64| {
        if a.linear {
            c as f64
        } else {
            (c as f64).ln_1p()
        }
    };
    let top = rows.iter().map(|r| weight(r.count)).fold(0.0, f64::max);
    // About five significant digits of the range width.
    let width_of_range = v.norm_range[1] - v.norm_range[0];
    let decimals = (4.0 - width_of_range.log10().floor()).clamp(0.0, 12.0) as usize;
    let label = |x: f64| format!("{x:.decimals$}");
    let width = rows
        .iter()
        .map(|r| label(r.lo).len().max(label(r.hi).len()))
        .max()
        .unwrap_or(1);
    for r in rows {
        let len = if top > 0.0 {
            (weight(r.count) / top * BAR_WIDTH as f64).round() as usize
        } else {
            0
        };
        // A non-empty bin always shows at least one mark.
        let len = if r.count > 0 { len.max(1) } else { 0 };
        let _ = writeln!(
            s,
            "  {:>width$} .. {:>width$} |{:<BAR_WIDTH$}| {}",
            label(r.lo),
            label(r.hi),
            "#".repeat(len),
            r.count
        );
    }
    s
}

fn json_report(a: &InfoArgs, v: &Summary, file_bytes: u64, rows: &[Row], secs: f64) -> String {
    let g = &v.geometry;
    let level0 = v.level0_bytes;
    let (format, array, byte_order) = match &v.source.format {
        SourceFormat::Raw { byte_order, .. } => (
            "raw",
            None,
            Some(match byte_order {
                ByteOrder::Little => "little",
                ByteOrder::Big => "big",
            }),
        ),
        SourceFormat::Vti { array } => ("vti", Some(array.as_str()), None),
        SourceFormat::LegacyVtk { array } => ("vtk", Some(array.as_str()), None),
    };
    let report = json!({
        "file": a.volume.to_string_lossy(),
        "format": format,
        "array": array,
        "byte_order": byte_order,
        "dims": g.dims,
        "spacing": g.spacing,
        "origin": g.origin,
        "dtype": v.scalar_type.scivis_name(),
        "range": v.range,
        "non_finite": v.non_finite,
        "memory": {
            "file_bytes": file_bytes,
            "value_bytes": g.voxel_count() * v.scalar_type.size(),
            "f32_bytes": level0,
            "pyramid_bytes": v.pyramid_bytes,
        },
        "pyramid": v.levels,
        "read_seconds": secs,
        "histogram": rows.iter().map(|r| json!({"lo": r.lo, "hi": r.hi, "count": r.count}))
            .collect::<Vec<_>>(),
    });
    format!("{report:#}\n")
}

// Test boilerplate alike in shape to units.rs's tests (one `use super::x` and asserts).
#[cfg(test)]
mod tests {
    use super::num;

    #[test]
    fn numbers_print_without_float_noise() {
        assert_eq!(num(201.60000000000002), "201.6");
        assert_eq!(num(3.2), "3.2");
        assert_eq!(num(-30.5), "-30.5");
        assert_eq!(num(0.0), "0");
        assert_eq!(num(1e10), "10000000000");
        assert_eq!(num(1e300), "1e300");
        assert_eq!(num(2.5e-7), "2.5e-7");
    }
}
