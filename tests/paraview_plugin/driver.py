"""pvpython driver for tests/paraview/paraview_plugin.rs: loads the plugin, runs the filter on one
kind of input and writes what ParaView holds afterwards as JSON (argv: plugin, mode, volume,
model, tokenizer, result.json, screenshot.png, size).

Modes ending in "_imported_first" import t2tf_plugin before LoadPlugin (which then makes a
second module object); the others import it after."""
import json
import os
import sys
import time

import paraview.simple as pvs
from paraview import servermanager

plugin, mode, volume, model, tokenizer, out_json, shot, size = sys.argv[1:9]
size = int(size)
sys.path.insert(0, os.path.dirname(plugin))
if mode.endswith("_imported_first"):
    import t2tf_plugin  # noqa: E402 (a module object of its own: LoadPlugin makes another)
pvs.LoadPlugin(plugin, ns=globals())
if not mode.endswith("_imported_first"):
    import t2tf_plugin  # noqa: E402 (the module the plugin loader ran)

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
    # Apply Camera (off by default) on: the tests compare the view with t2tf's own renders.
    return TextToTransferFunction(Input=source, Prompt=prompt, Negatives=["a blank image", "a cat"],
                                  Steps=steps, Views=1, Seed=3, Model=model, Tokenizer=tokenizer,
                                  ApplyCamera=1)


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
        preset=r["preset"], name=r["name"], report=r["report"], volume=r["volume"],
        interrupted=r["interrupted"],
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
    wavelet = pvs.Wavelet(WholeExtent=[-12, 12, -12, 12, -12, 12])
    f = tf_filter(wavelet, prompt="a glowing cloud")
    pvs.Show(f, view)
    record(f, "RTData")
    # The plugin's own copy is removed with its temporary folder: a copy for the comparison.
    res["volume_copy"] = os.path.join(os.path.dirname(out_json), "wavelet.vti")
    pvs.XMLImageDataWriter(Input=wavelet, FileName=res["volume_copy"]).UpdatePipeline()
elif mode.startswith("cancel"):
    # "cancel": through the algorithm's abort flag (what ParaView's Abort button sets);
    # "cancel_by_function[_imported_first]": t2tf_plugin.cancel() from the module this
    # script imported. Either after a few steps have finished.
    f = tf_filter(raw_reader(volume), steps=2000)
    algo = f.GetClientSideObject()
    seen = []

    def on_progress(obj, _event):
        seen.append((time.time(), obj.GetProgress(), obj.GetProgressText()))
        steps_seen = [t for _, _, t in seen if "step " in (t or "")]
        if len(steps_seen) == 6:
            if mode == "cancel":
                obj.SetAbortExecute(1)
            else:
                t2tf_plugin.cancel()

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
    res["progress"] = [[t - seen[0][0], p, text] for (t, p, text) in seen]
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
    # Each ends in one message in the output window (stderr here), never a traceback, and a
    # failed filter.
    ok = pvs.Wavelet(WholeExtent=[-4, 4, -4, 4, -4, 4])
    failed = {}
    print("CASE empty prompt", flush=True)
    f = tf_filter(ok, prompt="  ")
    f.UpdatePipeline()
    failed["empty"] = f.GetClientSideObject().error
    print("CASE not image data", flush=True)
    f = tf_filter(pvs.Sphere())
    f.UpdatePipeline()
    failed["notimage"] = f.GetClientSideObject().error
    print("CASE missing binary", flush=True)
    binary = os.environ["T2TF_BIN"]
    os.environ["T2TF_BIN"] = os.path.join(os.path.dirname(out_json), "no-such-t2tf")
    f = tf_filter(ok, prompt="a cloud")
    f.UpdatePipeline()
    failed["nobinary"] = f.GetClientSideObject().error
    os.environ["T2TF_BIN"] = binary
    print("CASES DONE", flush=True)
    res["failed"] = failed
