"""Startup script for the ParaView GUI (`paraview --script=`, started through
paraview/bin/t2tf-paraview) for tests/paraview/paraview_plugin.rs: connects to a running
`t2tf-paraview mpiexec -n 2 pvserver`, then uses the filter as a user does: Filters > t2tf >
Text To Transfer Function on a volume the server reads, Apply clicked through the X server,
and a second Apply after a change. Records whether the session defines the filter after
connecting, any dialog ParaView opened (the Plugin Manager's warning), the progress bar's
state while t2tf runs (Abort enabled, the GUI's input held), the display after each Apply and
how many times t2tf ran. Writes JSON and exits (environment: T2TF_PORT, T2TF_VOLUME (a 64³
uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER, T2TF_RESULT, T2TF_RUNS)."""
import ctypes
import json
import os
import time

import paraview.simple as pvs
from paraview import servermanager
from gui_steps import apply_and_wait, apply_button, mark_modified, new_filter
from qt_calls import (X11, enabled, find_child, find_children, function, main_window,
                      process_events, visible)

env = os.environ
res = {}


def runs():
    try:
        with open(env["T2TF_RUNS"]) as f:
            return len(f.read().split())
    except OSError:
        return 0


def dialogs(window):
    """The dialogs ParaView shows now (e.g. the Plugin Manager with a warning)."""
    return [d for d in find_children(window, "_ZN7QDialog16staticMetaObjectE") if visible(d)]


def display(source, view):
    d = pvs.GetDisplayProperties(source, view)
    lut = d.LookupTable
    rep = d.Representation
    return {"representation": str(rep.GetData() if hasattr(rep, "GetData") else rep),
            "color_array": str(d.ColorArrayName[1]),
            "rgb_points": list(lut.RGBPoints) if lut is not None else None,
            "unit_distance": d.ScalarOpacityUnitDistance}


try:
    x = X11()
    process_events(1.0)
    window = main_window()
    pvs.Connect("localhost", int(env["T2TF_PORT"]))
    process_events(2.0)  # the GUI follows the new session: menus, plugins
    conn = servermanager.ActiveConnection
    res["remote"] = bool(conn.IsRemote())
    res["partitions"] = conn.GetNumberOfDataPartitions()
    res["dialogs_after_connect"] = len(dialogs(window))
    res["modal_after_connect"] = bool(function("_ZN12QApplication17activeModalWidgetEv",
                                               ctypes.c_void_p)())
    # The server defines the filter for the session (else the Filters menu cannot make it).
    res["filter_defined"] = conn.Session.GetProxyDefinitionManager().GetProxyDefinition(
        "filters", "TextToTransferFunction") is not None
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    view = pvs.GetActiveViewOrCreate("RenderView")
    pvs.GetSettingsProxy("RenderViewSettings").RemoteRenderThreshold = 0.0
    pvs.Show(reader, view)
    f = new_filter(window, reader, Prompt="a protein molecule", Steps=400, Views=4, Seed=3,
                   Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
    abort = find_child(window, "AbortButton", "_ZN11QToolButton16staticMetaObjectE")
    interactor = view.GetInteractor()
    seen = {"abort_enabled": False, "ticks": 0}

    def on_timer(_obj, _event):
        # Fires while t2tf runs only because the plugin processes the GUI's events.
        if runs() > res.get("runs_before", 0):
            seen["ticks"] += 1
            seen["abort_enabled"] = seen["abort_enabled"] or enabled(abort)

    interactor.AddObserver("TimerEvent", on_timer)
    timer = interactor.CreateRepeatingTimer(50)
    res["runs_before"] = runs()
    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()

    def shown():
        lut = pvs.GetDisplayProperties(f, view).LookupTable
        return lut is not None and any(
            presets.GetPresetName(i) == "t2tf: a protein molecule"
            for i in range(presets.GetNumberOfPresets()))

    apply_and_wait(x, window, None, 180, lambda: runs() > res["runs_before"] and shown())
    process_events(1.0)
    pvs.Render(view)
    res["runs_after_apply"] = runs()
    res["during_run"] = dict(seen)
    res["first"] = display(f, view)
    res["abort_enabled_after"] = enabled(abort)
    res["dialogs_after_apply"] = len(dialogs(window))
    # A render and an update with the same settings run nothing.
    f.UpdatePipeline()
    pvs.Render(view)
    process_events(0.5)
    res["runs_after_render"] = runs()
    # A second Apply with other settings runs once more.
    f.Steps = 5
    f.Views = 1
    mark_modified(f)
    before = runs()
    apply_and_wait(x, window, None, 180, lambda: runs() > before)
    process_events(1.0)
    pvs.Render(view)
    res["runs_after_second_apply"] = runs()
    res["second"] = display(f, view)
    for i in range(presets.GetNumberOfPresets()):
        if presets.GetPresetName(i) == "t2tf: a protein molecule":
            res["preset"] = json.loads(presets.GetPresetAsString(i))
    interactor.DestroyTimer(timer)

    # The macro's route, text_to_transfer_function on the reader: the progress bar shows it,
    # Abort is enabled, and the GUI's input is held, so the Apply button of the filter,
    # changed again and clicked through the X server during the run, starts nothing.
    import t2tf_plugin
    f.Steps = 6
    mark_modified(f)
    apply = apply_button(window)
    macro = {"abort_enabled": False, "pressed": False}
    before = runs()

    def on_macro_timer(_obj, _event):
        if runs() <= before:
            return
        macro["abort_enabled"] = macro["abort_enabled"] or enabled(abort)
        if "pointer_at" not in macro:
            x.move_to(apply)
            macro["pointer_at"] = time.time()
        elif not macro["pressed"] and time.time() - macro["pointer_at"] > 0.3:
            x.press()
            macro["pressed"] = True

    interactor.AddObserver("TimerEvent", on_macro_timer)
    timer = interactor.CreateRepeatingTimer(50)
    result, _local = t2tf_plugin.text_to_transfer_function(
        reader, "a protein molecule", steps=400, views=4, seed=5, model=env["T2TF_MODEL"],
        tokenizer=env["T2TF_TOKENIZER"], proxy_size=32, view=view, camera=False)
    interactor.DestroyTimer(timer)
    res["macro_runs"] = runs() - before
    res["macro_during"] = {k: v for k, v in macro.items() if k != "pointer_at"}
    res["macro_steps_run"] = json.loads(result["report"])["steps_run"]
    process_events(1.0)  # a press held back during the run is not replayed after it
    res["runs_after_macro"] = runs() - before
    res["apply_enabled_after_macro"] = enabled(apply)
except Exception:  # reported in the JSON: the GUI would swallow it
    import traceback
    res["exception"] = traceback.format_exc()
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
os._exit(0)  # the GUI has no other way out of a startup script
