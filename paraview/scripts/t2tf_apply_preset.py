"""Apply a t2tf transfer function (the NAME.json ParaView preset t2tf writes) to a volume.

Colour and opacity are set directly on the lookup table and opacity function (ParaView's
ApplyPreset needs two calls and reports success even when it fails), the range is never
rescaled, and the unit distance stored in the file becomes the display's
ScalarOpacityUnitDistance, so ParaView renders what t2tf rendered.

Uses:
  * pvpython:  pvpython t2tf_apply_preset.py PRESET.json VOLUME_FILE [--array NAME]
               [--dims X,Y,Z --dtype TYPE [--spacing A,B,C] [--byte-order big]]
               [--screenshot OUT.png [--size W H]]
    A .raw volume is read like t2tf reads it: dims and type from the Open SciVis name
    NAME_XxYxZ_TYPE.raw, or from --dims and --dtype. A volume that cannot be read, or a
    screenshot that would show only the background, ends with a one-line error and exit 1.
  * from Python:  import t2tf_apply_preset; t2tf_apply_preset.apply_preset("x.json")
    (applies to the active source in the active view; open_volume(path, ...) opens a file)
  * ParaView GUI macro: Macros > Import new macro... > this file. The macro applies the file
    named by the environment variable T2TF_PRESET to the active source.
"""
import json
import os
import re
import shutil
import sys
import tempfile

import paraview.simple as pvs

UNIT_DISTANCE_KEY = "t2tfScalarOpacityUnitDistance"

# t2tf's --dtype names -> (ImageReader DataScalarType, bytes per value). ParaView 5.11's
# ImageReader has no "long long": 64-bit integers go through "long" (64-bit on Linux/macOS).
RAW_TYPES = {
    "uint8": ("unsigned char", 1),
    "int8": ("char", 1),
    "uint16": ("unsigned short", 2),
    "int16": ("short", 2),
    "uint32": ("unsigned int", 4),
    "int32": ("int", 4),
    "uint64": ("unsigned long", 8),
    "int64": ("long", 8),
    "float32": ("float", 4),
    "float64": ("double", 8),
}

# The Open SciVis naming rule, e.g. aneurism_256x256x256_uint8.raw.
SCIVIS_NAME = re.compile(r"^.+_(\d+)x(\d+)x(\d+)_([A-Za-z0-9]+)$")

# The array name t2tf's generated script gives raw data (so both colour the same array).
RAW_ARRAY = "ImageFile"


class VolumeError(Exception):
    """A volume that cannot be shown; the message is one line naming the file."""


def read_preset(path):
    """The first preset with RGBPoints in a ParaView JSON preset file."""
    with open(path) as f:
        data = json.load(f)
    presets = data if isinstance(data, list) else [data]
    for p in presets:
        if isinstance(p, dict) and "RGBPoints" in p:
            return p
    raise ValueError(path + ": no preset with RGBPoints")


def _point_array(source):
    info = source.GetPointDataInformation()
    for i in range(info.GetNumberOfArrays()):
        return info.GetArray(i).GetName()
    raise ValueError("the source has no point arrays to colour by")


def apply_preset(path, source=None, view=None, array=None):
    """Show `source` (default: the active one) as a volume with the preset; returns the display."""
    preset = read_preset(path)
    source = source or pvs.GetActiveSource()
    if source is None:
        raise ValueError("no active source: open a volume first")
    view = view or pvs.GetActiveViewOrCreate("RenderView")
    disp = pvs.Show(source, view)
    disp.Representation = "Volume"
    array = array or _point_array(source)
    pvs.ColorBy(disp, ("POINTS", array))
    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    lut.AutomaticRescaleRangeMode = "Never"
    lut.ColorSpace = "RGB"
    lut.RGBPoints = [float(v) for v in preset["RGBPoints"]]
    lut.ScalarRangeInitialized = 1
    if "Points" in preset:
        pwf.Points = [float(v) for v in preset["Points"]]
        pwf.ScalarRangeInitialized = 1
    disp.LookupTable = lut
    disp.ScalarOpacityFunction = pwf
    if UNIT_DISTANCE_KEY in preset:
        disp.ScalarOpacityUnitDistance = float(preset[UNIT_DISTANCE_KEY])
    pvs.Render(view)
    return disp


def _raw_layout(path, dims, dtype):
    """(dims, type name) from the flags, else from the SciVis file name (flags win)."""
    match = SCIVIS_NAME.match(os.path.splitext(os.path.basename(path))[0])
    if match:
        dims = dims or [int(v) for v in match.group(1, 2, 3)]
        dtype = dtype or match.group(4).lower()
    if dims is None and dtype is None:
        raise VolumeError(
            path + ": name does not follow NAME_XxYxZ_DTYPE.raw: give --dims X,Y,Z and --dtype TYPE"
        )
    if dims is None:
        raise VolumeError(path + ": --dims X,Y,Z is missing (the name does not give dimensions)")
    if dtype is None:
        raise VolumeError(path + ": --dtype TYPE is missing (the name does not give the type)")
    if dtype not in RAW_TYPES:
        raise VolumeError(
            path + ": unknown scalar type '%s' (expected one of %s)" % (dtype, ", ".join(RAW_TYPES))
        )
    if len(dims) != 3 or min(dims) < 1:
        raise VolumeError(path + ": dimensions %s must be three positive numbers" % (dims,))
    return dims, dtype


