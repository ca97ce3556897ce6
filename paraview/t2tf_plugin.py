"""ParaView plugin: "Text to Transfer Function" (XML name TextToTransferFunction).

Load it with Tools > Manage Plugins > Load New (this file), with PV_PLUGIN_PATH naming its
folder, or from pvpython with LoadPlugin(path, ns=globals()). The filter takes image data
and runs t2tf in this process when ParaView's Python can import the t2tf module (`pip install
--user .` for the Python ParaView uses, or PYTHONPATH): the point array is handed over
through vtk_to_numpy, no file is written, and ParaView's progress bar and abort button drive
the run. Otherwise (or when T2TF_BIN names a binary) it runs the t2tf binary (T2TF_BIN, else
PATH, else beside this file) with --progress json. The output window says which. Either way
it applies the result to its own output display: colour, opacity, ScalarOpacityUnitDistance,
range never rescaled, the preset registered in ParaView's preset manager, and optionally the
camera of t2tf's view. The output is the input plus field data t2tf_report (report.json),
t2tf_preset (the preset's name) and t2tf_out (the folder t2tf wrote).

Connected to a remote pvserver, use text_to_transfer_function(source, prompt, ...) (or the
macro t2tf_macro.py): it fetches a bounded ResampleToImage proxy of the data, optimizes
locally and applies the TF to the full data's display.

Errors (no binary, empty prompt, input that is not image data, t2tf failing) are one
message in ParaView's output window, never a Python traceback.
"""
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time

from paraview.util.vtkAlgorithm import VTKPythonAlgorithmBase, smdomain, smhint, smproperty, smproxy
from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringArray
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData

TITLE = "Text to Transfer Function"
UNIT_DISTANCE_KEY = "t2tfScalarOpacityUnitDistance"
# Default bound of the proxy fetched from a remote server (points per axis).
PROXY_SIZE = 256


class T2tfError(Exception):
    """A problem the user can fix; shown as one line in ParaView's output window."""


def message(text, error=True):
    """One line in ParaView's output window (stderr in pvpython), prefixed with the title."""
    window = vtkOutputWindow.GetInstance()
    line = "%s: %s\n" % (TITLE, text)
    if error:
        window.DisplayErrorText(line)
    else:
        window.DisplayText(line)


def t2tf_module():
    """The t2tf Python module, or None to run the binary: when T2TF_BIN names one, or when
    this Python cannot import the module."""
    if os.environ.get("T2TF_BIN"):
        return None
    try:
        import t2tf
        import t2tf.vtk  # noqa: F401 (the VTK bridge the filter uses)
    except ImportError:
        return None
    return t2tf


def find_binary():
    """The t2tf executable: T2TF_BIN, then PATH, then beside this plugin."""
    env = os.environ.get("T2TF_BIN")
    if env:
        if os.path.isfile(env) and os.access(env, os.X_OK):
            return env
        raise T2tfError("T2TF_BIN=%s is not an executable file" % env)
    on_path = shutil.which("t2tf")
    if on_path:
        return on_path
    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("t2tf", "t2tf.exe"):
        beside = os.path.join(here, name)
        if os.path.isfile(beside) and os.access(beside, os.X_OK):
            return beside
    raise T2tfError(
        "the t2tf binary was not found: set T2TF_BIN, put t2tf on PATH, or copy it beside " + here
    )


# Runs in progress, so that cancel() (from a Python shell, a macro or a test) can stop them.
_RUNS = []


def cancel():
    """Ask every running t2tf to stop after its current step (it keeps that step's TF)."""
    for run in list(_RUNS):
        run.cancel()