elif mode == "offline":
    # The README's pvpython example with no network and an empty model cache: the documented
    # API raises T2tfError with one line that says what to do.
    src = pvs.Wavelet(WholeExtent=[-8, 8, -8, 8, -8, 8])
    try:
        t2tf_plugin.text_to_transfer_function(src, "a glowing cloud", steps=2, views=1)
        res["raised"] = None
    except t2tf_plugin.T2tfError as e:
        res["raised"] = str(e)
elif mode == "panel":
    # What the GUI's panel is made from: the proxy definition's properties in order, with
    # their labels, visibility, tooltips, domains and hints, and the filter's description.
    from paraview.servermanager import vtkSMOrderedPropertyIterator

    proto = servermanager.ProxyManager().SMProxyManager.GetPrototypeProxy(
        "filters", "TextToTransferFunction")
    doc = proto.GetDocumentation()
    res["short_help"], res["long_help"] = doc.GetShortHelp(), doc.GetLongHelp()
    res["description"] = doc.GetDescription()
    props = []
    it = vtkSMOrderedPropertyIterator()
    it.SetProxy(proto)
    it.Begin()
    while not it.IsAtEnd():
        prop = it.GetProperty()
        hints = prop.GetHints()
        props.append({
            "name": it.GetKey(), "label": prop.GetXMLLabel(),
            "visibility": prop.GetPanelVisibility(),
            "doc": prop.GetDocumentation().GetDescription() if prop.GetDocumentation() else None,
            "hints": [hints.GetNestedElement(i).GetName()
                      for i in range(hints.GetNumberOfNestedElements())] if hints else [],
            "min": (prop.GetDomain("range").GetMinimum(0)
                    if prop.GetDomain("range") is not None else None),
            "domains": [prop.GetDomain(d).GetClassName() for d in ("files", "range", "bool")
                        if prop.GetDomain(d) is not None],
        })
        it.Next()
    res["properties"] = props
    f = TextToTransferFunction(Input=pvs.Wavelet())
    res["negatives_default"] = list(f.Negatives)
    f.Steps = 0  # outside the domain: the panel refuses it, Python reports it
    res["steps_in_domain"] = bool(f.GetProperty("Steps").SMProperty.IsInDomains())
elif mode == "presets":
    # First run through the documented API (after LoadPlugin with ns=globals()), then re-runs
    # of the same filter: its preset is replaced, never added to.
    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()

    def t2tf_names():
        return sorted(presets.GetPresetName(i) for i in range(presets.GetNumberOfPresets())
                      if presets.GetPresetName(i).startswith("t2tf: "))

    # Choose Preset's groups as a GUI saved them (pvpython has no group manager: the plugin
    # edits this setting, which the GUI reads at start-up).
    settings = servermanager.vtkSMSettings.GetInstance()
    settings.SetSetting("TransferFunctionPresets.Groups", json.dumps(
        [{"groupName": "Default", "presets": ["Cool to Warm"]},
         {"groupName": "Linear", "presets": ["X Ray"]}]))

    def groups():
        return {g["groupName"]: g["presets"] for g in json.loads(
            settings.GetSettingAsString("TransferFunctionPresets.Groups", ""))}

    res["before"] = t2tf_names()
    src = raw_reader(volume)
    result, f = t2tf_plugin.text_to_transfer_function(
        src, "a protein molecule", negatives=["a blank image"], steps=2, views=1, seed=3,
        model=model, tokenizer=tokenizer)
    res["first_name"] = result["name"]
    res["after_first"] = t2tf_names()
    res["groups_after_first"] = groups()
    f.Steps = 3
    f.UpdatePipeline()
    res["after_rerun"] = t2tf_names()
    res["groups_after_rerun"] = groups()
    f.Prompt = "a   glowing\ncloud"
    f.UpdatePipeline()
    res["after_new_prompt"] = t2tf_names()
    res["groups_after_new_prompt"] = groups()
    res["applied"] = f.GetClientSideObject().result["preset"]["RGBPoints"]
    res["removed"] = t2tf_plugin.remove_presets()
    res["after_remove"] = t2tf_names()
    res["groups_after_remove"] = groups()
