"""The ParaView filter "Text To Transfer Function" (XML name TextToTransferFunction).

Its properties are declared by ParaView's decorators on their setters, in the order the panel
lists them. RequestData computes and nothing else: it runs t2tf on the input (run.py), or
reuses a result made from the same input and settings (Undo, Redo, a loaded state), and passes
the input through with the report as field data; watch.py shows the result after the update.
On a pvserver it only passes the data through: the client runs t2tf (watch.py, remote.py).
"""
import json
from xml.sax.saxutils import escape

from paraview.util.vtkAlgorithm import (VTKPythonAlgorithmBase, smdomain, smhint, smproperty,
                                        smproxy)
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP
from vtkmodules.vtkCommonCore import vtkStringArray
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData

from . import display, gui, inputs, run, timing
from .api import DEFAULT_MODEL
from .errors import TITLE, T2tfError, say

# Results each filter keeps in memory, so Undo and Redo of an Apply do not run t2tf again.
CACHED_RESULTS = 8


def _doc(text):
    """A property's Documentation (its tooltip). ParaView's decorators nest the XML of
    domains in the property they decorate; Documentation is one more such child."""
    return smdomain.xml("<Documentation>%s</Documentation>" % escape(" ".join(text.split())))


def _undecorated(obj):
    while hasattr(obj, "_pv_original_func"):
        obj = obj._pv_original_func
    return obj


def _in_panel_order(decorated):
    """ParaView's smproxy sorts the properties declared on methods by method name, while the
    panel lists properties in the XML's order. So they are moved, in the order the class
    defines them, to the end of the class's own list, which smproxy keeps first and as is."""
    cls = _undecorated(decorated)
    xmls = list(getattr(cls, "_pvsm_property_xmls", []))
    for value in list(vars(cls).values()):
        method = _undecorated(value)
        if callable(method) and hasattr(method, "_pvsm_property_xmls"):
            xmls += method._pvsm_property_xmls
            del method._pvsm_property_xmls
    cls._pvsm_property_xmls = xmls
    return decorated


DESCRIPTION = """
<Documentation short_help="Optimize a transfer function for a sentence with t2tf."
    long_help="Optimizes a volume-rendering transfer function (colour and opacity) so that
    renderings of the data match a sentence under CLIP, and shows the data with it.">
  Text To Transfer Function runs t2tf on the input image data: it renders the volume from
  random views, scores the renderings against the Prompt (and against the Negatives) with a
  CLIP model, and optimizes the colour and opacity functions by gradient descent. The result
  is applied to the output's display (colour, opacity, unit distance, no automatic
  rescaling), registered as the preset "t2tf: PROMPT", and kept with a saved state. The run
  time grows with Steps x Views; the progress bar shows the step, the loss and the time
  left, and Abort (or t2tf_plugin.cancel() in Python) stops after the current step, keeping
  that step's transfer function.
</Documentation>"""

# Where the Input may come from and which arrays it must have (the datatype decorator gives
# the data type): the filter is offered for image data with a one-component point array.
INPUT_DOMAINS = """
<ProxyGroupDomain name="groups"><Group name="sources" /><Group name="filters" /></ProxyGroupDomain>
<InputArrayDomain name="input_array" attribute_type="point" number_of_components="1" />
<Documentation>Image data with a point array of one component.</Documentation>"""


