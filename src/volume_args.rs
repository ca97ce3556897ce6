//! Flags shared by every command that reads a volume (`#[command(flatten)]` them).

use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::memory::Budget;
use crate::volume::{
    self, is_series_path, ByteOrder, ReadOptions, ScalarType, Series, TimeSelection, Volume,
    VolumeError,
};

/// How to read a volume file. `.vti` and `.vtk` files describe themselves; a `.raw` file
/// named `NAME_XxYxZ_DTYPE.raw` does too, other raw files need `--dims` and `--dtype`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct VolumeArgs {
    /// Raw files: points per axis, x fastest (overrides the file name)
    // Hyphen values reach the parser, which says what is wrong with a negative one (clap
    // would take `-2,1,1` for a flag).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_dims, allow_hyphen_values = true)]
    pub dims: Option<[usize; 3]>,
    /// Raw files: scalar type: uint8, int8, uint16, int16, uint32, int32, float32, float64
    /// (also uint64, int64)
    #[arg(long, value_name = "TYPE", value_parser = ScalarType::from_str)]
    pub dtype: Option<ScalarType>,
    /// Grid spacing per axis (raw files: default 1,1,1; other files: replaces theirs)
    #[arg(long, value_name = "A,B,C", value_parser = parse_spacing, allow_hyphen_values = true)]
    pub spacing: Option<[f64; 3]>,
    /// Raw files: byte order of the values (default little)
    #[arg(long, value_name = "little|big", value_parser = ByteOrder::from_str)]
    pub byte_order: Option<ByteOrder>,
    /// .vti/.vtk files: the point-data array to read (default: the active scalars, else the
    /// first array)
    #[arg(long, value_name = "NAME")]
    pub array: Option<String>,
}

/// Which steps of a time series to use (`#[command(flatten)]` into the commands that read
/// one: `info`, `optimize`).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct SeriesArgs {
    /// Time series: use the steps whose time is in T0..T1 (inclusive)
    #[arg(long, value_name = "T0,T1", value_parser = parse_time_range, allow_hyphen_values = true)]
    pub time_range: Option<[f64; 2]>,
    /// Time series: use these steps, by index (0 = first), e.g. 0,4,8
    #[arg(long, value_name = "I,J,...", value_delimiter = ',', num_args = 1..)]
    pub time_steps: Option<Vec<usize>>,
}

impl VolumeArgs {
    /// The reader settings these flags give, within what the system has.
    pub fn read_options(&self) -> ReadOptions {
        self.read_options_within(Budget::system())
    }

    /// The reader settings these flags give, within `budget`.
    pub fn read_options_within(&self, budget: Budget) -> ReadOptions {
        ReadOptions {
            dims: self.dims,
            dtype: self.dtype,
            spacing: self.spacing,
            byte_order: self.byte_order,
            array: self.array.clone(),
            budget,
            norm_range: None,
        }
    }

    /// Read and normalize the volume at `path` with these flags, within `budget`.
    pub fn load_within(
        &self,
        path: &Path,
        budget: Budget,
    ) -> Result<Volume, crate::volume::VolumeError> {
        let v = volume::load(path, &self.read_options_within(budget))?;
        self.warn_thin(path, v.geometry.dims);
        Ok(v)
    }

    /// Warn when an axis has one point.
    pub fn warn_thin(&self, path: &Path, dims: [usize; 3]) {
        let thin: Vec<&str> = ["x", "y", "z"]
            .into_iter()
            .zip(dims)
            .filter(|&(_, n)| n == 1)
            .map(|(axis, _)| axis)
            .collect();
        if !thin.is_empty() {
            // Said, since a slab seen edge-on shows almost nothing (docs: ARCHITECTURE.md).
            errln!(
                "t2tf: warning: {} has one point along {}: it is drawn as a slab one spacing thick",
                path.display(),
                thin.join(" and ")
            );
        }
    }
}

impl SeriesArgs {
    /// The time series `paths` name (a `.pvd` or `.series` file, a glob pattern, or several
    /// files), with `--time-range`/`--time-steps` applied; `None` for one volume file (where
    /// those flags are an error).
    pub fn series(&self, paths: &[PathBuf]) -> Result<Option<Series>, VolumeError> {
        let is_series = paths.len() > 1 || paths.first().is_some_and(|p| is_series_path(p));
        if !is_series {
            if self.time_range.is_some() || self.time_steps.is_some() {
                let path = paths.first().map_or(Path::new(""), PathBuf::as_path);
                return Err(VolumeError::file(
                    path,
                    "--time-range and --time-steps select steps of a time series (a .pvd or \
                     .series file, a pattern such as 'name_*.vti', or several files); this is \
                     one volume",
                ));
            }
            return Ok(None);
        }
        let series = Series::open(paths)?;
        let selection = TimeSelection {
            range: self.time_range,
            indices: self.time_steps.clone(),
        };
        Ok(Some(series.select(&selection)?))
    }
}

/// Three comma-separated values, e.g. "256,256,99".
fn parse_triple<T: FromStr>(s: &str, what: &str) -> Result<[T; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated {what} like 1,2,3, got '{s}'"
        ));
    }
    let mut out = Vec::with_capacity(3);
    for p in parts {
        out.push(
            p.parse::<T>()
                .map_err(|_| format!("'{p}' in '{s}' is not {what}"))?,
        );
    }
    out.try_into()
        .map_err(|_| format!("expected three {what}, got '{s}'"))
}

fn parse_time_range(s: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [a, b] = parts[..] else {
        return Err(format!("expected two times T0,T1, got '{s}'"));
    };
    let t = |p: &str| {
        p.parse::<f64>()
            .ok()
            .filter(|t| t.is_finite())
            .ok_or_else(|| format!("'{p}' in '{s}' is not a finite number"))
    };
    let (t0, t1) = (t(a)?, t(b)?);
    if t0 > t1 {
        return Err(format!("T0 must not exceed T1, got '{s}'"));
    }
    Ok([t0, t1])
}

fn parse_dims(s: &str) -> Result<[usize; 3], String> {
    let d = parse_triple::<usize>(s, "whole numbers")?;
    if d.contains(&0) {
        return Err(format!("dimensions '{s}' contain a zero"));
    }
    Ok(d)
}

fn parse_spacing(s: &str) -> Result<[f64; 3], String> {
    let v = parse_triple::<f64>(s, "numbers")?;
    if v.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
        return Err(format!("spacing '{s}' must be positive finite numbers"));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_triples_with_clear_errors() {
        assert_eq!(parse_dims("256, 256,99").unwrap(), [256, 256, 99]);
        assert!(parse_dims("1,2").unwrap_err().contains("three"));
        assert!(parse_dims("1,x,3").unwrap_err().contains("'x'"));
        assert!(parse_dims("1,0,3").unwrap_err().contains("zero"));
        assert!(parse_dims("1,-2,3").is_err());
        assert_eq!(parse_spacing("0.5,1,2e0").unwrap(), [0.5, 1.0, 2.0]);
        assert!(parse_spacing("1,0,1").is_err());
        assert!(parse_spacing("1,nan,1").is_err());
        assert!(parse_spacing("1,inf,1").is_err());
    }
}