elif mode == "estimate":
    # The panel's read-only Time Estimate before any run, after a 3-step run, and after
    # Steps and Views are applied (pushed) without running again.
    f = tf_filter(raw_reader(volume), steps=3)
    proxy = f.SMProxy

    def estimate():
        proxy.UpdatePropertyInformation()
        return proxy.GetProperty("TimeEstimate").GetElement(0)

    res["information_only"] = bool(proxy.GetProperty("TimeEstimate").GetInformationOnly())
    res["before_run"] = estimate()
    f.UpdatePipeline()
    res["after_run"] = estimate()
    f.Steps = 300
    proxy.UpdateVTKObjects()
    res["steps_300"] = estimate()
    f.Views = 4
    proxy.UpdateVTKObjects()
    res["views_4"] = estimate()
    res["timing"] = f.GetClientSideObject().result["timing"]
elif mode in ("state_save", "state_load"):
    # Save a state after one run with a camera of the user's, then load it in a new
    # session: the result comes back without running t2tf, with the saved camera.
    state = os.path.join(os.path.dirname(out_json), "t2tf.pvsm")
    camera = {"position": [200.0, -150.0, 90.0], "focal_point": [31.5, 31.5, 31.5],
              "view_up": [0.0, 0.0, 1.0]}
    if mode == "state_save":
        f = tf_filter(raw_reader(volume), steps=3)
        pvs.Show(f, view)
        record(f, "ImageFile")
        view.CameraPosition = camera["position"]
        view.CameraFocalPoint = camera["focal_point"]
        view.CameraViewUp = camera["view_up"]
        pvs.SaveState(state)
    else:
        pvs.LoadState(state)
        view = pvs.GetActiveViewOrCreate("RenderView")
        f = pvs.FindSource("TextToTransferFunction1")
        pvs.Render(view)
        record(f, "ImageFile")
        res["reused"] = f.GetClientSideObject().reused
        res["saved_camera"] = camera
elif mode == "recover":
    # Failures, bad settings, a new Refine start and a cancelled run, each followed by the
    # Render a property change brings (what the GUI's Apply does): which of them ran t2tf.
    runs_log = os.path.join(os.path.dirname(out_json), "runs.log")

    def runs():
        try:
            with open(runs_log) as fh:
                return len(fh.read().splitlines())
        except OSError:
            return 0

    f = tf_filter(raw_reader(volume), steps=2)
    algo = f.GetClientSideObject()
    res["pipeline_name"] = [name for (name, _), p in pvs.GetSources().items() if p == f][0]
    pvs.Show(f, view)
    steps_seen = []

    def on_progress(obj, _event):
        if "step " in (obj.GetProgressText() or ""):
            steps_seen.append(1)
            if len(steps_seen) == 6:
                obj.SetAbortExecute(1)

    algo.AddObserver("ProgressEvent", on_progress)
    res["after"] = []

    def apply(what, **props):
        steps_seen.clear()
        for k, v in props.items():
            setattr(f, k, v)
        pvs.Render(view)
        res["after"].append({"what": what, "runs": runs(), "error": algo.error,
                             "reused": algo.reused,
                             "interrupted": (algo.result or {}).get("interrupted")})

    apply("first")
    apply("no tokenizer", Tokenizer="")
    apply("steps 3, still no tokenizer", Steps=3)
    apply("tokenizer back", Tokenizer=tokenizer)
    apply("seed 4", Seed=4)
    apply("steps 0", Steps=0)
    apply("steps -3", Steps=-3)
    apply("steps 2", Steps=2)
    # Refine from two presets: each start is its own run (a run's result is the next start).
    def choose(preset):
        pvs.GetColorTransferFunction("ImageFile").ApplyPreset(preset, True)
        pvs.GetOpacityTransferFunction("ImageFile").Points = [0, 0, 0.5, 0, 255, 1, 0.5, 0]

    choose("X Ray")
    apply("refine from X Ray", Refine=1)
    choose("Inferno (matplotlib)")
    apply("refine from Inferno", Seed=5)
    apply("refine from its result", Seed=6)
    choose("Inferno (matplotlib)")
    apply("refine from Inferno again", Seed=5)
    # A cancelled run (the observer aborts after 6 steps) is never reused.
    apply("cancelled", Refine=0, Steps=300, Seed=4)
    apply("steps 2 again", Steps=2)
    apply("steps 300 again", Steps=300)
