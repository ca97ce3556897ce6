"""Startup script for the ParaView GUI (`paraview --script=`) for tests/paraview/paraview_plugin.rs:
aborts a 2000-step run from the GUI's event loop. A repeating timer of the view's Qt
interactor fires only while Qt processes events; its handler sets the filter's abort flag
once steps have started, as ParaView's Abort button does. Writes what happened as JSON and
exits (environment: T2TF_PLUGIN, T2TF_VOLUME (a 64³ uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER,
T2TF_RESULT)."""
import json
import os
import time

import paraview.simple as pvs

env = os.environ
res = {}
try:
    pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    f = TextToTransferFunction(Input=reader, Prompt="a protein molecule", Steps=2000, Views=1,
                               Seed=3, Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
    algo = f.GetClientSideObject()
    view = pvs.GetActiveViewOrCreate("RenderView")
    interactor = view.GetInteractor()
    ticks = []

    def on_timer(_obj, _event):
        # The GUI event path: runs only when Qt's event loop gets to run.
        text = algo.GetProgressText() or ""
        ticks.append((time.time(), text))
        if "step " in text and not algo.GetAbortExecute():
            res["aborted_at"] = text
            algo.SetAbortExecute(1)

    interactor.AddObserver("TimerEvent", on_timer)
    timer = interactor.CreateRepeatingTimer(20)
    start = time.time()
    pvs.Show(f, view)
    res["filter_seconds"] = time.time() - start
    interactor.DestroyTimer(timer)
    res["ticks_during_run"] = len([t for t, _ in ticks if t <= start + res["filter_seconds"]])
    res["texts"] = sorted({text for _, text in ticks})[:20]
    r = algo.result
    res["interrupted"] = r["interrupted"] if r else None
    res["report"] = r["report"] if r else None
    res["error"] = algo.error
except Exception as e:  # reported in the JSON: the GUI would swallow it
    res["exception"] = "%s: %s" % (type(e).__name__, e)
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
os._exit(0)  # the GUI has no other way out of a startup script
