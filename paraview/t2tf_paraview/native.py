"""Every call of the plugin into C and C++ code through ctypes, in one place.

ParaView's Python has no Qt bindings, so the GUI work of a run (processing events, the Abort
button, the progress bar, Choose Preset's groups) calls Qt's and ParaView's exported C++
functions by their Itanium-mangled names in this process (Linux and macOS builds of Qt 5).
Such a symbol is missing in pvpython (no Qt), in MSVC builds (other names) and in Qt 6 (some
changed): then the feature that needs it is off for the session, said once in the GUI's
output window, and its caller gets None instead of an exception.

Calls go through ctypes.PyDLL, which keeps the GIL held: the events and signals they run call
ParaView's own Python (the progress bar, the Abort button's observers) on this thread, and
with the GIL released (CDLL) Python aborts ("PyThreadState_Get: ... the GIL is released").
"""
import ctypes
import os

from .errors import say

# Functions not found, by feature: what stops working without them, said once.
FEATURES = {
    "events": "the GUI is not repainted while t2tf runs (it repaints when the run ends)",
    "abort": "the Abort button and closing the main window do not stop a run "
             "(the abort flag and t2tf_plugin.cancel() still do)",
    "progress": "a run without a pipeline update (client-server) shows no progress bar",
    "preset_groups": "presets join Choose Preset's groups through the saved setting only",
}
_off = {}  # feature -> why it is off


class _Missing(Exception):
    """A symbol this process does not export."""


_lib = None


def _process():
    """The symbols of this process (dlopen(NULL)); on Windows there is no such handle."""
    global _lib
    if _lib is None:
        try:
            _lib = ctypes.PyDLL(None)
        except (OSError, TypeError):
            _lib = False
    if not _lib:
        raise _Missing("no handle for this process's own symbols on this platform")
    return _lib


def _function(name, restype, *argtypes):
    try:
        f = getattr(_process(), name)
    except AttributeError:
        raise _Missing("no symbol %s in this process" % name)
    f.restype, f.argtypes = restype, list(argtypes)
    return f


def _variable(name):
    """The address of a global variable (e.g. a class's staticMetaObject)."""
    try:
        return ctypes.addressof(ctypes.c_void_p.in_dll(_process(), name))
    except ValueError:
        raise _Missing("no symbol %s in this process" % name)


def _gui_running():
    """Whether ParaView's Qt GUI runs this Python: it installs its own undo stack builder
    (pqUndoStackBuilder); pvpython, pvbatch and pvserver have none. Asked without ctypes, so
    it holds where no symbol can be found."""
    try:
        from paraview import servermanager

        builder = servermanager.vtkSMProxyManager.GetProxyManager().GetUndoStackBuilder()
        return builder is not None and builder.GetClassName().startswith("pq")
    except Exception:
        return False


def _guarded(feature):
    """Run the decorated call unless `feature` is off; a missing symbol turns it off (said
    once, in the GUI only: elsewhere there is no GUI to miss) and the call gives None."""
    def decorate(call):
        def guarded(*args):
            if feature in _off:
                return None
            try:
                return call(*args)
            except (_Missing, OSError, ValueError, AttributeError, TypeError) as e:
                _off[feature] = str(e)
                if _gui_running():
                    say("%s: %s" % (FEATURES[feature], e), False)
                return None
        guarded.__name__ = call.__name__
        guarded.__doc__ = call.__doc__
        return guarded
    return decorate


class _QString:
    """A QString made from Python text for one call, freed after it (`with` block). None
    makes a null QString, which matches any object name in findChild."""

    def __init__(self, text):
        self.text = text

    def __enter__(self):
        self.buf = self._make(self.text)
        return ctypes.byref(self.buf)

    def __exit__(self, *_):
        # ~QString is inline; assigning a null QString (QString::operator=, exported) drops
        # this one's reference and frees its data, as the destructor would.
        null = self._make(None)
        _function("_ZN7QStringaSERKS_", ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)(
            ctypes.byref(self.buf), ctypes.byref(null))

    @staticmethod
    def _make(text):
        # A QString is one pointer to its shared data; fromUtf8_helper returns it through the
        # hidden result pointer (the buffer), as the C++ ABI returns a class by value.
        data = text.encode("utf-8") if text is not None else None
        buf = (ctypes.c_void_p * 1)()
        _function("_ZN7QString15fromUtf8_helperEPKci", ctypes.c_void_p, ctypes.c_void_p,
                  ctypes.c_char_p, ctypes.c_int)(ctypes.byref(buf), data, len(data or b""))
        return buf


