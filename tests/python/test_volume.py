"""t2tf.Volume from NumPy arrays (read in place where the layout allows, converted where
not) and t2tf.read_volume."""
import numpy as np
import pytest

import t2tf
from conftest import HEADSQ, NEGHIP, PRESET, require_module


def picture(volume):
    """A small render: what the renderer sees of a volume, to compare two volumes by."""
    tf = t2tf.TransferFunction.load(PRESET)
    return t2tf.render(volume, tf, size=48)


def test_a_c_ordered_array_is_read_in_place(neghip):
    v = t2tf.Volume(neghip, spacing=(1.0, 2.0, 0.5), origin=(-1.0, 0.0, 3.0))
    assert v.shape == (64, 64, 64)
    assert v.spacing == (1.0, 2.0, 0.5)
    assert v.origin == (-1.0, 0.0, 3.0)
    assert v.dtype == "uint8"
    assert v.range == (float(neghip.min()), float(neghip.max()))
    assert v.path is None
    out = v.to_numpy()
    assert np.shares_memory(out, neghip), "the volume copied a C-ordered uint8 array"
    assert not out.flags.writeable
    np.testing.assert_array_equal(out, neghip)


def test_the_file_and_the_array_are_one_volume(neghip):
    from_file = t2tf.read_volume(NEGHIP)
    assert from_file.path == NEGHIP
    np.testing.assert_array_equal(from_file.to_numpy(), neghip)
    np.testing.assert_array_equal(picture(from_file), picture(t2tf.Volume(neghip)))


def test_fortran_order_and_strided_views_are_converted(neghip):
    fortran = np.asfortranarray(neghip)
    v = t2tf.Volume(fortran)
    assert not np.shares_memory(v.to_numpy(), fortran)
    np.testing.assert_array_equal(picture(v), picture(t2tf.Volume(neghip)))
    view = neghip[:, ::2, 1:]
    w = t2tf.Volume(view)
    assert w.shape == (64, 32, 63)
    np.testing.assert_array_equal(w.to_numpy(), view)
    np.testing.assert_array_equal(picture(w), picture(t2tf.Volume(view.copy())))


@pytest.mark.parametrize("dtype", ["uint8", "int8", "uint16", "int16", "uint32", "int32",
                                   "uint64", "int64", "float32", "float64"])
def test_every_volume_dtype_is_read_in_place(dtype):
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "iu" else None
    lo = max(info.min, -100) if info else -1.5
    a = np.linspace(lo, 100, 6 * 5 * 4).astype(dtype).reshape(6, 5, 4)
    v = t2tf.Volume(a)
    assert v.dtype == dtype
    assert v.range == (float(a.min()), float(a.max()))
    assert np.shares_memory(v.to_numpy(), a)


def test_other_byte_orders_are_read_in_place():
    a = (np.arange(4 * 4 * 4, dtype=">u2") * 500).reshape(4, 4, 4)
    v = t2tf.Volume(a)
    assert np.shares_memory(v.to_numpy(), a)
    assert v.range == (0.0, 63 * 500.0)
    np.testing.assert_array_equal(picture(v), picture(t2tf.Volume(a.astype("<u2"))))


def test_bool_float16_and_lists_are_converted():
    assert t2tf.Volume(np.ones((2, 2, 2), dtype=bool)).dtype == "uint8"
    assert t2tf.Volume(np.ones((2, 2, 2), dtype=np.float16)).dtype == "float32"
    v = t2tf.Volume([[[0, 1], [2, 3]], [[4, 5], [6, 7]]])
    assert v.shape == (2, 2, 2) and v.range == (0.0, 7.0)


def test_nan_is_empty_space():
    a = np.linspace(0, 1, 8 * 8 * 8, dtype=np.float32).reshape(8, 8, 8)
    a[0, 0, :3] = np.nan
    a[1, 1, 1] = np.inf
    v = t2tf.Volume(a)
    assert v.non_finite == 4
    assert v.range == (float(np.nanmin(a[np.isfinite(a)])), 1.0)


def test_a_vtk_image_is_read_without_a_copy():
    vtk = require_module("vtkmodules.vtkImagingCore")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    from t2tf.vtk import volume_from_vtk

    source = vtk.vtkRTAnalyticSource()
    source.SetWholeExtent(-4, 5, 0, 7, 2, 7)
    source.Update()
    image = source.GetOutput()
    v = volume_from_vtk(image)
    values = vtk_to_numpy(image.GetPointData().GetScalars())
    assert v.shape == (6, 8, 10)
    assert v.origin == (-4.0, 0.0, 2.0)
    assert np.shares_memory(v.to_numpy(), values)
    np.testing.assert_array_equal(v.to_numpy().ravel(), values)


@pytest.mark.parametrize("values, words", [
    (np.zeros((4, 4)), "3-D array"),
    (np.full((2, 2, 2), np.nan), "NaN"),
    (np.zeros((2, 2, 2), dtype=complex), "integers or floats"),
    (np.zeros((0, 2, 2)), "zero"),
])
def test_unusable_arrays_are_volume_errors(values, words):
    with pytest.raises(t2tf.VolumeError, match=words):
        t2tf.Volume(values)


def test_bad_geometry_is_a_volume_error(neghip):
    with pytest.raises(t2tf.VolumeError, match="spacing"):
        t2tf.Volume(neghip, spacing=(1.0, 0.0, 1.0))
    with pytest.raises(t2tf.Error):
        t2tf.Volume(neghip, origin=(float("nan"), 0.0, 0.0))


def test_read_volume_takes_the_clis_reader_settings(tmp_path):
    raw = tmp_path / "volume.raw"
    a = np.fromfile(HEADSQ, dtype="<u2").reshape(93, 64, 64)
    a.astype(">u2").tofile(raw)
    v = t2tf.read_volume(raw, dims=(64, 64, 93), dtype=np.uint16, byte_order="big",
                         spacing=(1, 1, 2))
    assert v.shape == (93, 64, 64) and v.spacing == (1.0, 1.0, 2.0)
    np.testing.assert_array_equal(v.to_numpy(), a)
    with pytest.raises(t2tf.VolumeError, match="volume.raw"):
        t2tf.read_volume(raw)  # no dims in the name, none given
    with pytest.raises(t2tf.VolumeError, match="no-such"):
        t2tf.read_volume(tmp_path / "no-such_8x8x8_uint8.raw")
    with pytest.raises(t2tf.VolumeError, match="unknown scalar type"):
        t2tf.read_volume(raw, dims=(64, 64, 93), dtype="uint12")


def test_volume_errors_carry_their_kind_and_option(tmp_path):
    raw = tmp_path / "volume.raw"
    raw.write_bytes(bytes(8))
    with pytest.raises(t2tf.VolumeError) as raised:
        t2tf.read_volume(raw, dims=(2, 2, 2), dtype="uint12")
    assert (raised.value.kind, raised.value.option) == ("invalid_option", "dtype")
    with pytest.raises(t2tf.VolumeError) as raised:
        t2tf.read_volume(raw, dims=(2, 2, 2), dtype=np.uint8, byte_order="middle")
    assert (raised.value.kind, raised.value.option) == ("invalid_option", "byte_order")
    with pytest.raises(t2tf.VolumeError) as raised:
        t2tf.Volume(np.zeros((4, 4)))
    assert (raised.value.kind, raised.value.option) == ("volume", None)
    # Every class has a kind, and an instance of the module's own making gets its class's.
    assert t2tf.Error.kind == "other" and t2tf.BudgetError.kind == "memory"