def _open_raw(path, dims, dtype, spacing, byte_order):
    """An ImageReader for a headerless array (x fastest), checked against the file's size."""
    dims, dtype = _raw_layout(path, dims, dtype)
    scalar_type, size = RAW_TYPES[dtype]
    need = dims[0] * dims[1] * dims[2] * size
    have = os.path.getsize(path)
    if have != need:
        raise VolumeError(
            "%s: file holds %d bytes but %dx%dx%d %s needs %d bytes"
            % (path, have, dims[0], dims[1], dims[2], dtype, need)
        )
    reader = pvs.ImageReader(FileNames=[path])
    reader.DataScalarType = scalar_type
    reader.DataByteOrder = "BigEndian" if byte_order == "big" else "LittleEndian"
    reader.FileDimensionality = 3
    reader.DataExtent = [0, dims[0] - 1, 0, dims[1] - 1, 0, dims[2] - 1]
    reader.DataSpacing = list(spacing or [1.0, 1.0, 1.0])
    reader.DataOrigin = [0.0, 0.0, 0.0]
    reader.NumberOfScalarComponents = 1
    reader.ScalarArrayName = RAW_ARRAY
    return reader


def _is_raw(path, dims, dtype):
    """Raw like t2tf: a .raw file, or any file when --dims or --dtype describe it."""
    return path.lower().endswith(".raw") or dims is not None or dtype is not None


def open_volume(path, dims=None, dtype=None, spacing=None, byte_order=None):
    """Open a volume file as t2tf does; raises VolumeError when nothing can be shown."""
    if not os.path.isfile(path):
        raise VolumeError(path + ": no such file")
    if _is_raw(path, dims, dtype):
        reader = _open_raw(path, dims, dtype, spacing, byte_order)
    elif spacing:
        raise VolumeError(path + ": --spacing applies to raw files here; this file gives its own")
    else:
        try:
            reader = pvs.OpenDataFile(path)
        except RuntimeError:
            reader = None
        if reader is None:
            raise VolumeError(path + ": ParaView found no reader that can open this file")
    reader.UpdatePipeline()
    points = reader.GetDataInformation().GetNumberOfPoints()
    if points < 2:
        raise VolumeError(
            "%s: ParaView's %s read %d point(s): nothing to render (is the file complete?)"
            % (path, reader.GetXMLName(), points)
        )
    return reader


def _png_pixels(path):
    """The PNG's pixel values as one flat list (for an equality check)."""
    from vtkmodules.vtkIOImage import vtkPNGReader
    from vtkmodules.util.numpy_support import vtk_to_numpy

    reader = vtkPNGReader()
    reader.SetFileName(path)
    reader.Update()
    return vtk_to_numpy(reader.GetOutput().GetPointData().GetScalars())


def save_screenshot(path, disp, view, size=None):
    """Save a screenshot, but only if it shows more than the background.

    The view is also rendered with the volume hidden: if both images are identical, the TF
    shows nothing (e.g. all opacity 0, or a range that misses the data) and no file is written.
    """
    size = list(size or view.ViewSize)
    with tempfile.TemporaryDirectory() as tmp:
        shot, background = os.path.join(tmp, "shot.png"), os.path.join(tmp, "background.png")
        pvs.SaveScreenshot(shot, view, ImageResolution=size)
        disp.Visibility = 0
        pvs.SaveScreenshot(background, view, ImageResolution=size)
        disp.Visibility = 1
        if (_png_pixels(shot) == _png_pixels(background)).all():
            raise VolumeError(
                path + ": not written: the volume is invisible with this preset "
                "(the image shows only the background)"
            )
        shutil.copyfile(shot, path)


def _camera_line(view):
    """The camera a screenshot used, as one JSON line (reuse it, or check the picture)."""
    camera = {
        "position": list(view.CameraPosition),
        "focal_point": list(view.CameraFocalPoint),
        "view_up": list(view.CameraViewUp),
        "view_angle": view.CameraViewAngle,
    }
    return "camera " + json.dumps(camera)


def _triple(kind):
    def parse(text):
        parts = text.split(",")
        if len(parts) != 3:
            raise ValueError(text)
        return [kind(p) for p in parts]

    return parse


def _parser():
    import argparse

    parser = argparse.ArgumentParser(description="Apply a t2tf preset to a volume")
    parser.add_argument("preset")
    parser.add_argument("volume", nargs="?", help="a volume file (default: active source)")
    parser.add_argument("--array", help="point array to colour by (default: the first)")
    parser.add_argument("--dims", type=_triple(int), metavar="X,Y,Z", help="raw files: points per axis")
    parser.add_argument("--dtype", type=str.lower, metavar="TYPE", help="raw files: " + ", ".join(RAW_TYPES))
    parser.add_argument("--spacing", type=_triple(float), metavar="A,B,C", help="raw files (default 1,1,1)")
    parser.add_argument("--byte-order", choices=["little", "big"], default="little")
    parser.add_argument("--screenshot", metavar="PATH", help="save a PNG of the view")
    parser.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), help="screenshot size")
    return parser


def _main(argv):
    args = _parser().parse_args(argv)
    source = None
    if args.volume:
        source = open_volume(args.volume, args.dims, args.dtype, args.spacing, args.byte_order)
    disp = apply_preset(args.preset, source=source, array=args.array)
    if args.screenshot:
        view = pvs.GetActiveView()
        save_screenshot(args.screenshot, disp, view, args.size)
        print("t2tf_apply_preset: wrote " + args.screenshot)
        print(_camera_line(view))


if __name__ == "__main__" and len(sys.argv) > 1:
    try:
        _main(sys.argv[1:])
    except (VolumeError, ValueError, OSError) as e:
        # One line on stderr and exit status 1, instead of a traceback or an empty picture.
        # Views are closed first: exiting with a render window open makes X print errors.
        for open_view in pvs.GetViews():
            pvs.Delete(open_view)
        sys.exit("t2tf_apply_preset: error: %s" % e)
elif os.environ.get("T2TF_PRESET"):
    # Run as a GUI macro (no command line): the file comes from the environment.
    apply_preset(os.environ["T2TF_PRESET"])