class _Point(ctypes.Structure):
    _fields_ = [("x", ctypes.c_int), ("y", ctypes.c_int)]


class _Rect(ctypes.Structure):
    # Qt 5's QRect: left, top, right, bottom (right = left + width - 1).
    _fields_ = [("x1", ctypes.c_int), ("y1", ctypes.c_int), ("x2", ctypes.c_int),
                ("y2", ctypes.c_int)]


# ---- Qt's event loop --------------------------------------------------------------------

@_guarded("events")
def process_events(milliseconds):
    """QCoreApplication::processEvents for at most `milliseconds`, where this process has a
    QApplication (the GUI); True if events were processed."""
    app = ctypes.c_void_p.from_address(_variable("_ZN16QCoreApplication4selfE"))
    if not app.value:
        return False
    _function("_ZN16QCoreApplication13processEventsE6QFlagsIN10QEventLoop17ProcessEventsFlagEEi",
              None, ctypes.c_int, ctypes.c_int)(0, milliseconds)
    return True


# ---- the GUI's widgets -------------------------------------------------------------------

def _find_child(parent, name, meta):
    """The first descendant of `parent` of class `meta` (its staticMetaObject's symbol) and
    object name `name` (None: any)."""
    find = _function("_Z20qt_qFindChild_helperPK7QObjectRK7QStringRK11QMetaObject6QFlagsIN2Qt15"
                     "FindChildOptionEE", ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                     ctypes.c_void_p, ctypes.c_int)
    with _QString(name) as qname:
        return find(parent, qname, _variable(meta), 1)  # 1: Qt::FindChildrenRecursively


def _core():
    return _function("_ZN17pqApplicationCore8instanceEv", ctypes.c_void_p)()


@_guarded("abort")
def gui_widgets():
    """(progress manager, main window, Abort button) of the ParaView GUI, or None where there
    is no GUI yet (or none at all)."""
    core = _core()
    window = _function("_ZN15pqCoreUtilities14findMainWindowEv", ctypes.c_void_p)()
    if not core or not window:
        return None
    manager = _find_child(core, None, "_ZN17pqProgressManager16staticMetaObjectE")
    button = _find_child(window, "AbortButton", "_ZN11QToolButton16staticMetaObjectE")
    return (manager, window, button) if manager and button else None


def _set_bool(name, widget, on):
    _function(name, None, ctypes.c_void_p, ctypes.c_bool)(widget, on)


def _get_bool(name, widget):
    return bool(_function(name, ctypes.c_bool, ctypes.c_void_p)(widget))


@_guarded("abort")
def enable_abort(manager, button, on):
    """Enable the Abort button through the progress manager (its enableAbort signal reaches
    the button) and on the button itself, where the manager is locked by another sender."""
    _set_bool("_ZN17pqProgressManager14setEnableAbortEb", manager, on)
    _set_bool("_ZN7QWidget10setEnabledEb", button, on)
    return True


@_guarded("abort")
def set_checkable(button, on):
    _set_bool("_ZN15QAbstractButton12setCheckableEb", button, on)
    return True


@_guarded("abort")
def set_checked(button, on):
    _set_bool("_ZN15QAbstractButton10setCheckedEb", button, on)
    return True


@_guarded("abort")
def pressed(button):
    """Whether the button is checked or held down."""
    return (_get_bool("_ZNK15QAbstractButton9isCheckedEv", button)
            or _get_bool("_ZNK15QAbstractButton6isDownEv", button))


