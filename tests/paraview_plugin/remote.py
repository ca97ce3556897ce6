"""pvpython driver for tests/paraview/paraview_plugin.rs's pvserver test: connects to a running
`mpiexec -n 2 pvserver`, opens a volume on the server, runs the plugin's remote path
(t2tf_plugin.text_to_transfer_function: ResampleToImage proxy fetched, t2tf here, TF applied
to the full data's display on the server) and writes what happened as JSON, a screenshot of
the full data and one of the proxy with the same TF and camera
(argv: plugin, port, volume, model, tokenizer, proxy_size, result.json, full.png, proxy.png,
size)."""
import json
import os
import sys

import paraview.simple as pvs
from paraview import servermanager

plugin, port, volume, model, tokenizer, proxy_size, out_json, full_png, proxy_png, size = sys.argv[1:11]
size, proxy_size = int(size), int(proxy_size)
sys.path.insert(0, os.path.dirname(plugin))
import t2tf_plugin  # noqa: E402 (the remote path runs here, on the client)



def text(value):
    return str(value.GetData() if hasattr(value, "GetData") else value)


pvs.Connect("localhost", int(port))
conn = servermanager.ActiveConnection
res = {"remote": bool(conn.IsRemote()), "partitions": conn.GetNumberOfDataPartitions()}

pvs._DisableFirstRenderCameraReset()
view = pvs.GetActiveViewOrCreate("RenderView")
view.ViewSize = [size, size]
view.UseColorPaletteForBackground = 0
view.Background = [0.3, 0.3, 0.3]
view.OrientationAxesVisibility = 0
# Render on the server whatever the data's size, so that no geometry (here: the volume) is
# delivered to the client for local rendering: only the proxy and images cross.
pvs.GetSettingsProxy("RenderViewSettings").RemoteRenderThreshold = 0.0

# The volume is read by the server (same machine, same path), in pieces across the ranks.
full = pvs.ImageReader(FileNames=[volume])
full.DataScalarType = "unsigned char"
full.DataExtent = [0, 63, 0, 63, 0, 63]
full.ScalarArrayName = "ImageFile"
full.UpdatePipeline()
res["full_points"] = full.GetDataInformation().GetNumberOfPoints()

result, local = t2tf_plugin.text_to_transfer_function(
    full, "a protein molecule", negatives=["a blank image", "a cat"], steps=5, views=1, seed=3,
    model=model, tokenizer=tokenizer, proxy_size=proxy_size, view=view, camera=True, timeout=240,
    # A strong L1 pull keeps the 5-step random-CLIP TF translucent (an opaque box would only
    # compare the box's faces): zero below ~107, opaque above ~150 on neghip.
    extra=["--l1", "1"])
disp = pvs.GetDisplayProperties(full, view)
lut = pvs.GetColorTransferFunction("ImageFile")
pwf = pvs.GetOpacityTransferFunction("ImageFile")
presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
res.update(
    proxy_dims=list(result["proxy_dims"]), local_dims=list(local.GetDimensions()),
    local_points=local.GetNumberOfPoints(), fetched_points=result["fetched_points"],
    local_bounds=list(local.GetBounds()), full_bounds=list(full.GetDataInformation().GetBounds()),
    representation=text(disp.Representation), color_array=str(disp.ColorArrayName[1]),
    rgb=list(lut.RGBPoints), points=list(pwf.Points),
    rescale=text(lut.AutomaticRescaleRangeMode), unit_distance=disp.ScalarOpacityUnitDistance,
    has_preset=bool(presets.HasPreset(result["name"])), preset=result["preset"],
    volume=result["volume"], interrupted=result["interrupted"])
pvs.SaveScreenshot(full_png, view, ImageResolution=[size, size])

# The proxy, resampled again on the server with the same dimensions, shown alone with the
# same TF, unit distance and camera.
pvs.Hide(full, view)
again = pvs.ResampleToImage(Input=full)
again.UseInputBounds = 1
again.SamplingDimensions = result["proxy_dims"]
again.UpdatePipeline()
res["proxy_points_on_server"] = again.GetDataInformation().GetNumberOfPoints()
pvs.Show(again, view)
t2tf_plugin.apply_to_display(result, again, view, "ImageFile", camera=True)
pvs.SaveScreenshot(proxy_png, view, ImageResolution=[size, size])

# The filter itself, loaded on the server (remote=True) as well as here (the imported module
# watches the session): the server's ranks pass the data through and run no t2tf; this client
# runs t2tf once, on a proxy, when the filter updates, and shows the TF on its display.
pvs.LoadPlugin(plugin, remote=True, ns=globals())
print("SERVER FILTER", flush=True)
f = TextToTransferFunction(Input=full, Prompt="a protein molecule", Steps=2, Views=1,
                           Model=model, Tokenizer=tokenizer)
f.UpdatePipeline()
pvs.Show(f, view)
f.UpdatePipeline()  # the same settings and data again: no second run
fdisp = pvs.GetDisplayProperties(f, view)
res["server_filter_points"] = f.GetDataInformation().GetNumberOfPoints()
res["server_filter_representation"] = text(fdisp.Representation)
res["server_filter_rgb"] = list(fdisp.LookupTable.RGBPoints) if fdisp.LookupTable else None
res["server_filter_preset"] = json.loads(presets.GetPresetAsString(
    next(i for i in range(presets.GetNumberOfPresets())
         if presets.GetPresetName(i) == "t2tf: a protein molecule")))
print("SERVER FILTER DONE", flush=True)
# All Time Steps on a time-varying source (a 3-step .pvd written here, read by the server):
# refused in client-server mode, in one line, without running t2tf.
from vtkmodules.vtkCommonDataModel import vtkImageData  # noqa: E402
from vtkmodules.vtkIOXML import vtkXMLImageDataWriter  # noqa: E402
from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: E402
import numpy  # noqa: E402
work = os.path.dirname(os.path.abspath(out_json))
entries = []
for i in range(3):
    image = vtkImageData()
    image.SetDimensions(8, 8, 8)
    values = numpy_to_vtk(numpy.arange(512, dtype=numpy.float32) * (i + 1), deep=1)
    values.SetName("v")
    image.GetPointData().SetScalars(values)
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(os.path.join(work, "step_%d.vti" % i))
    writer.SetInputData(image)
    writer.Write()
    entries.append('<DataSet timestep="%d" part="0" file="step_%d.vti"/>' % (i, i))
with open(os.path.join(work, "steps.pvd"), "w") as fh:
    fh.write('<VTKFile type="Collection" version="0.1"><Collection>%s</Collection></VTKFile>'
             % "".join(entries))
timed = TextToTransferFunction(Input=pvs.OpenDataFile(os.path.join(work, "steps.pvd")),
                               Prompt="a cloud", Steps=2, Views=1, Model=model,
                               Tokenizer=tokenizer, AllTimeSteps=1)
pvs.Show(timed, view)
pvs.Render(view)
print("ALL TIME STEPS DONE", flush=True)
with open(out_json, "w") as fh:
    json.dump(res, fh)
pvs.Disconnect()
