//! Time series: `.pvd` and `.series` collections, file lists, selection, the streamed
//! statistics, and steps normalized over the series' range.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use t2tf::volume::{load, ReadOptions, Series, TimeSelection, HISTOGRAM_BINS};

/// Three 6×5×4 uint8 steps whose values drift upward: step s holds 10·s + (i % 50).
fn write_steps(dir: &Path) -> Vec<PathBuf> {
    (0..3)
        .map(|s| {
            let bytes: Vec<u8> = (0..120).map(|i| (10 * s + i % 50) as u8).collect();
            let path = dir.join(format!("drift_{s}_6x5x4_uint8.raw"));
            std::fs::write(&path, bytes).unwrap();
            path
        })
        .collect()
}

fn pvd(entries: &[(&str, &str, &str)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n<Collection>\n",
    );
    for (t, part, file) in entries {
        s += &format!("<DataSet timestep=\"{t}\" part=\"{part}\" file=\"{file}\"/>\n");
    }
    s + "</Collection>\n</VTKFile>\n"
}

#[test]
fn a_pvd_lists_its_steps_in_time_order_relative_to_itself() {
    let dir = tempfile::tempdir().unwrap();
    let files = write_steps(dir.path());
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    // Listed out of order: the series is in time order.
    let text = pvd(&[
        ("2.5", "0", &names[2]),
        ("0.5", "0", &names[0]),
        ("1.5", "0", &names[1]),
    ]);
    let path = dir.path().join("drift.pvd");
    std::fs::write(&path, text).unwrap();
    let s = Series::open(std::slice::from_ref(&path)).unwrap();
    assert_eq!(s.collection.as_deref(), Some(path.as_path()));
    assert_eq!(
        s.steps.iter().map(|s| s.time).collect::<Vec<_>>(),
        [0.5, 1.5, 2.5]
    );
    assert_eq!(
        s.steps.iter().map(|s| s.path.clone()).collect::<Vec<_>>(),
        files
    );
    assert!(s.is_whole());
}

#[test]
fn a_series_file_and_a_file_list_read_like_paraview() {
    let dir = tempfile::tempdir().unwrap();
    let files = write_steps(dir.path());
    let json = serde_json::json!({
        "file-series-version": "1.0",
        "files": [
            {"name": files[0].file_name().unwrap().to_str(), "time": 10.0},
            {"name": files[1].file_name().unwrap().to_str(), "time": 20.0},
            {"name": files[2].file_name().unwrap().to_str(), "time": 30.0},
        ]
    });
    let path = dir.path().join("drift.raw.series");
    std::fs::write(&path, json.to_string()).unwrap();
    let s = Series::open(std::slice::from_ref(&path)).unwrap();
    assert_eq!(
        s.steps.iter().map(|s| s.time).collect::<Vec<_>>(),
        [10.0, 20.0, 30.0]
    );
    // Several files, and a pattern: ordered by the numbers in their names, time = index.
    let reversed: Vec<PathBuf> = files.iter().rev().cloned().collect();
    let list = Series::open(&reversed).unwrap();
    assert_eq!(
        list.steps
            .iter()
            .map(|s| s.path.clone())
            .collect::<Vec<_>>(),
        files
    );
    assert_eq!(list.steps[2].time, 2.0);
    let glob = Series::open(&[dir.path().join("drift_*_6x5x4_uint8.raw")]).unwrap();
    assert_eq!(glob.steps, list.steps);
}

#[test]
fn statistics_cover_every_step_and_steps_share_their_normalization() {
    let dir = tempfile::tempdir().unwrap();
    let files = write_steps(dir.path());
    let series = Arc::new(Series::open(&files).unwrap());
    let opts = ReadOptions::default();
    let mut seen = Vec::new();
    let stats = series.scan(&opts, &mut |i| seen.push(i)).unwrap();
    assert_eq!(seen, [0, 1, 2]);
    assert_eq!(stats.range, [0.0, 69.0]);
    assert_eq!(stats.step_ranges, [[0.0, 49.0], [10.0, 59.0], [20.0, 69.0]]);
    assert_eq!(stats.histogram.len(), HISTOGRAM_BINS);
    assert_eq!(stats.histogram.iter().sum::<u64>(), 360);
    // The series' histogram has no count above the data (value 69 is the top bin).
    let last = stats.histogram.iter().rposition(|&c| c > 0).unwrap();
    assert!(last >= HISTOGRAM_BINS - 2, "{last}");

    // The histogram is the sum of what the steps' loads count over the series' range.
    let mut loaded = vec![0u64; HISTOGRAM_BINS];
    for i in 0..3 {
        let step = series.load_step(i, stats.norm_range, &opts).unwrap();
        for (h, k) in loaded.iter_mut().zip(&step.histogram) {
            *h += k;
        }
    }
    assert_eq!(stats.histogram, loaded);
    // A step normalized over the series' range: v / 69 for every value.
    let step = series.load_step(1, stats.norm_range, &opts).unwrap();
    assert_eq!(step.norm_range, [0.0, 69.0]);
    assert_eq!(step.range, [10.0, 59.0]);
    assert!(Arc::ptr_eq(step.series.as_ref().unwrap(), &series));
    let data = step.data();
    for (i, &v) in data.iter().enumerate() {
        let want = (10 + i % 50) as f32 / 69.0;
        assert!((v - want).abs() < 1e-6, "{i}: {v} vs {want}");
    }
    // Over its own range, a step is what a plain load gives, bit for bit.
    let own = load(&files[2], &opts).unwrap();
    let same = series.load_step(2, own.norm_range, &opts).unwrap();
    let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(same.data()), bits(own.data()));
    assert_eq!(same.histogram, own.histogram);
    // A range that does not hold the values is refused, naming the file.
    let err = series
        .load_step(2, [0.0, 30.0], &opts)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("drift_2") && err.contains("outside the range"),
        "{err}"
    );
}

