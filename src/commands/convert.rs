//! `t2tf convert`: a transfer function from one file format to another, optionally moved to
//! a new data range.

use std::path::PathBuf;

use crate::formats::{
    extension_list, format_of, list_presets, read_preset_within, write_preset, PointCounts,
};

/// Convert a transfer function between ParaView JSON (.json), ParaView XML (.xml) and VisIt
/// colour tables (.ct); the formats follow the file extensions.
#[derive(clap::Args, Debug)]
// clap writes an optional positional as [OUTPUT]; it is required unless --list.
#[command(
    override_usage = "t2tf convert [OPTIONS] <INPUT> <OUTPUT>\n       t2tf convert --list <INPUT>"
)]
#[command(after_help = "Examples:\n  \
    t2tf convert out/neghip.json neghip.ct\n  \
    t2tf convert preset.json preset_12bit.json --rescale 0,4095\n\n\
    Colours and opacity convert exactly between .json and .xml; .ct holds 8-bit colours and \
    alpha. ParaView's XML import reads only the colours; use the .json for opacity.")]
pub struct ConvertArgs {
    /// Input transfer function (.json, .xml or .ct).
    #[arg(help = format!("Input transfer function ({})", extension_list()))]
    pub input: PathBuf,
    /// Output file; its extension picks the format (.json, .xml or .ct). Required unless
    /// --list.
    #[arg(
        required_unless_present = "list",
        help = format!(
            "Output file (required unless --list); its extension picks the format ({})",
            extension_list()
        )
    )]
    pub output: Option<PathBuf>,
    /// The preset to convert from a file holding several (see --list).
    #[arg(long, value_name = "NAME")]
    pub preset: Option<String>,
    /// List the presets of INPUT (name, colour space, points) and exit.
    #[arg(long)]
    pub list: bool,
    /// Name of the written preset (default: the input preset's own name).
    #[arg(long, value_name = "NAME")]
    pub name: Option<String>,
    /// Map the TF's data range linearly onto MIN,MAX (data units).
    #[arg(long, value_name = "MIN,MAX", value_parser = parse_range, allow_hyphen_values = true)]
    pub rescale: Option<Range>,
    #[command(flatten)]
    pub preset_file: crate::PresetFileArgs,
}

/// A data range given on the command line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// Lower end (data units).
    pub min: f64,
    /// Upper end, above `min`.
    pub max: f64,
}

fn parse_range(s: &str) -> Result<Range, String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("\"{s}\" is not MIN,MAX"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("\"{v}\" is not a finite number"))
    };
    let (min, max) = (num(a)?, num(b)?);
    if min >= max {
        return Err(format!("MIN ({min}) must be below MAX ({max})"));
    }
    Ok(Range { min, max })
}

/// `--list`: one line per preset (name, colour space and, where the format counts them,
/// colour and opacity points).
fn list(input: &std::path::Path, max_size: u64) -> anyhow::Result<()> {
    for s in list_presets(input, max_size)? {
        let kind = s
            .space
            .unwrap_or_else(|| "categorical (not convertible)".into());
        match s.counts {
            Some(c) => outln!(
                "{}\t{kind}\t{} colour points\t{} opacity points",
                s.name,
                c.colour,
                c.opacity
            )?,
            None => outln!("{}\t{kind}", s.name)?,
        }
    }
    Ok(())
}

/// Run `t2tf convert`: list, or read, optionally rescale, and write.
pub fn run(args: ConvertArgs) -> anyhow::Result<()> {
    if args.list {
        return list(&args.input, args.preset_file.limit());
    }
    let output = args.output.expect("clap requires OUTPUT without --list");
    // Check the output's format before reading, so a typo fails fast.
    format_of(&output)?;
    crate::fs::check_writable(&output)?;
    let limit = args.preset_file.limit();
    let mut preset = read_preset_within(&args.input, args.preset.as_deref(), limit)?;
    if let Some(r) = args.rescale {
        preset.tf = preset.tf.rescaled(r.min, r.max);
        // A width beyond f64 (e.g. -1e308,1e308) turns points into inf or NaN.
        let tf = &preset.tf;
        let [lo, hi] = tf.data_range();
        let finite = tf.rgb_points.iter().all(|p| p.0.is_finite())
            && tf.opacity_points.iter().all(|p| p.0.is_finite());
        if !(lo.is_finite() && hi.is_finite() && finite) {
            anyhow::bail!(
                "--rescale {},{}: the range is too wide to represent (MAX - MIN overflows); give a narrower one",
                r.min,
                r.max
            );
        }
    }
    if let Some(name) = args.name {
        if name.trim().is_empty() {
            anyhow::bail!("--name is empty: give the preset a name");
        }
        preset.tf.name = name;
    }
    // Errors from here name the output file already.
    write_preset(&output, &preset)?;
    let tf = &preset.tf;
    let [lo, hi] = tf.data_range();
    // Counted as `--list` counts the input's presets.
    let counts = PointCounts::of(tf);
    outln!(
        "wrote {} ({}, {}: {} colour points, {} opacity points, data range {lo} to {hi})",
        output.display(),
        preset.space.paraview_name(),
        tf.name,
        counts.colour,
        counts.opacity
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_ranges() {
        assert_eq!(
            parse_range("-1,2.5"),
            Ok(Range {
                min: -1.0,
                max: 2.5
            })
        );
        assert!(parse_range("3,1").unwrap_err().contains("below"));
        assert!(parse_range("1").is_err());
        assert!(parse_range("a,1").unwrap_err().contains("\"a\""));
        assert!(parse_range("0,inf").is_err());
    }
}
