"""Startup script for the ParaView GUI (`paraview --script=`) for tests/paraview/paraview_plugin.rs:
the filter made from Filters > t2tf as a user makes it, its Properties panel read back (the
labels ParaView shows), then a first Apply that fails (an empty Prompt), clicked on the
panel's Apply button through the X server, and the display ParaView is left with; then a
Prompt and an Apply that works. Writes what it saw as JSON and exits (environment:
T2TF_PLUGIN, T2TF_VOLUME (a 64³ uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER, T2TF_RESULT)."""
import json
import os

import paraview.simple as pvs
from gui_steps import apply_and_wait, mark_modified, new_filter
from qt_calls import (X11, find_child, find_children, label_text, main_window, process_events,
                      visible)

env = os.environ
res = {}


def text(value):
    return str(value.GetData() if hasattr(value, "GetData") else value)


def display(source, view):
    """What the view shows of `source`: representation, colouring, colour map, visibility."""
    d = pvs.GetDisplayProperties(source, view)
    array = d.ColorArrayName[1] if d.ColorArrayName else ""
    lut = d.LookupTable
    return {"visible": bool(d.Visibility), "representation": text(d.Representation),
            "color_array": str(array or ""),
            "rgb_points": list(lut.RGBPoints) if lut is not None else None}


try:
    pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
    x = X11()
    process_events(1.0)
    window = main_window()
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    view = pvs.GetActiveViewOrCreate("RenderView")
    pvs.Show(reader, view)
    pvs.Render(view)
    res["input_before"] = display(reader, view)
    f = new_filter(window, reader, Prompt="", Steps=3, Views=1, Seed=3,
                   Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
    panel = find_child(window, None, "_ZN17pqPropertiesPanel16staticMetaObjectE")
    res["labels"] = [label_text(label)
                     for label in find_children(panel, "_ZN6QLabel16staticMetaObjectE")
                     if visible(label)]
    algo = f.GetClientSideObject()
    apply_and_wait(x, window, algo, 60)
    process_events(0.5)
    res["error"] = algo.error
    res["failed"] = display(f, view)
    res["input_after_failure"] = display(reader, view)
    # The same filter, given a prompt: Apply runs t2tf and shows its TF as a volume.
    f.Prompt = "a protein molecule"
    process_events(0.3)
    mark_modified(f)
    apply_and_wait(x, window, algo, 120, lambda: algo.result is not None)
    process_events(0.5)
    res["error_after"] = algo.error
    res["worked"] = display(f, view)
    res["result_rgb"] = algo.result["rgb"] if algo.result else None
except Exception:  # reported in the JSON: the GUI would swallow it
    import traceback
    res["exception"] = traceback.format_exc()
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
os._exit(0)  # the GUI has no other way out of a startup script
