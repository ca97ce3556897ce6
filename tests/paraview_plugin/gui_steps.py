"""What a user does in the ParaView GUI, for the startup scripts that click (gui_abort.py,
gui_panel.py): make the filter from the Filters menu, and Apply it with the Properties
panel's button, clicked through the X server (qt_calls.X11)."""
import ctypes
import time

import paraview.simple as pvs
from qt_calls import enabled, find_child, function, process_events


def apply_button(window):
    """The Properties panel's Apply button (a QPushButton named "Accept")."""
    return find_child(window, "Accept", "_ZN11QPushButton16staticMetaObjectE")


def apply_and_wait(x, window, algo, seconds, done=None):
    """Click Apply and let the GUI's event loop run until `done()` (default: the filter has
    a result or an error); the run happens inside that loop, as after a user's click."""
    button = apply_button(window)
    if not button or not enabled(button):
        raise RuntimeError("the Apply button is not there or not enabled")
    done = done or (lambda: algo.result is not None or algo.error is not None)
    x.click(button)
    end = time.time() + seconds
    while not done() and time.time() < end:
        process_events(0.1)


def new_filter(window, source, **props):
    """A TextToTransferFunction on `source` made as Filters > t2tf makes it (the menu's
    action, so the panel holds it unapplied, its Apply button enabled), with `props` set."""
    pvs.SetActiveSource(source)
    process_events(0.5)  # the Filters menu enables the filters the active source accepts
    action = find_child(window, "TextToTransferFunction", "_ZN7QAction16staticMetaObjectE")
    if not action:
        raise RuntimeError("no TextToTransferFunction action under the main window")
    function("_ZN7QAction8activateENS_11ActionEventE", None, ctypes.c_void_p,
             ctypes.c_int)(action, 0)  # QAction::Trigger
    f = pvs.GetActiveSource()
    if f is source:
        raise RuntimeError("Filters > t2tf > Text To Transfer Function made nothing")
    for k, v in props.items():
        setattr(f, k, v)
    process_events(0.5)
    return f


def mark_modified(source):
    """Mark `source` changed in the panel (pqProxy::setModifiedState(MODIFIED)), as typing in
    one of its fields does, so that its Apply button is enabled: a property set from Python
    changes the proxy but not the panel's state."""
    core = function("_ZN17pqApplicationCore8instanceEv", ctypes.c_void_p)()
    model = find_child(core, None, "_ZN20pqServerManagerModel16staticMetaObjectE")
    address = int(source.SMProxy.__this__[1:].split("_")[0], 16)
    meta = ctypes.addressof(ctypes.c_void_p.in_dll(
        ctypes.PyDLL(None), "_ZN7pqProxy16staticMetaObjectE"))
    item = function("_ZN20pqServerManagerModel14findItemHelperEPKS_RK11QMetaObjectP10vtkSMProxy",
                    ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)(
                        model, meta, address)
    if not item:
        raise RuntimeError("no pqProxy for " + source.GetXMLName())
    function("_ZN7pqProxy16setModifiedStateENS_13ModifiedStateE", None, ctypes.c_void_p,
             ctypes.c_int)(item, 1)  # pqProxy::MODIFIED
    process_events(0.3)