elif mode == "binary":
    # The binary found on PATH is kept for the session, said once with its version; a binary
    # of another version is refused. The module route is closed, so the binary runs.
    sys.modules["t2tf"] = None
    work = os.path.dirname(out_json)
    counting = os.environ.pop("T2TF_BIN")
    first, second = os.path.join(work, "first"), os.path.join(work, "second")
    for d in (first, second):
        os.makedirs(d, exist_ok=True)
    os.symlink(counting, os.path.join(first, "t2tf"))
    os.environ["PATH"] = first + os.pathsep + os.environ["PATH"]
    f = tf_filter(raw_reader(volume), steps=2)
    algo = f.GetClientSideObject()
    pvs.Show(f, view)
    pvs.Render(view)
    res["first_error"] = algo.error
    # Another t2tf comes first on PATH: it must not take over.
    with open(os.path.join(second, "t2tf"), "w") as fh:
        fh.write("#!/bin/sh\necho taken-over >> '%s'\nexit 1\n" % os.path.join(work, "second.log"))
    os.chmod(os.path.join(second, "t2tf"), 0o755)
    os.environ["PATH"] = second + os.pathsep + os.environ["PATH"]
    f.Seed = 4
    pvs.Render(view)
    res["second_error"] = algo.error
    # A binary of another version, named by T2TF_BIN: refused before it runs.
    other = os.path.join(work, "other-t2tf")
    with open(other, "w") as fh:
        fh.write("#!/bin/sh\n[ \"$1\" = --version ] && echo 't2tf 9.9.9' && exit 0\n"
                 "echo ran >> '%s'\nexit 1\n" % os.path.join(work, "other.log"))
    os.chmod(other, 0o755)
    os.environ["T2TF_BIN"] = other
    f.Seed = 5
    pvs.Render(view)
    res["other_error"] = algo.error
    res["plugin_version"] = t2tf_plugin.__version__
