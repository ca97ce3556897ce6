"""pvpython script for tests/paraview/paraview_plugin.rs, run twice without --dr (so ParaView
loads and saves its user settings): "run" runs the filter with the Model and Tokenizer given;
"new" (a later session) makes a filter without them and writes the values it starts with as
JSON (argv: plugin, phase, volume-less wavelet run, model, tokenizer, result.json)."""
import json
import sys

import paraview.simple as pvs

plugin, phase, model, tokenizer, out_json = sys.argv[1:6]
pvs.LoadPlugin(plugin, ns=globals())
if phase == "run":
    f = TextToTransferFunction(Input=pvs.Wavelet(WholeExtent=[-6, 6, -6, 6, -6, 6]),
                               Prompt="a cloud", Steps=1, Views=1, Model=model,
                               Tokenizer=tokenizer)
    f.UpdatePipeline()
    res = {"error": f.GetClientSideObject().error}
else:
    f = TextToTransferFunction(Input=pvs.Wavelet())
    res = {"Model": f.Model, "Tokenizer": f.Tokenizer}
with open(out_json, "w") as fh:
    json.dump(res, fh)
