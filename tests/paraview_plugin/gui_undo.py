"""Startup script for the ParaView GUI (`paraview --script=`) for tests/paraview/paraview_plugin.rs:
Apply, Undo and Redo on the GUI's own undo stack (pqUndoStack, the one Edit > Undo and Redo
drive). Each Apply is recorded as the properties panel records it (pqUndoStack::beginUndoSet
"Apply", the filter shown, endUndoSet); Undo and Redo are pqUndoStack::undo and redo, the
slots of Edit's actions. ParaView's Python has no Qt bindings, so these are called through
ctypes (with the GIL held: they push properties to the Python algorithm). Writes the camera
and the t2tf run count after each step as JSON and exits (environment: T2TF_PLUGIN,
T2TF_VOLUME (a 64³ uint8 .raw), T2TF_MODEL, T2TF_TOKENIZER, T2TF_RESULT, T2TF_RUNS (the
counting wrapper's log))."""
import ctypes
import json
import os

import paraview.simple as pvs
from qt_calls import function, lib, qstring

env = os.environ
res = {}


def undo_stack():
    """The application's pqUndoStack: pqApplicationCore::setUndoStack makes it a child of
    pqApplicationCore::instance()."""
    core = function("_ZN17pqApplicationCore8instanceEv", ctypes.c_void_p)()
    meta = ctypes.c_void_p.in_dll(lib, "_ZN11pqUndoStack16staticMetaObjectE")
    find = function("_Z20qt_qFindChild_helperPK7QObjectRK7QStringRK11QMetaObject6QFlagsIN2Qt15"
                    "FindChildOptionEE", ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                    ctypes.c_void_p, ctypes.c_int)
    return find(core, ctypes.byref(qstring(None)), ctypes.addressof(meta), 1)


def runs():
    try:
        with open(env["T2TF_RUNS"]) as f:
            return len(f.read().split())
    except OSError:
        return 0


def camera(view):
    return {"position": list(view.CameraPosition), "focal_point": list(view.CameraFocalPoint),
            "view_up": list(view.CameraViewUp), "view_angle": view.CameraViewAngle}


try:
    stack = undo_stack()
    if not stack:
        raise RuntimeError("no pqUndoStack under pqApplicationCore")
    begin = function("_ZN11pqUndoStack12beginUndoSetE7QString", None, ctypes.c_void_p,
                     ctypes.c_void_p)
    end = function("_ZN11pqUndoStack10endUndoSetEv", None, ctypes.c_void_p)
    undo = function("_ZN11pqUndoStack4undoEv", None, ctypes.c_void_p)
    redo = function("_ZN11pqUndoStack4redoEv", None, ctypes.c_void_p)
    can_undo = function("_ZN11pqUndoStack7canUndoEv", ctypes.c_bool, ctypes.c_void_p)
    can_redo = function("_ZN11pqUndoStack7canRedoEv", ctypes.c_bool, ctypes.c_void_p)

    pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
    view = pvs.GetActiveViewOrCreate("RenderView")
    reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
    reader.DataScalarType = "unsigned char"
    reader.DataExtent = [0, 63, 0, 63, 0, 63]
    reader.ScalarArrayName = "ImageFile"
    pvs.Show(reader, view)
    # The user's camera before t2tf runs.
    view.CameraPosition = [200.0, -150.0, 90.0]
    view.CameraFocalPoint = [31.5, 31.5, 31.5]
    view.CameraViewUp = [0.0, 0.0, 1.0]
    view.CameraViewAngle = 30.0
    pvs.Render(view)
    res["user_camera"] = camera(view)
    f = TextToTransferFunction(Input=reader, Prompt="a protein molecule", Steps=2, Views=1,
                               Seed=3, Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"],
                               ApplyCamera=1)
    algo = f.GetClientSideObject()

    def step(name):
        pvs.Render(view)
        res[name] = {"camera": camera(view), "runs": runs(), "reused": algo.reused,
                     "can_undo": can_undo(stack), "can_redo": can_redo(stack)}

    label = qstring("Apply")
    begin(stack, ctypes.byref(label))
    pvs.Show(f, view)
    end(stack)
    step("apply")
    res["t2tf_camera"] = algo.result["camera"]
    undo(stack)
    step("undo")
    redo(stack)
    step("redo")
    # A second Apply with other settings runs t2tf; its Undo brings the first settings
    # back, whose result the filter still holds.
    begin(stack, ctypes.byref(label))
    f.Steps = 3
    f.UpdatePipeline()
    end(stack)
    step("apply2")
    undo(stack)
    step("undo2")
    res["steps_after_undo2"] = f.Steps
    redo(stack)
    step("redo2")
except Exception as e:  # reported in the JSON: the GUI would swallow it
    import traceback
    res["exception"] = traceback.format_exc()
with open(env["T2TF_RESULT"], "w") as fh:
    json.dump(res, fh)
os._exit(0)  # the GUI has no other way out of a startup script