class Run:
    """One `t2tf optimize --progress json` child: its progress, cancellation and result."""

    def __init__(self, args, out):
        self.args, self.out = args, out
        self.lines = queue.Queue()
        self.cancelled = False
        self.done = None
        self.tail = []

    def cancel(self):
        if not self.cancelled and self.proc.poll() is None:
            # SIGINT: t2tf finishes the current step and writes the last finished step's TF.
            self.cancelled = True
            self.proc.send_signal(signal.SIGINT)

    def _read(self):
        for line in self.proc.stderr:
            self.lines.put(line)
        self.lines.put(None)

    def run(self, progress=None, aborted=None, timeout=None):
        """Run to the end; `progress(fraction, text)` per step; `aborted()` polled to cancel."""
        self.proc = subprocess.Popen(
            self.args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        _RUNS.append(self)
        try:
            reader = threading.Thread(target=self._read, daemon=True)
            reader.start()
            start = time.time()
            while True:
                if aborted is not None and aborted():
                    self.cancel()
                if timeout is not None and time.time() - start > timeout:
                    self.cancel()
                try:
                    line = self.lines.get(timeout=0.1)
                except queue.Empty:
                    continue
                if line is None:
                    break
                self._line(line, progress)
            self.proc.wait()
        finally:
            _RUNS.remove(self)
        # A run stopped by a signal (the cancel sends SIGINT) exits with 128 + the signal after
        # writing the last finished step's result; its done event says so.
        stopped = self.done is not None and self.done.get("interrupted")
        if self.done is None or (self.proc.returncode != 0 and not stopped):
            raise T2tfError(
                "t2tf failed (exit status %s): %s"
                % (self.proc.returncode, " | ".join(self.tail[-3:]) or "no output")
            )
        return self.done

    def _line(self, line, progress):
        line = line.strip()
        try:
            event = json.loads(line)
        except ValueError:
            # Not progress: keep the last lines for the error message.
            if line:
                self.tail.append(line)
            return
        kind = event.get("event")
        if kind == "step" and progress is not None:
            steps = max(1, int(event.get("steps", 1)))
            progress(float(event["step"]) / steps, "step %s/%s" % (event["step"], steps))
        elif kind == "done":
            self.done = event
        elif kind == "error" and "message" in event:
            self.tail.append(event["message"])


def optimize(volume, out, prompt, negatives=(), steps=300, views=3, seed=0, model=None,
             tokenizer=None, array=None, reference_image=None, extra=(), progress=None,
             aborted=None, timeout=None, init=None, locks=()):
    """Run t2tf on a volume file; returns the result (see read_result). `init`: a TF file
    to start from; `locks`: (min, max) data ranges kept as they start."""
    if not (prompt or "").strip() and not reference_image:
        raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")
    args = [find_binary(), "optimize", volume, "--out", out, "--progress", "json"]
    if (prompt or "").strip():
        args += ["--prompt", prompt]
    for n in negatives or ():
        if n.strip():
            args += ["--negative", n]
    args += ["--steps", str(int(steps)), "--views", str(int(views)), "--seed", str(int(seed))]
    if model:
        args += ["--model", model]
    if tokenizer:
        args += ["--tokenizer", tokenizer]
    if array:
        args += ["--array", array]
    if reference_image:
        args += ["--reference-image", reference_image]
    if init:
        args += ["--init", init]
    for lo, hi in locks or ():
        args += ["--lock=%r,%r" % (float(lo), float(hi))]
    args += list(extra)
    done = Run(args, out).run(progress, aborted, timeout)
    return read_result(done)


def optimize_in_process(t2tf, image, array, out, prompt, negatives=(), steps=300, views=3,
                        seed=0, model=None, tokenizer=None, reference_image=None,
                        progress=None, aborted=None, init=None, locks=()):
    """Run t2tf in this process on `image`'s point array `array` (read in place, no file
    written) and save its files into `out`; returns the result as read_result gives it.
    `progress(fraction, text)` per step; `aborted()` is asked after each step and stops the
    run there (keeping that step's TF)."""
    if not (prompt or "").strip() and not reference_image:
        raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")

    def on_event(event):
        if event["event"] == "step" and progress is not None:
            steps_ = max(1, int(event["steps"]))
            progress(float(event["step"]) / steps_, "step %s/%s" % (event["step"], steps_))
        elif event["event"] == "warning":
            message("warning: " + event["message"], False)
        return not (aborted is not None and aborted())

    try:
        volume = t2tf.vtk.volume_from_vtk(image, array)
        run = t2tf.optimize(
            volume, (prompt or "").strip() or None, negatives=[n for n in negatives if n.strip()],
            steps=int(steps), views=int(views), seed=int(seed), model=model or None,
            tokenizer=tokenizer or None, reference_image=reference_image or None,
            progress=on_event, init=init or None, lock=[tuple(l) for l in locks or ()])
        report = run.save(out)
    except (t2tf.Error, ValueError) as e:
        raise T2tfError(str(e))
    result = read_result({"out": out, "files": report["outputs"], "interrupted": run.interrupted})
    # An array has no file to reopen, so no pvpython script holds the camera: the run has it.
    result["camera"] = run.camera
    return result


def parse_locks(text):
    """'MIN,MAX; MIN,MAX' (the Lock Ranges property) as [(min, max), ...]."""
    locks = []
    for part in (text or "").replace("\n", ";").split(";"):
        if not part.strip():
            continue
        try:
            lo, hi = (float(v) for v in part.split(","))
        except ValueError:
            raise T2tfError("Lock Ranges: %r is not MIN,MAX (e.g. 120,400; 800,1200)" % part.strip())
        locks.append((lo, hi))
    return locks


def write_current_tf(array, path, source=None):
    """Write the colour and opacity functions ParaView now uses for `array` (and the unit
    distance of `source`'s display) as a preset file: the start of a Refine."""
    import paraview.simple as pvs

    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    rgb, points = list(lut.RGBPoints), list(pwf.Points)
    if len(rgb) < 8 or len(points) < 8:
        raise T2tfError("Refine: %s has no colour and opacity function to start from" % array)
    space = _text(lut.ColorSpace)
    preset = {"Name": "current", "ColorSpace": space, "RGBPoints": rgb, "Points": points}
    if space == "HSV":
        preset["HSVWrap"] = int(lut.HSVWrap)
    if source is not None:
        disp = pvs.GetDisplayProperties(source)
        preset[UNIT_DISTANCE_KEY] = float(disp.ScalarOpacityUnitDistance)
    with open(path, "w") as f:
        json.dump([preset], f)
    return path


def _script_list(text, name):
    for line in text.splitlines():
        if line.startswith(name + " = "):
            return json.loads(line[len(name) + 3:])
    return None


def read_result(done):
    """The files named by t2tf's done event: preset, unit distance, camera, report."""
    out = done["out"]
    files = done.get("files", [])
    preset_file = next(
        (os.path.join(out, f) for f in files
         if f.endswith(".json") and f != "report.json"), None)
    if preset_file is None:
        raise T2tfError("t2tf wrote no preset in " + out)
    with open(preset_file) as f:
        data = json.load(f)
    preset = data[0] if isinstance(data, list) else data
    result = {
        "out": out,
        "preset_file": preset_file,
        "name": preset["Name"],
        "rgb": [float(v) for v in preset["RGBPoints"]],
        "points": [float(v) for v in preset.get("Points", [])],
        "unit_distance": preset.get(UNIT_DISTANCE_KEY),
        "interrupted": bool(done.get("interrupted")),
        "camera": None,
        "report": "",
    }
    report = os.path.join(out, "report.json")
    if os.path.exists(report):
        with open(report) as f:
            result["report"] = f.read()
    # The camera of t2tf's view: the one its generated pvpython script sets.
    script = next((os.path.join(out, f) for f in files if f.endswith("_paraview.py")), None)
    if script:
        with open(script) as f:
            text = f.read()
        cam = {k: _script_list(text, "CAMERA_" + k.upper())
               for k in ("position", "focal_point", "view_up")}
        angle = re.search(r"^CAMERA_VIEW_ANGLE = (.+)$", text, re.M)
        if all(cam.values()) and angle:
            cam["view_angle"] = float(angle.group(1))
            result["camera"] = cam
    return result


# ---- client side: presets, displays, camera -------------------------------------------

def register_preset(result):
    """Import the preset into ParaView's preset manager (once per name: t2tf's names carry
    a content hash, and re-importing an existing name is fragile)."""
    import paraview.simple as pvs
    from paraview import servermanager

    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
    if not presets.HasPreset(result["name"]):
        pvs.ImportPresets(result["preset_file"])
    return bool(presets.HasPreset(result["name"]))


def apply_transfer_function(result, array):
    """Set the array's colour and opacity functions to t2tf's points, never rescaled."""
    import paraview.simple as pvs

    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    lut.AutomaticRescaleRangeMode = "Never"
    lut.ColorSpace = "RGB"
    lut.RGBPoints = result["rgb"]
    lut.ScalarRangeInitialized = 1
    if result["points"]:
        pwf.Points = result["points"]
        pwf.ScalarRangeInitialized = 1
    return lut, pwf


def apply_to_display(result, source, view=None, array=None, camera=True):
    """Show `source` as a volume in `view` with t2tf's TF, unit distance and (optionally)
    camera. Returns the display."""
    import paraview.simple as pvs

    view = view or pvs.GetActiveViewOrCreate("RenderView")
    array = array or result.get("array")
    disp = pvs.GetDisplayProperties(source, view)
    disp.Representation = "Volume"
    pvs.ColorBy(disp, ("POINTS", array))
    lut, pwf = apply_transfer_function(result, array)
    disp.LookupTable = lut
    disp.ScalarOpacityFunction = pwf
    if result.get("unit_distance") is not None:
        disp.ScalarOpacityUnitDistance = float(result["unit_distance"])
    if camera and result.get("camera"):
        apply_camera(result["camera"], view)
    return disp


def apply_camera(cam, view):
    view.CameraPosition = cam["position"]
    view.CameraFocalPoint = cam["focal_point"]
    view.CameraViewUp = cam["view_up"]
    view.CameraViewAngle = cam["view_angle"]
    view.CameraParallelProjection = 0


# Results of filters run in this process, applied to their displays as those appear
# (ParaView creates a filter's display after its first update, so RequestData cannot).
_PENDING = {}
_OBSERVED = []


def _proxy_of(algorithm):
    """The source proxy whose VTK object is `algorithm` (builtin session), else None."""
    from paraview import servermanager

    if servermanager.ActiveConnection is None:
        return None
    for proxy in servermanager.ProxyManager().GetProxiesInGroup("sources").values():
        try:
            if proxy.GetClientSideObject() is algorithm:
                return proxy
        except AttributeError:
            continue
    return None


def _apply_pending(*_):
    """Apply each pending result to every display of its filter not yet given it. Displays
    are found among registered representations (not through views: ParaView registers a
    new display before adding it to its view)."""
    import paraview.simple as pvs
    from paraview import servermanager

    if not _PENDING:
        return
    reprs = servermanager.ProxyManager().GetProxiesInGroup("representations").values()
    for proxy, result, camera, applied in list(_PENDING.values()):
        for disp in reprs:
            try:
                if disp.Input.SMProxy is not proxy.SMProxy:
                    continue
                disp.ScalarOpacityUnitDistance
            except AttributeError:
                continue  # not a display of this filter, or not a 3D one
            key = disp.GetGlobalIDAsString()
            if key in applied:
                continue
            applied.add(key)
            disp.Representation = "Volume"
            pvs.ColorBy(disp, ("POINTS", result["array"]))
            lut, pwf = apply_transfer_function(result, result["array"])
            disp.LookupTable = lut
            disp.ScalarOpacityFunction = pwf
            if result.get("unit_distance") is not None:
                disp.ScalarOpacityUnitDistance = float(result["unit_distance"])
            if camera and result.get("camera"):
                for view in pvs.GetViews():
                    if view.GetXMLName() == "RenderView":
                        apply_camera(result["camera"], view)


def _watch_displays():
    """Apply pending results whenever a proxy (e.g. a new display) is registered."""
    from paraview import servermanager

    pxm = servermanager.ProxyManager().SMProxyManager
    if pxm not in _OBSERVED:
        pxm.AddObserver("RegisterEvent", _apply_pending)
        _OBSERVED.append(pxm)


# ---- the filter ----------------------------------------------------------------------

def _text(value):
    """An enumeration property's text (its GetData()), else the value as text."""
    return str(value.GetData() if hasattr(value, "GetData") else value)


def _upstream_file(proxy, array):
    """(path, extra t2tf flags) when the filter's input is a file t2tf reads, else None."""
    try:
        reader = proxy.Input
        name = reader.GetXMLName()
    except AttributeError:
        return None
    if name == "XMLImageDataReader":
        names = list(reader.FileName)  # a FileNameProperty, not a str
        if len(names) == 1 and names[0].lower().endswith(".vti"):
            return (names[0], [])
        return None
    if name == "ImageReader" and len(list(reader.FileNames)) == 1:
        types = {"unsigned char": "uint8", "char": "int8", "unsigned short": "uint16",
                 "short": "int16", "unsigned int": "uint32", "int": "int32",
                 "float": "float32", "double": "float64"}
        dtype = types.get(_text(reader.DataScalarType))
        e = list(reader.DataExtent)
        # FileDimensionality is an enumeration property: compare its text.
        if (dtype is None or reader.NumberOfScalarComponents != 1
                or _text(reader.FileDimensionality) != "3"
                or any(e[i] != 0 for i in (0, 2, 4)) or any(reader.DataOrigin)):
            return None
        dims = "%d,%d,%d" % (e[1] + 1, e[3] + 1, e[5] + 1)
        spacing = ",".join(repr(float(s)) for s in reader.DataSpacing)
        order = "big" if _text(reader.DataByteOrder) == "BigEndian" else "little"
        return (list(reader.FileNames)[0],
                ["--dims", dims, "--dtype", dtype, "--spacing", spacing, "--byte-order", order])
    return None


def write_vti(image, array, path):
    """The image with only `array` (as its scalars) as a .vti file t2tf reads."""
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    copy = vtkImageData()
    copy.SetExtent(image.GetExtent())
    copy.SetOrigin(image.GetOrigin())
    copy.SetSpacing(image.GetSpacing())
    copy.GetPointData().SetScalars(image.GetPointData().GetArray(array))
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(path)
    writer.SetInputData(copy)
    if not writer.Write():
        raise T2tfError("could not write the input to " + path)


@smproxy.filter(name="TextToTransferFunction", label=TITLE)
@smhint.xml('<ShowInMenu category="t2tf" /><RepresentationType view="RenderView" type="Volume" />')
@smproperty.input(name="Input", port_index=0)
@smdomain.datatype(dataTypes=["vtkImageData"], composite_data_supported=False)
# The domain the Array property's ArrayListDomain names: point arrays of one component.
@smdomain.xml('<InputArrayDomain name="input_array" attribute_type="point" '
              'number_of_components="1" />')
class TextToTransferFunction(VTKPythonAlgorithmBase):
    """Optimizes a transfer function for a sentence with t2tf and shows the data with it."""

    def __init__(self):
        VTKPythonAlgorithmBase.__init__(
            self, nInputPorts=1, nOutputPorts=1, outputType="vtkImageData")
        self._prompt = ""
        self._negatives = []
        self._steps = 300
        self._views = 3
        self._seed = 0
        self._model = "openai/clip-vit-base-patch32"
        self._tokenizer = ""
        self._reference = ""
        self._camera = 1
        self._refine = 0
        self._locks = ""
        self.result = None

    def FillInputPortInformation(self, port, info):
        # Any data object reaches RequestData, which names the problem in one line; the
        # datatype domain above still offers the filter only for image data in the GUI.
        info.Set(self.INPUT_REQUIRED_DATA_TYPE(), "vtkDataObject")
        return 1

    @smproperty.stringvector(name="Prompt", default_values="")
    def SetPrompt(self, value):
        self._prompt = value or ""
        self.Modified()

    @smproperty.xml("""
        <StringVectorProperty name="Negatives" command="SetNegative" clean_command="ClearNegatives"
            repeat_command="1" number_of_elements_per_command="1" default_values="a blank image">
          <Documentation>What to suppress (several strings).</Documentation>
        </StringVectorProperty>""")
    def SetNegative(self, value):
        self._negatives.append(value)
        self.Modified()

    def ClearNegatives(self):
        self._negatives = []
        self.Modified()

    @smproperty.intvector(name="Steps", default_values=300)
    @smdomain.intrange(min=0, max=2000)
    def SetSteps(self, value):
        self._steps = int(value)
        self.Modified()

    @smproperty.intvector(name="Views", default_values=3)
    @smdomain.intrange(min=1, max=16)
    def SetViews(self, value):
        self._views = int(value)
        self.Modified()

    @smproperty.intvector(name="Seed", default_values=0)
    def SetSeed(self, value):
        self._seed = int(value)
        self.Modified()

    @smproperty.stringvector(name="Model", default_values="openai/clip-vit-base-patch32")
    def SetModel(self, value):
        self._model = value or ""
        self.Modified()

    @smproperty.stringvector(name="Tokenizer", default_values="")
    @smdomain.filelist()
    @smhint.filechooser(extensions="json", file_description="tokenizer.json")
    def SetTokenizer(self, value):
        self._tokenizer = value or ""
        self.Modified()

    @smproperty.xml("""
        <StringVectorProperty name="Array" command="SetInputArrayToProcess"
            number_of_elements="5" element_types="0 0 0 0 2" animateable="0">
          <ArrayListDomain name="array_list" attribute_type="Scalars" input_domain_name="input_array">
            <RequiredProperties><Property name="Input" function="Input" /></RequiredProperties>
          </ArrayListDomain>
          <Documentation>The point array (default: the active scalars).</Documentation>
        </StringVectorProperty>""")
    def SetInputArrayToProcess(self, idx, port, connection, field, name):
        VTKPythonAlgorithmBase.SetInputArrayToProcess(self, idx, port, connection, field, name)
        self.Modified()

    @smproperty.stringvector(name="ReferenceImage", default_values="")
    @smdomain.filelist()
    @smhint.filechooser(extensions="png", file_description="PNG image")
    def SetReferenceImage(self, value):
        self._reference = value or ""
        self.Modified()

    @smproperty.xml("""
        <IntVectorProperty name="Refine" command="SetRefine" number_of_elements="1"
            default_values="0">
          <BooleanDomain name="bool" />
          <Documentation>Start from the colour and opacity functions the array has now (the
          last result, or a preset you chose) instead of t2tf's initialization. Refining needs
          far fewer steps than a fresh run.</Documentation>
        </IntVectorProperty>""")
    def SetRefine(self, value):
        self._refine = int(value)
        self.Modified()

    @smproperty.xml("""
        <StringVectorProperty name="LockRanges" label="Lock Ranges" command="SetLockRanges"
            number_of_elements="1" default_values="">
          <Documentation>Data ranges whose transfer function stays as it starts, e.g.
          "120,400; 800,1200": the rest is optimized around them.</Documentation>
        </StringVectorProperty>""")
    def SetLockRanges(self, value):
        self._locks = value or ""
        self.Modified()

    @smproperty.intvector(name="ApplyCamera", default_values=1)
    @smdomain.xml('<BooleanDomain name="bool" />')
    def SetApplyCamera(self, value):
        self._camera = int(value)
        self.Modified()

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        # t2tf needs the whole volume, not a piece.
        info = inInfo[0].GetInformationObject(0)
        sddp = self.GetExecutive()
        if info.Has(sddp.WHOLE_EXTENT()):
            info.Set(sddp.UPDATE_EXTENT(), info.Get(sddp.WHOLE_EXTENT()), 6)
        return 1

    def _array(self, image):
        info = self.GetInputArrayInformation(0)
        name = info.Get(vtkDataObject.FIELD_NAME()) if info is not None else None
        if name and image.GetPointData().GetArray(name) is not None:
            return name
        scalars = image.GetPointData().GetScalars()
        if scalars is not None and scalars.GetName():
            return scalars.GetName()
        if image.GetPointData().GetNumberOfArrays() > 0:
            return image.GetPointData().GetArrayName(0)
        raise T2tfError("the input has no point array to optimize a transfer function for")

    def RequestData(self, request, inInfo, outInfo):
        data = vtkDataObject.GetData(inInfo[0])
        out = vtkImageData.GetData(outInfo)
        if not isinstance(data, vtkImageData):
            message("the input is a %s, not image data (vtkImageData): resample it first, "
                    "e.g. with Resample To Image" % (data.GetClassName() if data else "nothing"))
            return 1
        out.ShallowCopy(data)
        try:
            result = self._run(data)
        except T2tfError as e:
            message(str(e))
            return 1
        except Exception as e:  # a bug of ours: still one line, not a traceback
            message("internal error: %s: %s" % (type(e).__name__, e))
            return 1
        self.result = result
        # A cancelled run still produced a TF (the last finished step's): clear the abort
        # flag so the pipeline keeps this output instead of discarding it.
        self.SetAbortExecute(0)
        self._annotate(out, result)
        try:
            self._show(result)
        except Exception as e:  # the TF is in the output; say why it is not shown
            message("could not apply the result to the display: %s" % e)
        return 1

    def _run(self, image):
        array = self._array(image)
        module = t2tf_module()
        binary = None if module else find_binary()  # fail early, before writing anything
        if not self._prompt.strip() and not self._reference:
            raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")
        locks = parse_locks(self._locks)
        out = tempfile.mkdtemp(prefix="t2tf-plugin-")
        init = None
        if self._refine:
            proxy = _proxy_of(self)
            source = proxy.Input if proxy is not None else None
            init = write_current_tf(array, os.path.join(out, "start.json"), source)
        self.UpdateProgress(0.0)
        if module:
            message("running t2tf %s in-process (%s)" % (module.__version__, module.__file__),
                    False)
            result = optimize_in_process(
                module, image, array, os.path.join(out, "tf"), self._prompt, self._negatives,
                self._steps, self._views, self._seed, self._model or None,
                self._tokenizer or None, self._reference or None,
                progress=lambda f, text: self.UpdateProgress(f), aborted=self.GetAbortExecute,
                init=init, locks=locks)
            volume = None
        else:
            message("running the t2tf binary %s" % binary, False)
            result, volume = self._run_binary(image, array, out, init, locks)
        self.UpdateProgress(1.0)
        result["array"] = array
        result["volume"] = volume
        if result["interrupted"]:
            message("cancelled: kept the transfer function of the last finished step", False)
        return result

    def _run_binary(self, image, array, out, init=None, locks=()):
        """`t2tf optimize` on the upstream file, else on the image written to a .vti."""
        proxy = _proxy_of(self)
        upstream = _upstream_file(proxy, array) if proxy is not None else None
        extra = []
        if upstream:
            volume, extra = upstream
            if volume.lower().endswith(".vti"):
                extra = ["--array", array]
        else:
            volume = os.path.join(out, "input.vti")
            write_vti(image, array, volume)
        result = optimize(
            volume, os.path.join(out, "tf"), self._prompt, self._negatives, self._steps,
            self._views, self._seed, self._model or None, self._tokenizer or None,
            reference_image=self._reference or None, extra=extra,
            progress=lambda f, text: self.UpdateProgress(f),
            aborted=self.GetAbortExecute, init=init, locks=locks)
        return result, volume

    def _annotate(self, out, result):
        fd = out.GetFieldData()
        for key, value in (("t2tf_report", result["report"]), ("t2tf_preset", result["name"]),
                           ("t2tf_out", result["out"])):
            a = vtkStringArray()
            a.SetName(key)
            a.InsertNextValue(value)
            fd.AddArray(a)

    def _show(self, result):
        proxy = _proxy_of(self)
        if proxy is None:
            return  # on a server: nothing to show here
        register_preset(result)
        apply_transfer_function(result, result["array"])
        _PENDING[id(self)] = (proxy, result, bool(self._camera), set())
        _watch_displays()
        _apply_pending()


# ---- remote servers ------------------------------------------------------------------

def text_to_transfer_function(source=None, prompt="", negatives=(), steps=300, views=3, seed=0,
                              model=None, tokenizer=None, array=None, reference_image=None,
                              proxy_size=None, view=None, camera=True, timeout=None, extra=(),
                              refine=False, locks=()):
    """Optimize a TF for `source` (default: the active source) and show it with it.
    `refine` starts from the array's current colour and opacity functions; `locks` are
    (min, max) data ranges kept as they start.

    In a builtin session this creates the TextToTransferFunction filter. Connected to a
    remote server it asks the server for a ResampleToImage proxy of at most `proxy_size`
    points per axis (default 256, or T2TF_PROXY_SIZE), fetches only that, runs t2tf here and
    applies the TF to `source`'s own display (full resolution, on the server). `extra` are
    further `t2tf optimize` flags (remote only), e.g. ["--l1", "0.001"].
    Returns (result, proxy_or_filter). Raises T2tfError with a one-line reason.
    """
    import paraview.simple as pvs
    from paraview import servermanager

    source = source or pvs.GetActiveSource()
    if source is None:
        raise T2tfError("no active source: open a volume first")
    if not (prompt or "").strip() and not reference_image:
        raise T2tfError("the prompt is empty: type what the rendering should show")
    if servermanager.ActiveConnection.IsRemote() or t2tf_module() is None:
        find_binary()  # fail early and clearly (remote runs always use the binary)
    source.UpdatePipeline()
    info = source.GetDataInformation()
    if info.GetDataClassName() not in ("vtkImageData", "vtkUniformGrid", "vtkStructuredPoints"):
        raise T2tfError("the input is a %s, not image data (vtkImageData)" % info.GetDataClassName())
    array = array or _active_array(source)
    if not servermanager.ActiveConnection.IsRemote():
        # paraview.simple names the function after the label: TexttoTransferFunction.
        f = pvs.TexttoTransferFunction(Input=source, Prompt=prompt, Negatives=list(negatives),
                                       Steps=steps, Views=views, Seed=seed,
                                       Model=model or "openai/clip-vit-base-patch32",
                                       Tokenizer=tokenizer or "", ReferenceImage=reference_image or "",
                                       Refine=int(bool(refine)),
                                       LockRanges="; ".join("%r,%r" % (float(a), float(b))
                                                            for a, b in locks))
        f.Array = ["POINTS", array]
        pvs.Show(f, view)
        algo = f.GetClientSideObject()
        if algo.result is None:
            raise T2tfError("t2tf gave no result (see the messages above)")
        return algo.result, f
    size = proxy_size_setting(proxy_size)
    dims = _proxy_dims(info.GetExtent(), size)
    local, fetched = fetch_proxy(source, dims)
    out = tempfile.mkdtemp(prefix="t2tf-plugin-")
    volume = os.path.join(out, "proxy.vti")
    write_vti(local, array, volume)
    init = write_current_tf(array, os.path.join(out, "start.json"), source) if refine else None
    result = optimize(volume, os.path.join(out, "tf"), prompt, negatives, steps, views, seed,
                      model, tokenizer, array=array, reference_image=reference_image,
                      extra=extra, timeout=timeout, init=init, locks=locks)
    result.update(array=array, volume=volume, proxy_dims=dims, fetched_points=fetched)
    register_preset(result)
    view = view or pvs.GetActiveViewOrCreate("RenderView")
    pvs.Show(source, view)
    # The full data's own display: on the server, at full resolution. The TF transfers
    # because t2tf's opacity is per normalized box length (docs/DESIGN.md) and the proxy
    # spans the same box (UseInputBounds).
    apply_to_display(result, source, view, array, camera)
    return result, local


def proxy_size_setting(proxy_size=None):
    """Points per axis of the remote proxy: the argument, else T2TF_PROXY_SIZE, else 256."""
    raw = proxy_size if proxy_size is not None else os.environ.get("T2TF_PROXY_SIZE")
    if raw is None or str(raw).strip() == "":
        return PROXY_SIZE
    try:
        size = int(raw)
    except ValueError:
        raise T2tfError("the proxy size must be a whole number of points per axis, not %r" % raw)
    if size < 2:
        raise T2tfError("the proxy size must be at least 2 points per axis, not %d" % size)
    return size


def fetch_proxy(source, dims):
    """Resample `source` on the server with ParaView's ResampleToImage to `dims` points over
    its own bounds and bring only that to the client. Returns (image, points fetched).

    Under MPI the resampled image is distributed: rank r holds a piece whose extent shares a
    boundary plane with its neighbour's. servermanager.Fetch with no rank would merge the
    pieces with vtkAppendFilter (an unstructured grid), so each rank's piece is fetched on its
    own (Fetch(proxy, rank)) and the pieces are put back into one image by extent here
    (vtkImageAppend with PreserveExtents)."""
    import paraview.simple as pvs
    from paraview import servermanager
    from vtkmodules.vtkFiltersCore import vtkImageAppend

    resample = pvs.ResampleToImage(Input=source)
    try:
        resample.UseInputBounds = 1
        resample.SamplingDimensions = list(dims)
        resample.UpdatePipeline()
        ranks = max(1, servermanager.ActiveConnection.GetNumberOfDataPartitions())
        pieces = []
        for rank in range(ranks):
            # Always by rank: with no rank Fetch merges through vtkAppendFilter, which turns
            # image data into an unstructured grid even on one rank.
            piece = servermanager.Fetch(resample, rank)
            if piece is not None and piece.GetNumberOfPoints() > 0:
                pieces.append(piece)
    finally:
        pvs.Delete(resample)
    if not pieces:
        raise T2tfError("the server's ResampleToImage proxy of the data is empty")
    fetched = sum(p.GetNumberOfPoints() for p in pieces)
    if len(pieces) == 1:
        image = pieces[0]
    else:
        append = vtkImageAppend()
        append.PreserveExtentsOn()
        for piece in pieces:
            append.AddInputData(piece)
        append.Update()
        image = append.GetOutput()
    got = list(image.GetDimensions())
    if got != list(dims):
        raise T2tfError("the server's proxy has %s points per axis, expected %s" % (got, list(dims)))
    return image, fetched


def _active_array(source):
    info = source.GetPointDataInformation()
    if info.GetNumberOfArrays() == 0:
        raise T2tfError("the input has no point array to optimize a transfer function for")
    try:
        active = source.PointData.keys()
    except AttributeError:
        active = []
    return active[0] if active else info.GetArray(0).GetName()


def _proxy_dims(extent, size):
    """Points per axis of the proxy: the data's own, scaled down so none exceeds `size`."""
    dims = [extent[2 * i + 1] - extent[2 * i] + 1 for i in range(3)]
    scale = min(1.0, float(size) / max(dims))
    return [max(2, min(size, int(round(d * scale)))) for d in dims]
