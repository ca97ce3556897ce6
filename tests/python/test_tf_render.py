"""t2tf.TransferFunction (load, save, sample) and t2tf.render against `t2tf render`."""
import subprocess

import numpy as np
import pytest

import t2tf
from conftest import NEGHIP, PRESET, read_png, t2tf_command


def test_sample_gives_rgba_in_data_units():
    tf = t2tf.TransferFunction.load(PRESET)
    assert tf.name == "ParaViewWritten"
    lo, hi = tf.range
    values, rgba = tf.sample(101)
    assert values.shape == (101,) and rgba.shape == (101, 4)
    assert values[0] == lo and values[-1] == hi
    assert np.all((rgba >= 0) & (rgba <= 1))
    # At the points themselves the samples are the points' colours and opacities.
    for x, r, g, b in tf.rgb_points:
        i = int(np.argmin(abs(values - x)))
        if abs(values[i] - x) < 1e-12:
            np.testing.assert_allclose(rgba[i, :3], [r, g, b])
    for x, o in tf.opacity_points:
        np.testing.assert_allclose(np.interp(x, values, rgba[:, 3]), o, atol=1e-2)
    with pytest.raises(t2tf.SettingsError):
        tf.sample(1)
    # A size no table holds is refused, not allocated (an allocation this large aborts).
    for n in (10**12, 2**62):
        with pytest.raises(t2tf.SettingsError, match="between 2 and 16777216"):
            tf.sample(n)


@pytest.mark.parametrize("ext", ["json", "xml", "ct"])
def test_save_and_load_round_trip(tmp_path, ext):
    tf = t2tf.TransferFunction.load(PRESET)
    path = tmp_path / ("tf." + ext)
    tf.save(path)
    back = t2tf.TransferFunction.load(path)
    assert back.range == pytest.approx(tf.range)
    # .ct holds 8-bit colours and alpha.
    tol = 1 / 255 if ext == "ct" else 1e-12
    np.testing.assert_allclose(back.sample(64)[1], tf.sample(64)[1], atol=tol)


def test_format_errors_name_the_file(tmp_path):
    tf = t2tf.TransferFunction.load(PRESET)
    with pytest.raises(t2tf.FormatError, match=r"tf\.png.*\.json, \.xml or \.ct"):
        tf.save(tmp_path / "tf.png")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(t2tf.FormatError, match="bad.json"):
        t2tf.TransferFunction.load(bad)
    with pytest.raises(t2tf.FormatError, match="no preset"):
        t2tf.TransferFunction.load(PRESET, preset="Other")


def test_files_past_the_size_cap_are_refused_before_they_are_read(tmp_path):
    big = tmp_path / "big.json"
    with open(big, "wb") as f:
        f.truncate(3 << 30)  # sparse: reading it would take 3 GiB
    with pytest.raises(t2tf.FormatError, match=r"big\.json: is 3\.0 GiB, more than the 64\.0 MiB.*`max_preset_size`"):
        t2tf.TransferFunction.load(big)
    size = PRESET.stat().st_size
    with pytest.raises(t2tf.FormatError, match="a transfer-function file may be"):
        t2tf.TransferFunction.load(PRESET, max_preset_size=size - 1)
    assert t2tf.TransferFunction.load(PRESET, max_preset_size=size).name == "ParaViewWritten"


def test_render_is_t2tf_renders_picture(tmp_path):
    volume = t2tf.read_volume(NEGHIP)
    tf = t2tf.TransferFunction.load(PRESET)
    mine = t2tf.render(volume, tf, yaw=40, pitch=-5, distance=2.2, size=96, up="-y",
                       background="checkerboard")
    assert mine.shape == (96, 96, 3) and mine.dtype == np.uint8
    png = tmp_path / "view.png"
    subprocess.run([t2tf_command(), "render", str(NEGHIP), "--tf", str(PRESET), "--out", str(png),
                    "--yaw", "40", "--pitch", "-5", "--distance", "2.2", "--size", "96",
                    "--up", "-y", "--background", "checkerboard"], check=True)
    np.testing.assert_array_equal(mine, read_png(png))


def test_render_errors_are_settings_errors():
    volume = t2tf.read_volume(NEGHIP)
    tf = t2tf.TransferFunction.load(PRESET)
    with pytest.raises(t2tf.SettingsError, match="background"):
        t2tf.render(volume, tf, background="plaid")
    with pytest.raises(t2tf.SettingsError, match="up"):
        t2tf.render(volume, tf, up="w")
    with pytest.raises(t2tf.SettingsError, match="size"):
        t2tf.render(volume, tf, size=0)


def test_a_tf_from_points_renders_as_its_saved_file(tmp_path):
    rgb = np.array([[0, 0.1, 0.2, 0.9], [128, 1, 0.5, 0], [255, 1, 1, 1]])
    tf = t2tf.TransferFunction.from_points(rgb, [(0, 0), (100, 0), (255, 0.8)], name="mine")
    assert tf.name == "mine" and tf.range == (0.0, 255.0) and tf.unit_distance is None
    np.testing.assert_array_equal(tf.rgb_points, rgb)
    tf.save(tmp_path / "mine.json")
    volume = t2tf.read_volume(NEGHIP)
    saved = t2tf.TransferFunction.load(tmp_path / "mine.json")
    np.testing.assert_array_equal(t2tf.render(volume, tf, size=48),
                                  t2tf.render(volume, saved, size=48))
    with pytest.raises(t2tf.FormatError, match="below the previous"):
        t2tf.TransferFunction.from_points([(1, 0, 0, 0), (0, 1, 1, 1)])
    with pytest.raises(t2tf.FormatError, match="no colour points"):
        t2tf.TransferFunction.from_points([])


def test_render_takes_paths_and_arrays_and_volume_takes_any_triple(neghip, tmp_path):
    tf = t2tf.TransferFunction.load(PRESET)
    want = t2tf.render(t2tf.read_volume(NEGHIP), tf, size=32)
    for volume in (NEGHIP, str(NEGHIP), neghip):
        np.testing.assert_array_equal(t2tf.render(volume, PRESET, size=32), want)
    with pytest.raises(t2tf.SettingsError, match="tf must be a t2tf.TransferFunction or"):
        t2tf.render(neghip, 3, size=32)
    for spacing in ([1, 1, 2], (1, 1, 2), np.array([1.0, 1.0, 2.0])):
        assert t2tf.Volume(neghip, spacing=spacing).spacing == (1.0, 1.0, 2.0)
    with pytest.raises(t2tf.SettingsError, match="spacing must be three numbers"):
        t2tf.Volume(neghip, spacing=[1, 2])
