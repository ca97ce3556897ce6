"""Startup script for the ParaView GUI (`paraview --script=`) for tests/paraview/paraview_plugin.rs:
the preset groups of the Choose Preset dialog after t2tf runs. The dialog opens on the group
"Default" and lists only its presets; the groups are the GUI's pqPresetGroupsManager's, which
writes them to the setting TransferFunctionPresets.Groups on every change. Records, after a
run, a re-run with another prompt and remove_presets(), the groups that setting holds (and
the manager's own count of "Default"), as JSON, and exits (environment: T2TF_PLUGIN,
T2TF_VOLUME (a 64³ uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER, T2TF_RESULT)."""
import ctypes
import json
import os
import sys

import paraview.simple as pvs
from paraview import servermanager
from qt_calls import function, qstring

env = os.environ
res = {}


def manager():
    core = function("_ZN17pqApplicationCore8instanceEv", ctypes.c_void_p)()
    return function("_ZN17pqApplicationCore7managerERK7QString", ctypes.c_void_p,
                    ctypes.c_void_p, ctypes.c_void_p)(core, qstring("PRESET_GROUP_MANAGER"))


def groups():
    """{group: [t2tf presets]} from the saved setting, plus the size of "Default" as the
    manager counts it and whether it still holds ParaView's built-in "Cool to Warm"."""
    text = servermanager.vtkSMSettings.GetInstance().GetSettingAsString(
        "TransferFunctionPresets.Groups", "")
    saved = json.loads(text) if text else []
    count = function("_ZN21pqPresetGroupsManager22numberOfPresetsInGroupERK7QString",
                     ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p)
    rank = function("_ZN21pqPresetGroupsManager17presetRankInGroupERK7QStringS2_",
                    ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)
    m = manager()
    return {
        "saved": {g["groupName"]: sorted(p for p in g["presets"] if p.startswith("t2tf: "))
                  for g in saved},
        "default_size": count(m, qstring("Default")),
        "builtin_in_default": rank(m, qstring("Cool to Warm"), qstring("Default")) >= 0,
        "t2tf_rank_in_default": {name: rank(m, qstring(name), qstring("Default"))
                                 for name in ("t2tf: a protein molecule",
                                              "t2tf: a glowing cloud")},
    }


try:
    sys.path.insert(0, os.path.dirname(env["T2TF_PLUGIN"]))
    pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
    import t2tf_plugin  # noqa: E402 (for remove_presets)

    res["before"] = groups()
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    f = TextToTransferFunction(Input=reader, Prompt="a protein molecule", Steps=2, Views=1,
                               Seed=3, Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
    pvs.Show(f)
    res["after_run"] = groups()
    f.Prompt = "a glowing cloud"
    f.UpdatePipeline()
    res["after_new_prompt"] = groups()
    res["removed"] = t2tf_plugin.remove_presets()
    res["after_remove"] = groups()
except Exception:  # reported in the JSON: the GUI would swallow it
    import traceback
    res["exception"] = traceback.format_exc()
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
os._exit(0)  # the GUI has no other way out of a startup script
