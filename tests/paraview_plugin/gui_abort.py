"""Startup script for the ParaView GUI (`paraview --script=`) for tests/paraview/paraview_plugin.rs:
a 5000-step run of 8 views started with the Properties panel's Apply button and stopped with the Abort
button beside the progress bar (T2TF_GUI_STOP=abort), or by closing the main window
(T2TF_GUI_STOP=close), each through real X input (XTEST clicks at the buttons' places, a
WM_DELETE_WINDOW message as a window's close button sends), sent from a timer once the run is
a few steps in. After an abort, a second filter is applied with the same button and must run
to its end. Writes what happened as JSON and exits (environment: T2TF_PLUGIN, T2TF_VOLUME (a
64³ uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER, T2TF_RESULT, T2TF_GUI_STOP)."""
import ctypes
import json
import os
import re
import time

import paraview.simple as pvs
from gui_steps import apply_and_wait, new_filter
from qt_calls import (X11, enabled, find_child, function, main_window, process_events,
                      screen_center, visible)

env = os.environ
stop = env.get("T2TF_GUI_STOP", "abort")
res = {"stop": stop}


def summary(algo):
    """What the filter's result says of its run: the report's step counts and flag."""
    r = algo.result
    if not r:
        return None
    report = json.loads(r["report"])
    return {"interrupted": r["interrupted"], "report_interrupted": report["interrupted"],
            "steps_run": report["steps_run"], "steps_recorded": len(report["steps"]),
            "steps": report["settings"]["steps"], "rgb_points": len(r["rgb"]) // 4}


def step_of(text):
    m = re.search(r"step (\d+)/(\d+)", text or "")
    return int(m.group(1)) if m else None


try:
    pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
    x = X11()
    process_events(1.0)  # the main window shown and laid out
    window = main_window()
    res["window_visible_before"] = visible(window)
    abort = find_child(window, "AbortButton", "_ZN11QToolButton16staticMetaObjectE")
    res["abort_enabled_before"] = enabled(abort)
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    view = pvs.GetActiveViewOrCreate("RenderView")
    pvs.Show(reader, view)
    f = new_filter(window, reader, Prompt="a protein molecule", Steps=5000, Views=8, Seed=3,
                   Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
    algo = f.GetClientSideObject()
    interactor = view.GetInteractor()

    def on_timer(_obj, _event):
        # Runs only while the plugin lets Qt process events during the run. Like a user, the
        # pointer comes to the Abort button first and presses it a moment later, once the
        # button stayed under it (the status bar moves it as the progress text changes).
        step = step_of(algo.GetProgressText())
        if step is None or step < 3:
            return
        if "pressed_at" in res:
            # The status bar may have moved the button between the last look and the press
            # (the click then lands beside it): a run still going a second later is pressed
            # again.
            if stop == "close" or time.time() - res["pressed_time"] < 1.0:
                return
            res.pop("pressed_at")
            res.pop("pointer", None)
        if stop == "close":
            res["abort_enabled_during"] = enabled(abort)
            x.close_window(window)
            res["pressed_at"] = step
            res["pressed_time"] = time.time()
            return
        center = screen_center(abort)
        if res.get("pointer") != [center.x, center.y]:
            res["abort_enabled_during"] = enabled(abort)
            res["pointer"] = x.move_to(abort)
            res["pointer_at"] = time.time()
            res["moves"] = res.get("moves", 0) + 1
        elif time.time() - res["pointer_at"] > 0.2:
            res["pressed_at"] = step
            res["pressed_time"] = time.time()
            res["presses"] = res.get("presses", 0) + 1
            x.press()

    interactor.AddObserver("TimerEvent", on_timer)
    timer = interactor.CreateRepeatingTimer(50)
    start = time.time()
    apply_and_wait(x, window, algo, 240)
    res["seconds"] = time.time() - start
    interactor.DestroyTimer(timer)
    res["error"] = algo.error
    res["first"] = summary(algo)
    res["window_visible_after"] = visible(window)
    if stop == "abort":
        process_events(0.3)
        res["abort_checked_after"] = bool(function(
            "_ZNK15QAbstractButton9isCheckedEv", ctypes.c_bool, ctypes.c_void_p)(abort))
        res["abort_enabled_after"] = enabled(abort)
        # ParaView stays usable: another filter, applied with the same button, runs to its end.
        g = new_filter(window, reader, Prompt="a protein molecule", Steps=3, Views=1, Seed=4,
                       Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
        second = g.GetClientSideObject()
        apply_and_wait(x, window, second, 120)
        res["second_error"] = second.error
        res["second"] = summary(second)
except Exception:  # reported in the JSON: the GUI would swallow it
    import traceback
    res["exception"] = traceback.format_exc()
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
if stop != "close" or "exception" in res:
    os._exit(0)  # the GUI has no other way out of a startup script
# A closed window: ParaView quits by itself once the script gives the event loop back.