@smproxy.filter(name="TextToTransferFunction", label=TITLE, support_reload=False)
@smhint.xml('<ShowInMenu category="t2tf" />')
@_in_panel_order
@smproperty.input(name="Input", port_index=0)
@smdomain.datatype(dataTypes=["vtkImageData"], composite_data_supported=0)
@smdomain.xml(INPUT_DOMAINS)
@smproperty.xml(DESCRIPTION)
class TextToTransferFunction(VTKPythonAlgorithmBase):
    """Optimizes a transfer function for a sentence with t2tf; passes the data through."""

    def __init__(self):
        VTKPythonAlgorithmBase.__init__(
            self, nInputPorts=1, nOutputPorts=1, outputType="vtkImageData")
        self._prompt = ""
        self._negatives = []
        self._steps = 300
        self._views = 3
        self._seed = 0
        self._model = DEFAULT_MODEL
        self._tokenizer = ""
        self._reference = ""
        self._camera = 0
        self._refine = 0
        self._locks = ""
        self._all_steps = 0
        # The digests of the time steps last read, with the input's pipeline time and steps
        # they were read at: moving the animation re-executes the filter, which then finds
        # its result without reading every step again.
        self._series_memo = None
        self._cache = {}  # settings-and-input key -> result, the last CACHED_RESULTS runs
        self.stored = None  # the Result property, parsed: {"key": ..., "result": ...}
        self.result = None
        self.failure = None  # the T2tfError of the last update, if it failed
        self.error = None  # ... as text
        self.reused = False  # the result shown was not computed by this update
        self.restored = False  # ... and came from the Result property (a loaded state)

    def FillInputPortInformation(self, port, info):
        # Any data object reaches RequestData, which names the problem in one line; the
        # datatype domain still offers the filter only for image data in the GUI.
        info.Set(self.INPUT_REQUIRED_DATA_TYPE(), "vtkDataObject")
        return 1

    # ---- properties, in the panel's order (advanced ones behind the gear button) ----------

    @smproperty.stringvector(name="Prompt", default_values="")
    @_doc("""What the rendering should show, in plain words, e.g. "a potted tree" or "the
        teeth of a CT head".""")
    def SetPrompt(self, value):
        self._prompt = value or ""
        self.Modified()

    @smproperty.stringvector(name="Negatives", label="Negatives", clean_command="ClearNegatives",
                             repeat_command=1, number_of_elements_per_command=1,
                             number_of_elements=1, default_values="a blank image")
    # ParaView 5.11 shows a list's widget without its label unless asked.
    @smhint.xml("<ShowLabel />")
    @_doc("""What the rendering should not look like, one phrase per row (default: "a blank
        image"); sampled captions are added to them at every step.""")
    def SetNegative(self, value):
        self._negatives.append(value)
        self.Modified()

    def ClearNegatives(self):
        self._negatives = []
        self.Modified()

    @smproperty.intvector(name="Steps", default_values=300)
    @smdomain.intrange(min=1, max=5000)
    @_doc("""Optimization steps. Each renders Views images and runs CLIP on each, so the run
        time is about Steps x Views x the time of one rendering and CLIP pass (the progress
        bar shows the time left). 300 is the paper's setting; a Refine needs far fewer.""")
    def SetSteps(self, value):
        self._steps = int(value)
        self.Modified()

    @smproperty.intvector(name="Views", default_values=3)
    @smdomain.intrange(min=1, max=16)
    @_doc("Random views rendered per step (run time grows with them).")
    def SetViews(self, value):
        self._views = int(value)
        self.Modified()

    @smproperty.stringvector(name="TimeEstimate", label="Time Estimate", information_only=1,
                             number_of_elements=1, default_values="",
                             panel_visibility="default")
    @_doc("""How long a run with the applied Steps and Views takes: Steps x Views x the time
        of one step and view that the last run with this Model measured, plus that run's
        start-up (loading the model, caption embeddings). Read-only; it follows Steps and
        Views when they are applied, and is known after the first run.""")
    def GetTimeEstimate(self):
        stored = ((self.stored or {}).get("result") or {}).get("timing")
        return timing.estimate(self._steps, self._views,
                               timing.for_model(self._model or None) or stored)

    @smproperty.intvector(name="Refine", default_values=0)
    @smdomain.xml('<BooleanDomain name="bool" />')
    @_doc("""Start from the colour and opacity functions the array has now (the last result,
        or a preset you chose) instead of t2tf's initialization. Refining needs far fewer
        steps than a fresh run.""")
    def SetRefine(self, value):
        self._refine = int(value)
        self.Modified()

    @smproperty.stringvector(name="LockRanges", label="Lock Ranges", default_values="")
    @_doc("""Data ranges whose transfer function stays as it starts, e.g. "120,400;
        800,1200": the rest is optimized around them.""")
    def SetLockRanges(self, value):
        self._locks = value or ""
        self.Modified()

    @smproperty.intvector(name="AllTimeSteps", label="All Time Steps", default_values=0)
    @smdomain.xml('<BooleanDomain name="bool" />')
    @_doc("""One transfer function for every time step of the input's animation: each step
        is read and t2tf optimizes for all of them over their common data range, so the
        colour map holds as the animation plays. Does nothing when the input has no time
        steps (then only the current step is used, as when off). Not in client-server
        mode.""")
    def SetAllTimeSteps(self, value):
        self._all_steps = int(value)
        self.Modified()

    @smproperty.stringvector(name="Model", default_values=DEFAULT_MODEL,
                             panel_visibility="advanced")
    @smdomain.filelist()
    @smhint.xml("<UseDirectoryName />")
    @_doc("""The CLIP model: a local model folder (config.json, tokenizer.json and weights;
        the button picks a folder), or a Hugging Face repository id, downloaded into the
        Hugging Face cache on first use (`t2tf model list` shows the cached ones; without
        network, `t2tf model fetch` elsewhere and copy the cache).""")
    def SetModel(self, value):
        self._model = value or ""
        self.Modified()

    @smproperty.stringvector(name="Tokenizer", default_values="", panel_visibility="advanced")
    @smdomain.filelist()
    @smhint.filechooser(extensions="json", file_description="tokenizer.json")
    @_doc("A tokenizer.json to use instead of the model's own (empty: the model's).")
    def SetTokenizer(self, value):
        self._tokenizer = value or ""
        self.Modified()

    @smproperty.intvector(name="Seed", default_values=0, panel_visibility="advanced")
    @_doc("""Random seed of the views, backgrounds and negatives: the same seed and settings
        give the same transfer function.""")
    def SetSeed(self, value):
        self._seed = int(value)
        self.Modified()

    # The array selection as ParaView's own examples declare it: five elements (index, port,
    # connection, field association, name), no default.
    @smproperty.xml("""
    <StringVectorProperty name="Array" command="SetInputArrayToProcess" number_of_elements="5"
        element_types="0 0 0 0 2" animateable="0" panel_visibility="advanced">
      <ArrayListDomain name="array_list" attribute_type="Scalars"
          input_domain_name="input_array">
        <RequiredProperties><Property name="Input" function="Input" /></RequiredProperties>
      </ArrayListDomain>
      <Documentation>The point array the transfer function is for (default: the active
      scalars).</Documentation>
    </StringVectorProperty>""")
    def SetInputArrayToProcess(self, idx, port, connection, field, name):
        VTKPythonAlgorithmBase.SetInputArrayToProcess(self, idx, port, connection, field, name)
        self.Modified()

    @smproperty.stringvector(name="ReferenceImage", label="Reference Image", default_values="",
                             panel_visibility="advanced")
    @smdomain.filelist()
    @smhint.filechooser(extensions="png", file_description="PNG image")
    @_doc("""A PNG picture the renderings should look like, instead of (or with) the
        Prompt.""")
    def SetReferenceImage(self, value):
        self._reference = value or ""
        self.Modified()

    @smproperty.intvector(name="ApplyCamera", label="Apply Camera", default_values=0,
                          panel_visibility="advanced")
    @smdomain.xml('<BooleanDomain name="bool" />')
    @_doc("""Also set the view's camera to t2tf's reference view after a run (not when a
        saved result is restored). Off by default: like ParaView's own filters, an Apply
        leaves your camera where it is.""")
    def SetApplyCamera(self, value):
        self._camera = int(value)
        self.Modified()

    @smproperty.stringvector(name="Result", default_values="", panel_visibility="never")
    @_doc("""The last result (transfer function, unit distance, report) with a digest of the
        input and settings it was made from; saved with the state, so loading the state
        shows it without running t2tf again.""")
    def SetResult(self, value):
        # Not Modified(): the stored result is a cache, not a setting. A state sets it before
        # the first update; the client sets it after each run (watch.py).
        try:
            self.stored = json.loads(value) if value else None
        except ValueError:
            self.stored = None

    # ---- the pipeline ----------------------------------------------------------------------

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        # t2tf needs the whole volume, not a piece.
        info = inInfo[0].GetInformationObject(0)
        sddp = self.GetExecutive()
        if info.Has(sddp.WHOLE_EXTENT()):
            info.Set(sddp.UPDATE_EXTENT(), info.Get(sddp.WHOLE_EXTENT()), 6)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        self.failure = self.error = None
        try:
            data = vtkDataObject.GetData(inInfo[0])
            if inputs.on_server():
                # The client that loaded this plugin runs t2tf on a bounded proxy of the data
                # and applies the TF to this output's display.
                vtkDataObject.GetData(outInfo).ShallowCopy(data)
                return 1
            if not isinstance(data, vtkImageData):
                raise inputs.not_image(data.GetClassName() if data else "nothing")
            out = vtkImageData.GetData(outInfo)
            out.ShallowCopy(data)
            times = self._time_steps(inInfo[0].GetInformationObject(0))
            result = self._result_for(data, times)
        except T2tfError as e:
            return self._fail(e)
        except Exception as e:  # a bug of ours: still one line, not a traceback
            return self._fail(T2tfError("internal error: %s: %s" % (type(e).__name__, e)))
        self.result = result
        # A cancelled run still produced a TF (the last finished step's): clear the abort
        # flag so the pipeline keeps this output instead of discarding it.
        self.SetAbortExecute(0)
        field = out.GetFieldData()
        for name, value in (("t2tf_report", result["report"]), ("t2tf_preset", result["name"])):
            a = vtkStringArray()
            a.SetName(name)
            a.InsertNextValue(value)
            field.AddArray(a)
        return 1

    def _time_steps(self, info):
        """The input's time steps when All Time Steps is on and it has more than one, else
        None (the current step alone, as with the property off)."""
        if not self._all_steps or not info.Has(SDDP.TIME_STEPS()):
            return None
        times = [float(t) for t in info.Get(SDDP.TIME_STEPS())]
        return times if len(times) > 1 else None

    def _read_time_steps(self, times, current):
        """[(time, image), ...]: the input at each time step, each a copy of what the input's
        algorithm produced for that time, read one at a time with a progress line; the input
        is updated back to the current time afterwards. All steps must share the first's
        dimensions and spacing."""
        conn = self.GetInputConnection(0, 0)
        producer, port = conn.GetProducer(), conn.GetIndex()
        info = producer.GetOutputInformation(port)
        now = (info.Get(SDDP.UPDATE_TIME_STEP()) if info.Has(SDDP.UPDATE_TIME_STEP())
               else current.GetInformation().Get(vtkDataObject.DATA_TIME_STEP())
               if current.GetInformation().Has(vtkDataObject.DATA_TIME_STEP()) else None)
        series = []
        try:
            for i, t in enumerate(times):
                self.SetProgressText("%s: reading time step %d of %d" % (TITLE, i + 1,
                                                                         len(times)))
                self.UpdateProgress(float(i) / len(times))
                gui.pump()
                if self.GetAbortExecute():
                    raise T2tfError("cancelled while reading the time steps")
                producer.UpdateTimeStep(t)
                data = producer.GetOutputDataObject(port)
                if not isinstance(data, vtkImageData):
                    raise inputs.not_image(data.GetClassName() if data else "nothing")
                image = vtkImageData()
                image.DeepCopy(data)
                if series:
                    first = series[0][1]
                    if (image.GetDimensions() != first.GetDimensions()
                            or image.GetSpacing() != first.GetSpacing()):
                        raise T2tfError(
                            "All Time Steps: time step %d (time %g) is %s points with spacing "
                            "%s, but the first step is %s with spacing %s: every step must "
                            "have the same dimensions and spacing"
                            % (i + 1, t, "x".join(map(str, image.GetDimensions())),
                               image.GetSpacing(), "x".join(map(str, first.GetDimensions())),
                               first.GetSpacing()), "volume")
                series.append((t, image))
        finally:
            # The pipeline is left at the current time, as the update that called us asked.
            if now is not None:
                producer.UpdateTimeStep(now)
            else:
                producer.Update(port)
        return series

    def _fail(self, error):
        """One message, the input passed through, and the error kept (the Python API raises
        it). RequestData succeeds: after two failed updates in a row ParaView stops asking a
        filter for data, so no later Apply would run t2tf again."""
        self.result = None
        self.failure, self.error = error, str(error)
        say(self.error)
        self.SetAbortExecute(0)
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
        raise T2tfError("the input has no point array to optimize a transfer function for",
                        "volume", "array")

    def _input_stamp(self, times):
        """What the time steps read depend on: the input pipeline's modification time and
        the steps."""
        producer = self.GetInputConnection(0, 0).GetProducer()
        return [producer.GetExecutive().GetPipelineMTime(), list(times)]

    def _result_for(self, image, times=None):
        """The stored result when it was made from this input and these settings (a loaded
        state), else an earlier run's from memory, else a new run's. `times`: the input's
        time steps, to optimize one TF for all of them (All Time Steps), or None."""
        array = self._array(image)
        series = None
        if times:
            stamp = self._input_stamp(times)
            memo = self._series_memo
            if memo and memo["stamp"] == stamp and memo["array"] == array:
                digest = memo["digest"]
            else:
                series = self._read_time_steps(times, image)
                digest = [[t, inputs.image_digest(step, array)] for t, step in series]
                self._series_memo = {"stamp": stamp, "array": array, "digest": digest}
        else:
            digest = inputs.image_digest(image, array)
        proxy = inputs.proxy_of(self)
        source = proxy.Input if proxy is not None else None
        start = None
        if self._refine:
            try:
                start = display.current_tf(array, source)
            except T2tfError:
                start = None  # the run says why
        # What a run reads: settings, input, Refine start, and the reference image's,
        # tokenizer's and local model's files (a Hub id stands for its own files).
        key = inputs.key([
            self._prompt, self._negatives, self._steps, self._views, self._seed, self._model,
            self._tokenizer, self._reference, self._refine, self._locks, array,
            digest, start, inputs.file_digest(self._reference),
            inputs.file_digest(self._tokenizer), inputs.folder_digest(self._model)])
        stored = self.stored
        if stored and stored.get("key") == key and stored.get("result"):
            self.reused = self.restored = True
            say("restored the saved result (input and settings unchanged): t2tf not run", False)
            return stored["result"]
        self.restored = False
        cached = self._cache.get(key)
        if cached is not None:
            # The settings and input of an earlier run of this filter, back again (Redo
            # Apply, or Undo of a later Apply): its result, without running t2tf.
            self.reused = True
            say("reused the result of an earlier run with the same input and settings: "
                "t2tf not run", False)
            self.stored = {"key": key, "result": cached}
            return cached
        self.reused = False
        request = run.Request(self._prompt, self._negatives, self._steps, self._views,
                              self._seed, self._model, self._tokenizer, self._reference,
                              run.parse_locks(self._locks))
        if self._refine:
            request.start = start or display.current_tf(array, source)
        upstream = inputs.upstream_file(proxy) if proxy is not None else None
        if times and series is None:
            series = self._read_time_steps(times, image)
        volume = (run.Volume(array, image=series[0][1], series=series) if series
                  else run.Volume(array, image=image, file=upstream))
        result = run.run(request, volume, self)
        # The preset a state's result registered, which this run's replaces.
        result["replaces"] = ((stored or {}).get("result") or {}).get("name")
        if result["interrupted"]:
            # Shown and saved, but never reused as the result of these settings.
            self.stored = {"key": None, "result": result}
        else:
            self._cache.pop(key, None)
            self._cache[key] = result
            while len(self._cache) > CACHED_RESULTS:
                self._cache.pop(next(iter(self._cache)))
            self.stored = {"key": key, "result": result}
        return result