#[test]
fn selection_keeps_the_collections_times() {
    let dir = tempfile::tempdir().unwrap();
    let files = write_steps(dir.path());
    let s = Series::open(&files).unwrap();
    let some = s
        .select(&TimeSelection {
            range: Some([1.0, 2.0]),
            indices: None,
        })
        .unwrap();
    assert_eq!(some.steps, s.steps[1..]);
    assert!(!some.is_whole());
    let err = s
        .select(&TimeSelection {
            range: None,
            indices: Some(vec![0, 7]),
        })
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("step 7 does not exist") && err.contains("0 to 2"),
        "{err}"
    );
}

#[test]
fn bad_collections_get_one_line_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let files = write_steps(dir.path());
    let name = |i: usize| files[i].file_name().unwrap().to_string_lossy().into_owned();
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "multi.pvd",
            pvd(&[("0", "0", &name(0)), ("0", "1", &name(1))]),
            "several parts",
        ),
        (
            "same.pvd",
            pvd(&[("1", "0", &name(0)), ("1", "0", &name(1))]),
            "two files at time 1",
        ),
        ("nan.pvd", pvd(&[("x", "0", &name(0))]), "not a number"),
        ("empty.pvd", pvd(&[]), "no time step"),
        (
            "notpvd.pvd",
            "<VTKFile type=\"ImageData\"/>".into(),
            "not a ParaView collection",
        ),
        (
            "broken.pvd",
            "<VTKFile type=\"Collection\"><Coll".into(),
            "",
        ),
        (
            "bad.series",
            "{\"files\": [{\"time\": 1}]}".into(),
            "no \"name\"",
        ),
        ("notjson.series", "files".into(), "invalid JSON"),
    ];
    for (file, text, says) in cases {
        let path = dir.path().join(file);
        std::fs::write(&path, text).unwrap();
        let err = match Series::open(std::slice::from_ref(&path)) {
            Ok(s) => s
                .scan(&ReadOptions::default(), &mut |_| {})
                .map(|_| ())
                .unwrap_err(),
            Err(e) => e,
        }
        .to_string();
        assert!(err.contains(file) && err.contains(says), "{file}: {err}");
        assert!(!err.contains('\n'), "{file}: {err}");
    }
    // A missing step is named when the series is read.
    let path = dir.path().join("missing.pvd");
    std::fs::write(
        &path,
        pvd(&[("0", "0", &name(0)), ("1", "0", "gone_6x5x4_uint8.raw")]),
    )
    .unwrap();
    let s = Series::open(std::slice::from_ref(&path)).unwrap();
    let err = s
        .scan(&ReadOptions::default(), &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("gone_6x5x4_uint8.raw"), "{err}");
    // Steps of different sizes.
    std::fs::write(dir.path().join("drift_3_5x5x4_uint8.raw"), vec![0u8; 100]).unwrap();
    let mixed =
        Series::open(&[files[0].clone(), dir.path().join("drift_3_5x5x4_uint8.raw")]).unwrap();
    let err = mixed
        .scan(&ReadOptions::default(), &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("differ in size"), "{err}");
    // A pattern that matches nothing; files of two formats.
    let err = Series::open(&[dir.path().join("none_*.vti")])
        .unwrap_err()
        .to_string();
    assert!(err.contains("no file matches"), "{err}");
    let err = Series::open(&[files[0].clone(), dir.path().join("x.vti")])
        .unwrap_err()
        .to_string();
    assert!(err.contains("share one format"), "{err}");
}
