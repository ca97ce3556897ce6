"""t2tf.read_series, t2tf.Series.from_arrays and optimize on a series: one TF for all steps."""
import json

import numpy as np
import pytest

import t2tf
from conftest import NEGHIP, QUICK


def drifting(tmp_path, n=3):
    """n steps of neghip whose values drift upward (step s: min(v + 40 s, 255)), written as
    SciVis-named raw files; returns the files and the arrays [z, y, x]."""
    base = np.fromfile(NEGHIP, dtype=np.uint8).reshape(64, 64, 64)
    files, arrays = [], []
    for s in range(n):
        a = np.minimum(base.astype(np.int32) + 40 * s, 255).astype(np.uint8)
        f = tmp_path / f"neghip_{s}_64x64x64_uint8.raw"
        a.tofile(f)
        files.append(f)
        arrays.append(a)
    return files, arrays


def test_read_series_from_a_pattern_and_a_selection(tmp_path):
    files, arrays = drifting(tmp_path)
    series = t2tf.read_series(str(tmp_path / "neghip_*_64x64x64_uint8.raw"))
    assert len(series) == 3
    assert series.times == [0.0, 1.0, 2.0]
    assert series.files == files
    assert series.collection is None
    assert series.range == (float(min(a.min() for a in arrays)), 255.0)
    assert series.step_ranges[2] == (float(arrays[2].min()), 255.0)
    picked = t2tf.read_series(files, time_steps=[0, 2])
    assert picked.times == [0.0, 2.0]
    with pytest.raises(t2tf.VolumeError, match="no time step selected"):
        t2tf.read_series(files, time_range=(5.0, 6.0))
    with pytest.raises(t2tf.VolumeError, match="no file matches"):
        t2tf.read_series(str(tmp_path / "nothing_*.raw"))


def test_a_pvd_keeps_its_times(tmp_path):
    files, _ = drifting(tmp_path)
    entries = "".join(
        f'<DataSet timestep="{t}" part="0" file="{f.name}"/>'
        for t, f in zip([0.5, 1.5, 2.5], files)
    )
    pvd = tmp_path / "run.pvd"
    pvd.write_text(f'<VTKFile type="Collection"><Collection>{entries}</Collection></VTKFile>')
    series = t2tf.read_series(pvd, time_range=(1.0, 3.0))
    assert series.times == [1.5, 2.5]
    assert series.collection == pvd
    assert "2 of 3 steps" in repr(series)


def test_arrays_and_files_make_the_same_series(tmp_path):
    files, arrays = drifting(tmp_path)
    held = t2tf.Series.from_arrays(arrays, times=[0.0, 10.0, 20.0])
    read = t2tf.read_series(files)
    assert held.times == [0.0, 10.0, 20.0]
    assert held.files is None
    assert held.range == read.range
    assert held.step_ranges == read.step_ranges
    with pytest.raises(t2tf.SettingsError, match="one time per array"):
        t2tf.Series.from_arrays(arrays, times=[0.0])
    with pytest.raises(t2tf.VolumeError, match="not after the previous"):
        t2tf.Series.from_arrays(arrays, times=[0.0, 2.0, 1.0])


def test_optimize_a_series(tmp_path):
    files, arrays = drifting(tmp_path)
    series = t2tf.read_series(files)
    result = t2tf.optimize(series, "a molecule in red", **QUICK)
    again = t2tf.optimize(t2tf.read_series(files), "a molecule in red", **QUICK)
    np.testing.assert_array_equal(result.transfer_function.sample(64)[1],
                                  again.transfer_function.sample(64)[1])
    # The TF spans the series' range: the same data values at every time.
    values, _ = result.transfer_function.sample(2)
    assert (values[0], values[-1]) == series.range
    report = result.report
    steps = report["time_series"]["steps"]
    assert [s["time"] for s in steps] == [0.0, 1.0, 2.0]
    assert sum(s["views"] for s in steps) == QUICK["steps"] * QUICK["views"]
    mean = sum(s["final_scores"][0]["cosine"] for s in steps) / 3
    assert report["final_scores"][0]["cosine"] == pytest.approx(mean, abs=1e-12)
    out = tmp_path / "out"
    result.save(out)
    saved = json.loads((out / "report.json").read_text())
    assert len(saved["time_series"]["steps"]) == 3
    # The same series in memory: the same TF, bit for bit (its statistics are the files').
    held = t2tf.optimize(t2tf.Series.from_arrays(arrays), "a molecule in red", **QUICK)
    assert held.report["time_series"]["steps"][2]["path"].endswith("(time step 2)")
    np.testing.assert_array_equal(held.transfer_function.sample(256)[1],
                                  result.transfer_function.sample(256)[1])
