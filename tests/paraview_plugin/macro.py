"""pvpython driver for tests/paraview/paraview_plugin.rs's macro test: runs paraview/scripts/t2tf_macro.py
the way ParaView runs a macro (as __main__) on the active source, five times: the prompt from
T2TF_PROMPT (a Wavelet source), from a NAME.prompt.txt next to a raw file, from nowhere, on a
source that is not image data, and without a t2tf binary (the last three: one message, no
traceback). Writes what ParaView holds as JSON (argv: macro, volume, model, tokenizer,
result.json)."""
import json
import os
import runpy
import shutil
import sys

import paraview.simple as pvs
from paraview import servermanager

macro, volume, model, tokenizer, out_json = sys.argv[1:6]
work = os.path.dirname(out_json)
os.environ.update(T2TF_MODEL=model, T2TF_TOKENIZER=tokenizer, T2TF_STEPS="5", T2TF_VIEWS="1",
                  T2TF_SEED="3", T2TF_NEGATIVES="a blank image;a cat")
view = pvs.GetActiveViewOrCreate("RenderView")
res = {}


def run_macro(case):
    print("CASE", case, flush=True)
    outcome = runpy.run_path(macro, run_name="__main__")["LAST"]
    if outcome is None:
        res[case] = None
        return
    result, f = outcome
    array = result["array"]
    disp = pvs.GetDisplayProperties(f, view)
    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
    res[case] = dict(
        rgb=list(pvs.GetColorTransferFunction(array).RGBPoints),
        points=list(pvs.GetOpacityTransferFunction(array).Points),
        representation=str(disp.Representation.GetData() if hasattr(disp.Representation, "GetData") else disp.Representation),
        color_array=str(disp.ColorArrayName[1]), preset=result["preset"],
        has_preset=bool(presets.HasPreset(result["name"])), volume=result["volume"],
        report=result["report"])


# 1. The environment; a source with no file behind it.
os.environ["T2TF_PROMPT"] = "a glowing cloud"
pvs.SetActiveSource(pvs.Wavelet(WholeExtent=[-12, 12, -12, 12, -12, 12]))
run_macro("env")
# 2. A file next to the data: NAME.prompt.txt beside the raw file the reader opened.
del os.environ["T2TF_PROMPT"]
raw = os.path.join(work, os.path.basename(volume))
shutil.copyfile(volume, raw)
with open(os.path.splitext(raw)[0] + ".prompt.txt", "w") as fh:
    fh.write("\n  a protein molecule  \n")
reader = pvs.ImageReader(FileNames=[raw])
reader.DataScalarType = "unsigned char"
reader.DataExtent = [0, 63, 0, 63, 0, 63]
reader.ScalarArrayName = "ImageFile"
pvs.SetActiveSource(reader)
run_macro("file")
# 2b. Refine that result with a locked range, through the environment.
os.environ.update(T2TF_REFINE="1", T2TF_LOCK="40,120", T2TF_PROMPT="a blue molecule")
run_macro("refine")
for key in ("T2TF_REFINE", "T2TF_LOCK", "T2TF_PROMPT"):
    del os.environ[key]
# 3. Nowhere: a Sphere has no prompt file and T2TF_PROMPT is unset.
pvs.SetActiveSource(pvs.Wavelet(WholeExtent=[-4, 4, -4, 4, -4, 4]))
run_macro("nowhere")
# 4. Not image data, and 5. no t2tf binary: one message each.
os.environ["T2TF_PROMPT"] = "a cloud"
pvs.SetActiveSource(pvs.Sphere())
run_macro("notimage")
os.environ["T2TF_BIN"] = os.path.join(work, "no-such-t2tf")
pvs.SetActiveSource(pvs.Wavelet(WholeExtent=[-4, 4, -4, 4, -4, 4]))
run_macro("nobinary")
print("CASES DONE", flush=True)
with open(out_json, "w") as fh:
    json.dump(res, fh)
