//! Every real volume in ../shared/data/volumes loads with the dims, type, spacing and value
//! range that PROVENANCE.md records.

use std::path::Path;

use t2tf::volume::{self, ReadOptions, ScalarType};

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/volumes");

/// One row of PROVENANCE.md's table, plus the "N–M" value range from the file's section
/// (absent for cthead, whose section states none).
struct Entry {
    file: String,
    dims: [usize; 3],
    dtype: ScalarType,
    spacing: [f64; 3],
    range: Option<[f64; 2]>,
}

fn provenance() -> Vec<Entry> {
    let text = std::fs::read_to_string(Path::new(DIR).join("PROVENANCE.md"))
        .expect("../shared/data/volumes/PROVENANCE.md must exist beside the repository");
    let mut out = Vec::new();
    for line in text.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        // | file | dims | dtype | bytes | spacing | kind |
        if cells.len() < 7 || !cells[1].ends_with(".raw") {
            continue;
        }
        let dims: Vec<usize> = cells[2].split('×').map(|d| d.parse().unwrap()).collect();
        let spacing: Vec<f64> = cells[5]
            .split_whitespace()
            .map(|s| s.parse().unwrap())
            .collect();
        let file = cells[1].to_string();
        // The section "## file" mentions the range as "0–255" (en dash).
        let section = text
            .split(&format!("## {file}"))
            .nth(1)
            .and_then(|s| s.split("\n## ").next())
            .unwrap_or("");
        let range = section.split_whitespace().find_map(|w| {
            let w = w.trim_matches(|c: char| !c.is_ascii_digit());
            let (a, b) = w.split_once('–')?;
            Some([a.parse().ok()?, b.parse().ok()?])
        });
        out.push(Entry {
            file,
            dims: dims.try_into().unwrap(),
            dtype: cells[3].parse().unwrap(),
            spacing: spacing.try_into().unwrap(),
            range,
        });
    }
    out
}

#[test]
fn every_shared_volume_matches_provenance() {
    let entries = provenance();
    let on_disk: Vec<String> = std::fs::read_dir(DIR)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".raw"))
        .collect();
    assert_eq!(
        entries.len(),
        on_disk.len(),
        "PROVENANCE.md lists every file"
    );
    assert!(entries.len() >= 7);
    // Every section but cthead's states its range: the parser must have found them.
    assert!(entries.iter().filter(|e| e.range.is_some()).count() >= 6);
    for e in &entries {
        let path = Path::new(DIR).join(&e.file);
        let opts = ReadOptions {
            spacing: Some(e.spacing),
            ..Default::default()
        };
        let v = volume::load(&path, &opts).unwrap_or_else(|err| panic!("{err}"));
        assert_eq!(v.dims(), e.dims, "{}", e.file);
        assert_eq!(v.scalar_type, e.dtype, "{}", e.file);
        assert_eq!(v.geometry.spacing, e.spacing, "{}", e.file);
        assert_eq!(v.non_finite, 0);
        assert!(v.range[1] > v.range[0], "{}: constant?", e.file);
        if let Some(r) = e.range {
            assert_eq!(v.range, r, "{}: range", e.file);
        }
        assert_eq!(v.histogram.iter().sum::<u64>() as usize, v.data().len());
        assert!(v.data().iter().all(|x| (0.0..=1.0).contains(x)));
    }
}
