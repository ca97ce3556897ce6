"""t2tf from pvpython: optimize for a ParaView source's data in this process and show it.

    pvpython examples/python/pvpython_optimize.py [--prompt TEXT] [--out view.png]

ParaView's Python must import t2tf: `pip install --user .` with the Python ParaView uses
(Debian's ParaView 5.11: the system python3), or PYTHONPATH naming a folder that holds the
installed `t2tf` package. Debian's ParaView 5.11 on Python 3.11 also needs paraview/compat
on PYTHONPATH (paraview/README.md). The data comes from VTK through vtk_to_numpy, no file is
written. The ParaView plugin (paraview/t2tf_plugin.py) does the same from the GUI.
"""
import argparse
from pathlib import Path

import paraview.simple as pvs
from paraview import servermanager

import t2tf
from t2tf.vtk import volume_from_vtk

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared" / "data"


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--prompt", default="a glowing cloud")
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--model", default=str(REPO / "tests" / "fixtures" / "clip" / "quick_gelu"))
    p.add_argument("--tokenizer", default=str(SHARED / "clip" / "tokenizer.json"))
    p.add_argument("--out", default="pvpython_optimize.png")
    args = p.parse_args()

    # Any image-data source; a Wavelet has no file behind it.
    source = pvs.Wavelet(WholeExtent=[-20, 20, -20, 20, -20, 20])
    image = servermanager.Fetch(source)
    volume = volume_from_vtk(image, "RTData")
    result = t2tf.optimize(volume, args.prompt, steps=args.steps, model=args.model,
                           tokenizer=args.tokenizer or None)
    tf = result.transfer_function

    view = pvs.GetActiveViewOrCreate("RenderView")
    display = pvs.Show(source, view)
    display.Representation = "Volume"
    pvs.ColorBy(display, ("POINTS", "RTData"))
    lut = pvs.GetColorTransferFunction("RTData")
    pwf = pvs.GetOpacityTransferFunction("RTData")
    lut.AutomaticRescaleRangeMode = "Never"
    lut.RGBPoints = [float(v) for row in tf.rgb_points for v in row]
    pwf.Points = [float(v) for x, o in tf.opacity_points for v in (x, o, 0.5, 0.0)]
    display.ScalarOpacityUnitDistance = tf.unit_distance
    camera = result.camera
    view.CameraPosition = camera["position"]
    view.CameraFocalPoint = camera["focal_point"]
    view.CameraViewUp = camera["view_up"]
    view.CameraViewAngle = camera["view_angle"]
    pvs.SaveScreenshot(args.out, view, ImageResolution=[400, 400])
    print("wrote %s (%d steps, TF %s)" % (args.out, result.steps_run, tf.name))


if __name__ == "__main__":
    main()
