"""Apply a t2tf transfer function (the NAME.json ParaView preset t2tf writes) to a volume.

Colour and opacity are set directly on the lookup table and opacity function (ParaView's
ApplyPreset needs two calls and reports success even when it fails), the range is never
rescaled, and the unit distance stored in the file becomes the display's
ScalarOpacityUnitDistance, so ParaView renders what t2tf rendered.

Uses:
  * pvpython:  pvpython t2tf_apply_preset.py PRESET.json VOLUME_FILE [--array NAME]
  * from Python:  import t2tf_apply_preset; t2tf_apply_preset.apply_preset("x.json")
    (applies to the active source in the active view)
  * ParaView GUI macro: Macros > Import new macro... > this file. The macro applies the file
    named by the environment variable T2TF_PRESET to the active source.
"""
import json
import os
import sys

import paraview.simple as pvs

UNIT_DISTANCE_KEY = "t2tfScalarOpacityUnitDistance"


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


def _main(argv):
    import argparse

    parser = argparse.ArgumentParser(description="Apply a t2tf preset to a volume")
    parser.add_argument("preset")
    parser.add_argument("volume", nargs="?", help="a file ParaView opens (default: active source)")
    parser.add_argument("--array", help="point array to colour by (default: the first)")
    parser.add_argument("--screenshot", metavar="PATH")
    args = parser.parse_args(argv)
    source = pvs.OpenDataFile(args.volume) if args.volume else None
    apply_preset(args.preset, source=source, array=args.array)
    if args.screenshot:
        pvs.SaveScreenshot(args.screenshot)


if __name__ == "__main__" and len(sys.argv) > 1:
    _main(sys.argv[1:])
elif os.environ.get("T2TF_PRESET"):
    # Run as a GUI macro (no command line): the file comes from the environment.
    apply_preset(os.environ["T2TF_PRESET"])
