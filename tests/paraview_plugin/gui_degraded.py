"""Startup script for the ParaView GUI (`paraview --script=`) for tests/paraview/paraview_plugin.rs:
the plugin where no Qt or ParaView C++ function can be called (as on Windows, whose process
has no handle for its own symbols): a run still works and shows its TF, and each GUI feature
that is off is said once in the output window. Writes what happened as JSON and exits
(environment: T2TF_PLUGIN, T2TF_VOLUME (a 64³ uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER,
T2TF_RESULT)."""
import json
import os
import sys

import paraview.simple as pvs

env = os.environ
res = {}

try:
    sys.path.insert(0, os.path.dirname(env["T2TF_PLUGIN"]))
    from t2tf_paraview import native
    native._lib = False  # no symbols: what a process without a handle of its own gives
    pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    view = pvs.GetActiveViewOrCreate("RenderView")
    for seed in (3, 4):
        f = TextToTransferFunction(Input=reader, Prompt="a protein molecule", Steps=2, Views=1,
                                   Seed=seed, Model=env["T2TF_MODEL"],
                                   Tokenizer=env["T2TF_TOKENIZER"])
        pvs.Show(f, view)
        pvs.Render(view)
        algo = f.GetClientSideObject()
        res["error_%d" % seed] = algo.error
        rep = pvs.GetDisplayProperties(f, view).Representation
        res["representation_%d" % seed] = str(rep.GetData() if hasattr(rep, "GetData") else rep)
    res["off"] = dict(native._off)
except Exception:  # reported in the JSON: the GUI would swallow it
    import traceback
    res["exception"] = traceback.format_exc()
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
os._exit(0)  # the GUI has no other way out of a startup script
