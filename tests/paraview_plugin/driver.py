"""pvpython driver for tests/paraview/paraview_plugin.rs: loads the plugin, runs the filter on one
kind of input and writes what ParaView holds afterwards as JSON (argv: plugin, mode, volume,
model, tokenizer, result.json, screenshot.png, size)."""
import json
import os
import sys
import time

import paraview.simple as pvs
from paraview import servermanager

plugin, mode, volume, model, tokenizer, out_json, shot, size = sys.argv[1:9]
size = int(size)
pvs.LoadPlugin(plugin, ns=globals())
sys.path.insert(0, os.path.dirname(plugin))
import t2tf_plugin  # the same module the plugin loader ran (for cancel and messages)

pvs._DisableFirstRenderCameraReset()
view = pvs.GetActiveViewOrCreate("RenderView")
view.ViewSize = [size, size]
view.UseColorPaletteForBackground = 0
view.Background = [0.3, 0.3, 0.3]
view.OrientationAxesVisibility = 0
res = {}


def raw_reader(path):
    # Open SciVis names: NAME_XxYxZ_TYPE.raw, little-endian.
    dims, dtype = os.path.basename(path)[:-4].split("_")[-2:]
    nx, ny, nz = (int(n) for n in dims.split("x"))
    r = pvs.ImageReader(FileNames=[path])
    r.DataScalarType = {"uint8": "unsigned char", "uint16": "unsigned short"}[dtype]
    r.DataByteOrder = "LittleEndian"
    r.DataExtent = [0, nx - 1, 0, ny - 1, 0, nz - 1]
    r.ScalarArrayName = "ImageFile"
    return r


def tf_filter(source, prompt="a protein molecule", steps=5):
    return TexttoTransferFunction(Input=source, Prompt=prompt, Negatives=["a blank image", "a cat"],
                                  Steps=steps, Views=1, Seed=3, Model=model, Tokenizer=tokenizer)


def text(value):
    return str(value.GetData() if hasattr(value, "GetData") else value)


def record(f, array):
    disp = pvs.GetDisplayProperties(f, view)
    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    r = f.GetClientSideObject().result
    fd = servermanager.Fetch(f).GetFieldData()
    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
    res.update(
        representation=text(disp.Representation), color_array=str(disp.ColorArrayName[1]),
        rgb=list(lut.RGBPoints), points=list(pwf.Points), rescale=text(lut.AutomaticRescaleRangeMode),
        unit_distance=disp.ScalarOpacityUnitDistance, has_preset=bool(presets.HasPreset(r["name"])),
        preset_file=r["preset_file"], volume=r["volume"], out=r["out"], interrupted=r["interrupted"],
        camera={"position": list(view.CameraPosition), "focal_point": list(view.CameraFocalPoint),
                "view_up": list(view.CameraViewUp), "view_angle": view.CameraViewAngle},
        result_camera=r["camera"],
        field={fd.GetAbstractArray(i).GetName(): fd.GetAbstractArray(i).GetValue(0)
               for i in range(fd.GetNumberOfArrays())
               if fd.GetAbstractArray(i).GetName().startswith("t2tf_")})


if mode == "vti":
    # The shared volume as a .vti file written by ParaView: the plugin hands t2tf the file.
    vti = os.path.join(os.path.dirname(out_json), "volume.vti")
    pvs.XMLImageDataWriter(Input=raw_reader(volume), FileName=vti).UpdatePipeline()
    f = tf_filter(pvs.XMLImageDataReader(FileName=[vti]))
    pvs.Show(f, view)
    record(f, "ImageFile")
elif mode == "nofile":
    # A source with no file behind it: the plugin writes the image to a temporary .vti.
    f = tf_filter(pvs.Wavelet(WholeExtent=[-12, 12, -12, 12, -12, 12]), prompt="a glowing cloud")
    pvs.Show(f, view)
    record(f, "RTData")
elif mode == "cancel":
    f = tf_filter(raw_reader(volume), steps=2000)
    algo = f.GetClientSideObject()
    seen = []

    def on_progress(obj, _event):
        # Cancel through the algorithm's abort flag (what ParaView's abort button sets),
        # after a few steps have finished.
        seen.append(obj.GetProgress())
        if len(seen) == 6:
            obj.SetAbortExecute(1)

    algo.AddObserver("ProgressEvent", on_progress)
    start = time.time()
    pvs.Show(f, view)
    res["filter_seconds"] = time.time() - start
    record(f, "ImageFile")
    # Still responsive: a new source updates and the view renders.
    start = time.time()
    pvs.Show(pvs.Sphere(), view)
    pvs.Render(view)
    res["after_cancel_seconds"] = time.time() - start
    res["progress_events"] = len(seen)
elif mode == "refine":
    # A first run, then Refine from the display's functions with a range locked.
    src = raw_reader(volume)
    f = tf_filter(src, steps=3)
    pvs.Show(f, view)

    def samples():
        lut = pvs.GetColorTransferFunction("ImageFile").GetClientSideObject()
        pwf = pvs.GetOpacityTransferFunction("ImageFile").GetClientSideObject()
        xs = [255.0 * i / 1023 for i in range(1024)]
        # The function itself, as vtkColorTransferFunction evaluates it (ParaView's class
        # would answer from its 256-colour discretization).
        from vtkmodules.vtkRenderingCore import vtkColorTransferFunction
        rgb = []
        for x in xs:
            c = [0.0, 0.0, 0.0]
            vtkColorTransferFunction.GetColor(lut, x, c)
            rgb.append(c)
        return {"x": xs, "rgb": rgb, "opacity": [pwf.GetValue(x) for x in xs]}

    res["before"] = samples()
    f.Prompt = "a blue cloud"
    f.Steps = 4
    f.Refine = 1
    f.LockRanges = "40,120"
    f.UpdatePipeline()  # Apply: Show alone does not re-execute a shown filter
    pvs.Render(view)
    res["after"] = samples()
    record(f, "ImageFile")
elif mode == "errors":
    # Each ends in one message in the output window (stderr here), never a traceback.
    ok = pvs.Wavelet(WholeExtent=[-4, 4, -4, 4, -4, 4])
    print("CASE empty prompt", flush=True)
    tf_filter(ok, prompt="  ").UpdatePipeline()
    print("CASE not image data", flush=True)
    tf_filter(pvs.Sphere()).UpdatePipeline()
    print("CASE missing binary", flush=True)
    os.environ["T2TF_BIN"] = os.path.join(os.path.dirname(out_json), "no-such-t2tf")
    tf_filter(ok, prompt="a cloud").UpdatePipeline()
    print("CASES DONE", flush=True)

if mode != "errors":
    pvs.SaveScreenshot(shot, view, ImageResolution=[size, size])
with open(out_json, "w") as fh:
    json.dump(res, fh)