elif mode == "hints":
    # A run that t2tf refuses is one message: t2tf's own words, then what to change in
    # ParaView, from the kind and option t2tf reports (none added to an older t2tf's text).
    work = os.path.dirname(out_json)
    counting = os.environ["T2TF_BIN"]
    src = raw_reader(volume)
    failed = {}

    def fail(case, **props):
        print("CASE", case, flush=True)
        f = tf_filter(src, steps=2)
        for k, v in props.items():
            setattr(f, k, v)
        f.UpdatePipeline()
        algo = f.GetClientSideObject()
        failed[case] = {"error": algo.error, "kind": getattr(algo.failure, "kind", None),
                        "option": getattr(algo.failure, "option", None)}
        pvs.Delete(f)

    def script(name, text):
        path = os.path.join(work, name)
        with open(path, "w") as fh:
            fh.write("#!/bin/sh\n[ \"$1\" = --version ] && echo 't2tf %s' && exit 0\n%s\nexit 1\n"
                     % (t2tf_plugin.__version__, text))
        os.chmod(path, 0o755)
        return path

    # The binary: Views above t2tf's bound (the panel's domain stops at 16, Python does not),
    # and a model folder that is not there.
    fail("binary_views", Views=100)
    fail("binary_model", Model=os.path.join(work, "no-such-model"))
    # A t2tf that reports the kind and option of its error (the --progress json error line).
    os.environ["T2TF_BIN"] = script("reporting-t2tf", "echo '%s' >&2" % json.dumps(
        {"event": "error", "message": "invalid setting `steps`: must be at most 5, got 7",
         "kind": "invalid_option", "option": "steps"}))
    fail("reported", Steps=7)
    # An older t2tf, whose error is a line of text: shown as it is.
    os.environ["T2TF_BIN"] = script("older-t2tf",
                                    "echo \"t2tf: error: invalid value '7' for '--steps'\" >&2")
    fail("older", Steps=7)
    # In-process: a stand-in t2tf module whose error has a kind and option, then one whose
    # error has neither (the kind comes from its class).
    del os.environ["T2TF_BIN"]
    fake = os.path.join(work, "fake")
    os.makedirs(os.path.join(fake, "t2tf"))
    with open(os.path.join(fake, "t2tf", "__init__.py"), "w") as fh:
        fh.write("import os\n__version__ = %r\nclass Error(Exception): pass\n"
                 "class SettingsError(Error): pass\n"
                 "def optimize(volume, prompt, **settings):\n"
                 "    e = SettingsError('invalid setting `views`: must be at most 8, got 100')\n"
                 "    if os.environ.get('T2TF_FAKE_KIND'):\n"
                 "        e.kind, e.option = 'invalid_option', 'views'\n"
                 "    raise e\n" % t2tf_plugin.__version__)
    with open(os.path.join(fake, "t2tf", "vtk.py"), "w") as fh:
        fh.write("def volume_from_vtk(image, array):\n    return None\n")

    def use_module(folder):
        for name in [n for n in sys.modules if n == "t2tf" or n.startswith("t2tf.")]:
            del sys.modules[name]
        sys.path.insert(0, folder)

    use_module(fake)
    os.environ["T2TF_FAKE_KIND"] = "1"
    fail("module_reported", Views=100)
    del os.environ["T2TF_FAKE_KIND"]
    fail("module_class", Views=100)
    # The real module, where the test built it.
    if os.environ.get("T2TF_TEST_MODULE"):
        sys.path.remove(fake)
        use_module(os.environ["T2TF_TEST_MODULE"])
        fail("module_views", Views=100)
        # Another folder, so that its message is not the binary's case's again.
        fail("module_model", Model=os.path.join(work, "no-such-model-2"))
    os.environ["T2TF_BIN"] = counting
    print("CASES DONE", flush=True)
    res["failed"] = failed