@_guarded("abort")
def visible(widget):
    """QWidget::isVisible() (inline): isVisibleTo(nullptr) is the same."""
    return bool(_function("_ZNK7QWidget11isVisibleToEPKS_", ctypes.c_bool, ctypes.c_void_p,
                          ctypes.c_void_p)(widget, None))


@_guarded("abort")
def unblock_events(manager, on):
    """pqProgressManager::unblockEvents: whether presses pass its lock during an update;
    returns the value it had."""
    return bool(_function("_ZN17pqProgressManager13unblockEventsEb", ctypes.c_bool,
                          ctypes.c_void_p, ctypes.c_bool)(manager, on))


@_guarded("abort")
def pointer_over(widget):
    """Whether the pointer (as the window system has it now: QCursor::pos) is over
    `widget`."""
    pos = _function("_ZN7QCursor3posEv", _Point)()
    corner = _function("_ZNK7QWidget11mapToGlobalERK6QPoint", _Point, ctypes.c_void_p,
                       ctypes.c_void_p)(widget, ctypes.byref(_Point(0, 0)))
    rect = _function("_ZNK7QWidget13frameGeometryEv", _Rect, ctypes.c_void_p)(widget)
    return (0 <= pos.x - corner.x <= rect.x2 - rect.x1
            and 0 <= pos.y - corner.y <= rect.y2 - rect.y1)


# ---- the progress bar of a run that is no pipeline update --------------------------------

@_guarded("progress")
def enable_progress(manager, on):
    """pqProgressManager::setEnableProgress: counts as an update (the GUI's input is held)."""
    _set_bool("_ZN17pqProgressManager17setEnableProgressEb", manager, on)
    return True


@_guarded("progress")
def set_progress(manager, text, percent):
    with _QString(text) as qtext:
        _function("_ZN17pqProgressManager11setProgressERK7QStringi", None, ctypes.c_void_p,
                  ctypes.c_void_p, ctypes.c_int)(manager, qtext, int(percent))
    return True


# ---- Choose Preset's groups --------------------------------------------------------------

@_guarded("preset_groups")
def preset_group_manager():
    """The GUI's pqPresetGroupsManager, or None outside the GUI."""
    core = _core()
    if not core:
        return None
    with _QString("PRESET_GROUP_MANAGER") as key:
        return _function("_ZN17pqApplicationCore7managerERK7QString", ctypes.c_void_p,
                         ctypes.c_void_p, ctypes.c_void_p)(core, key) or None


@_guarded("preset_groups")
def add_to_group(manager, group, name):
    with _QString(group) as qgroup, _QString(name) as qname:
        _function("_ZN21pqPresetGroupsManager10addToGroupERK7QStringS2_", None,
                  ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)(manager, qgroup, qname)
    return True


@_guarded("preset_groups")
def remove_from_all_groups(manager, name):
    with _QString(name) as qname:
        _function("_ZN21pqPresetGroupsManager19removeFromAllGroupsERK7QString", None,
                  ctypes.c_void_p, ctypes.c_void_p)(manager, qname)
    return True


# ---- processes ---------------------------------------------------------------------------

def process_alive(pid):
    """Whether process `pid` runs (a process we may not signal runs)."""
    if os.name != "nt":
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except OSError:
            return True
        return True
    # os.kill on Windows terminates the process: ask the kernel instead.
    from ctypes import wintypes

    kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)
    # A HANDLE is pointer-sized: ctypes' default int return would cut it on 64-bit.
    kernel32.OpenProcess.restype = wintypes.HANDLE
    kernel32.OpenProcess.argtypes = (wintypes.DWORD, wintypes.BOOL, wintypes.DWORD)
    kernel32.GetExitCodeProcess.argtypes = (wintypes.HANDLE, ctypes.POINTER(wintypes.DWORD))
    kernel32.CloseHandle.argtypes = (wintypes.HANDLE,)
    handle = kernel32.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
    if not handle:
        return ctypes.get_last_error() == 5  # access denied: it exists
    code = wintypes.DWORD()
    ok = kernel32.GetExitCodeProcess(handle, ctypes.byref(code))
    kernel32.CloseHandle(handle)
    return bool(ok) and code.value == 259  # STILL_ACTIVE