elif mode.startswith("series"):
    # A time-varying source (argv's volume is a .pvd): the filter with All Time Steps on
    # optimizes one TF for every step (range: all steps'), reading each step with a progress
    # line; the colour map holds when the animation moves. Then, off: the current step only.
    reader = pvs.OpenDataFile(volume)
    scene = pvs.GetAnimationScene()
    scene.UpdateAnimationUsingDataTimeSteps()
    times = list(reader.TimestepValues)
    ranges = {name: [] for name in reader.PointData.keys()}
    for t in times:
        reader.UpdatePipeline(t)
        for name in ranges:
            ranges[name].append(list(reader.PointData[name].GetRange()))
    res["times"] = times
    # The first step's range differs from all steps' (the gray-scott fixture).
    scene.AnimationTime = times[0]
    f = tf_filter(reader, prompt="a cloud", steps=3)
    f.AllTimeSteps = 1
    algo = f.GetClientSideObject()
    texts = []
    algo.AddObserver("ProgressEvent", lambda obj, _e: texts.append(obj.GetProgressText() or ""))
    pvs.Show(f, view)
    pvs.Render(view)
    res["error"] = algo.error
    res["progress"] = [t for i, t in enumerate(texts) if i == 0 or texts[i - 1] != t]
    array = algo.result["array"]
    res["ranges"] = ranges[array]
    res["all_range"] = [min(r[0] for r in ranges[array]), max(r[1] for r in ranges[array])]
    record(f, array)
    res["report_time_series"] = json.loads(res["field"]["t2tf_report"]).get("time_series")
    # The pipeline is back at the animation's time: the output is the current step's data.
    res["output_range"] = list(f.PointData[array].GetRange())
    lut = pvs.GetColorTransferFunction(array)
    res["rgb_before"] = list(lut.RGBPoints)
    seen = len(texts)
    scene.AnimationTime = times[2]
    pvs.Render(view)
    res["reads_after_time_change"] = len([t for t in texts[seen:] if "reading time step" in t])
    res["output_range_after_time_change"] = list(f.PointData[array].GetRange())
    res["rgb_after_time_change"] = list(lut.RGBPoints)
    res["rescale_after_time_change"] = text(lut.AutomaticRescaleRangeMode)
    res["runs_before_off"] = len([t for t in texts if "step 1/" in t])
    scene.AnimationTime = times[0]
    off = tf_filter(reader, prompt="a cloud", steps=3)
    pvs.Show(off, view)
    pvs.Render(view)
    res["off_error"] = off.GetClientSideObject().error
    res["off_report"] = json.loads(off.GetClientSideObject().result["report"])
    res["off_rgb"] = list(off.GetClientSideObject().result["rgb"])
    # Steps of different spacings: refused, naming the first step that differs. A .pvd:
    # ParaView's .series reader gives every step the first file's extent and spacing.
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter
    from vtkmodules.util.numpy_support import numpy_to_vtk
    import numpy
    work = os.path.dirname(out_json)
    entries = []
    for i, spacing in enumerate((1.0, 1.0, 2.0)):
        name = "odd_%d.vti" % i
        image = vtkImageData()
        image.SetDimensions(8, 8, 8)
        image.SetSpacing(spacing, spacing, spacing)
        values = numpy_to_vtk(numpy.arange(512, dtype=numpy.float32) * (i + 1), deep=1)
        values.SetName("v")
        image.GetPointData().SetScalars(values)
        writer = vtkXMLImageDataWriter()
        writer.SetFileName(os.path.join(work, name))
        writer.SetInputData(image)
        writer.Write()
        entries.append('<DataSet timestep="%d" part="0" file="%s"/>' % (i, name))
    with open(os.path.join(work, "odd.pvd"), "w") as fh:
        fh.write('<VTKFile type="Collection" version="0.1"><Collection>%s</Collection>'
                 '</VTKFile>' % "".join(entries))
    odd = tf_filter(pvs.OpenDataFile(os.path.join(work, "odd.pvd")), steps=2)
    odd.AllTimeSteps = 1
    pvs.Show(odd, view)
    pvs.Render(view)
    res["mismatch_error"] = odd.GetClientSideObject().error
elif mode == "twice":
    # The plugin loaded again (and imported in between): one package, one filter definition,
    # one binary check, one run per update.
    pvs.LoadPlugin(plugin, ns=globals())
    import t2tf_plugin as again  # noqa: E402
    pvs.LoadPlugin(plugin, ns=globals())
    res["same_package"] = again.text_to_transfer_function is t2tf_plugin.text_to_transfer_function
    f = tf_filter(raw_reader(volume), steps=2)
    pvs.Show(f, view)
    pvs.Render(view)
    res["error"] = f.GetClientSideObject().error
    res["has_result"] = f.GetClientSideObject().result is not None
    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
    res["presets"] = [presets.GetPresetName(i) for i in range(presets.GetNumberOfPresets())
                      if presets.GetPresetName(i).startswith("t2tf: ")]
    res["representation"] = text(pvs.GetDisplayProperties(f, view).Representation)
if not mode.startswith("series") and mode not in ("errors", "offline", "panel", "presets", "estimate", "recover", "binary", "hints",
                "twice"):
    pvs.SaveScreenshot(shot, view, ImageResolution=[size, size])
with open(out_json, "w") as fh:
    json.dump(res, fh)
