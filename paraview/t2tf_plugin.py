"""ParaView plugin: "Text To Transfer Function" (XML name TextToTransferFunction).

Load it with Tools > Manage Plugins > Load New (this file), with PV_PLUGIN_PATH naming its
folder, or from pvpython with LoadPlugin(path, ns=globals()). The filter takes image data
and runs t2tf in this process when ParaView's Python can import the t2tf module (`pip install
--user .` for the Python ParaView uses, or PYTHONPATH): the point array is handed over
through vtk_to_numpy, no file is written. Otherwise (or when T2TF_BIN names a binary) it runs
the t2tf binary (T2TF_BIN, else PATH, else beside this file) with --progress json. The output
window says which. Either way the progress bar shows "Text To Transfer Function: step k/N,
loss L, ETA s", the GUI keeps processing its events while t2tf runs, and the filter stops
after the current step (keeping that step's TF) when its abort flag is set or
t2tf_plugin.cancel() is called. The result is applied to the filter's own display: colour,
opacity, ScalarOpacityUnitDistance, range never rescaled, a preset named after the prompt
("t2tf: PROMPT") in ParaView's preset manager, and optionally the camera of t2tf's view. The
output is the input plus field data t2tf_report (report.json) and t2tf_preset (the preset's
name). t2tf's files are written to a temporary folder that is removed after the run; the
result is kept in memory and in the hidden property Result, so a saved state restores it
without running t2tf again while the input and settings are unchanged. The preset joins the
groups "Default" and "User" of the Choose Preset dialog (it opens on "Default"). In the GUI,
Undo of an Apply restores the camera the view had before, and Redo (or Undo of a later
Apply) reuses the earlier run's result from memory. The read-only Time Estimate shows the
run time of the applied Steps and Views from the last measured run with the same model.

In the GUI the Abort button beside the progress bar stops a run after its current step, and
closing the main window stops it too. Connected to a remote pvserver that loaded this plugin
too, the filter passes the data through on the server and this client runs t2tf on a bounded
ResampleToImage proxy of it at each Apply, applying the TF to the filter's full-resolution
display; text_to_transfer_function(source, prompt, ...) (or the macro t2tf_macro.py) does the
same for any source.

Errors (no binary, empty prompt, Steps below 1, input that is not image data, t2tf failing)
are one message in ParaView's output window, in ParaView's words (properties, never t2tf's
command-line flags), never a Python traceback; the input passes through unchanged and the
next Apply runs again, whatever failed before. text_to_transfer_function raises T2tfError
with that message.

A result is reused (Undo, Redo, a loaded state) only for the same input and settings: the
Refine start's functions, the reference image's bytes and the model's and tokenizer's files
are part of the key, and a cancelled run's result is never reused as a finished one.
"""
import ctypes
import hashlib
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import types

from paraview.util.vtkAlgorithm import VTKPythonAlgorithmBase, smhint, smproperty, smproxy
from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringArray
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData

# The t2tf release this plugin belongs to: a binary or module of another is refused.
__version__ = "0.1.0"
# ParaView names the pipeline item and the pvpython function after the label without its
# spaces: TextToTransferFunction1, as ParaView's own "Resample To Image" gives ResampleToImage1.
TITLE = "Text To Transfer Function"
UNIT_DISTANCE_KEY = "t2tfScalarOpacityUnitDistance"
DEFAULT_MODEL = "openai/clip-vit-base-patch32"
# Default bound of the proxy fetched from a remote server (points per axis).
PROXY_SIZE = 256
# Every preset this plugin registers starts with this, so remove_presets() finds them.
PRESET_PREFIX = "t2tf: "


class T2tfError(Exception):
    """A problem the user can fix; shown as one line in ParaView's output window."""


def message(text, error=True):
    """One line in ParaView's output window (stderr in pvpython), prefixed with the title."""
    window = vtkOutputWindow.GetInstance()
    line = "%s: %s\n" % (TITLE, text)
    if error:
        window.DisplayErrorText(line)
    else:
        window.DisplayText(line)


# t2tf's words for a setting (the binary's flags, the Python module's keywords) and the
# property that sets it in ParaView, longest first.
_PROPERTY_WORDS = (
    ("give a --tokenizer", "set Tokenizer"),
    ("--reference-image PNG", "Reference Image"), ("--reference-image", "Reference Image"),
    ("--model DIR", "Model"), ("--model", "Model"), ("--tokenizer", "Tokenizer"),
    ("--steps", "Steps"), ("--views", "Views"), ("--seed", "Seed"),
    ("--negative", "Negatives"), ("--lock", "Lock Ranges"), ("--array", "Array"),
    ("--prompt", "Prompt"), ("`reference_image`", "Reference Image"), ("`model`", "Model"),
    ("`tokenizer`", "Tokenizer"), ("`steps`", "Steps"), ("`views`", "Views"),
    ("`seed`", "Seed"), ("`negatives`", "Negatives"), ("`lock`", "Lock Ranges"),
    ("`prompt`", "Prompt"),
)


def with_advice(text):
    """`text` (a t2tf error) in ParaView's words: its settings named by the properties that
    set them, without the command line's hints (the repository's test model), and what to do
    in ParaView when the model could not be had."""
    text = re.sub(r" \(offline, the test model of the repository[^)]*\)", "", text)
    for words, prop in _PROPERTY_WORDS:
        text = text.replace(words, prop)
    if "Hugging Face cache" in text or "cannot download" in text:
        # t2tf's own message says how to fetch the model; what ParaView adds is where.
        text += "; in ParaView, set Model (an advanced property) to a local model folder"
    return text


def t2tf_module():
    """The t2tf Python module, or None to run the binary: when T2TF_BIN names one, or when
    this Python cannot import the module."""
    if os.environ.get("T2TF_BIN"):
        return None
    try:
        import t2tf
        import t2tf.vtk  # noqa: F401 (the VTK bridge the filter uses)
    except ImportError:
        return None
    return t2tf


# The binary found on PATH or beside this file, kept for the session (another t2tf put on
# PATH later does not take over), and the binaries whose version was checked.
_PINNED = {}
_CHECKED = set()


def find_binary():
    """The t2tf executable: T2TF_BIN, else the one found first on PATH, then beside this
    plugin (kept for the session); of this plugin's version (said once per binary)."""
    env = os.environ.get("T2TF_BIN")
    if env:
        if os.path.isfile(env) and os.access(env, os.X_OK):
            return _checked(env)
        raise T2tfError("T2TF_BIN=%s is not an executable file" % env)
    pinned = _PINNED.get("binary")
    if pinned and os.path.isfile(pinned):
        return _checked(pinned)
    found = shutil.which("t2tf")
    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("t2tf", "t2tf.exe"):
        beside = os.path.join(here, name)
        if not found and os.path.isfile(beside) and os.access(beside, os.X_OK):
            found = beside
    if not found:
        raise T2tfError(
            "the t2tf binary was not found: set T2TF_BIN, put t2tf on PATH, or copy it beside "
            + here)
    _PINNED["binary"] = os.path.abspath(found)
    return _checked(_PINNED["binary"])


def _check_module(module):
    """The t2tf module, once its version is this plugin's (said once)."""
    if module.__version__ != __version__:
        raise T2tfError(
            "the t2tf module %s is version %s, but this plugin is %s: install t2tf %s in the "
            "Python ParaView uses, or set T2TF_BIN to a t2tf %s binary"
            % (module.__file__, module.__version__, __version__, __version__, __version__))
    if "module" not in _CHECKED:
        message("running t2tf %s in-process (%s)" % (module.__version__, module.__file__), False)
        _CHECKED.add("module")


def _checked(binary):
    """`binary`, once its version is this plugin's (asked once per file and change)."""
    st = os.stat(binary)
    key = (os.path.abspath(binary), st.st_size, st.st_mtime_ns)
    if key in _CHECKED:
        return binary
    try:
        said = subprocess.run([binary, "--version"], capture_output=True, text=True,
                              timeout=60).stdout.split()
    except (OSError, subprocess.SubprocessError) as e:
        raise T2tfError("the t2tf binary %s does not run: %s" % (binary, e))
    version = said[-1] if len(said) == 2 and said[0] == "t2tf" else " ".join(said) or "unknown"
    if version != __version__:
        raise T2tfError(
            "the t2tf binary %s is version %s, but this plugin is %s: install t2tf %s (from "
            "the same release as this plugin), or set T2TF_BIN to it"
            % (binary, version, __version__, __version__))
    message("using the t2tf binary %s (t2tf %s)" % (binary, version), False)
    _CHECKED.add(key)
    return binary


# ---- temporary folders ------------------------------------------------------------------

# A run's files go to a temporary folder named after this process, removed after the run; a
# ParaView killed mid-run leaves its folder, which the next start removes.
_TEMP_PREFIX = "t2tf-plugin-%d-" % os.getpid()


def _alive(pid):
    """Whether process `pid` runs (a process we may not signal runs)."""
    if os.name == "nt":
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
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def remove_stale_temporaries():
    """Remove the temporary folders of runs whose process is gone (a ParaView killed while
    t2tf ran); returns their names."""
    removed = []
    root = tempfile.gettempdir()
    try:
        names = os.listdir(root)
    except OSError:
        return removed
    for name in names:
        m = re.match(r"t2tf-plugin-(\d+)-", name)
        if not m or int(m.group(1)) == os.getpid() or _alive(int(m.group(1))):
            continue
        path = os.path.join(root, name)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(name)
    return removed


remove_stale_temporaries()


# ---- runs in progress: cancel, progress text, GUI events ------------------------------

def _runs():
    """The runs in progress, in one list every copy of this module shares.

    LoadPlugin executes this file as a new module object, so a `t2tf_plugin` imported before
    LoadPlugin and the one the filter runs from are two modules with their own globals. The
    list lives on a module of its own in sys.modules, which both find."""
    shared = sys.modules.get("_t2tf_plugin_runs")
    if shared is None:
        shared = types.ModuleType("_t2tf_plugin_runs")
        shared.runs = []
        sys.modules[shared.__name__] = shared
    return shared.runs


def cancel():
    """Ask every running t2tf to stop after its current step (it keeps that step's TF).
    Works from any copy of this module (imported before or after LoadPlugin)."""
    for run in list(_runs()):
        run.cancel()


class _Qt:
    """QCoreApplication::processEvents where this process has a QApplication (the ParaView
    GUI; pvpython has none). ParaView's Python has no Qt bindings, so the static functions
    are called through ctypes, looked up once."""
    looked_up = False
    instance = None  # QCoreApplication::self, a live view of the pointer
    process = None
    hooks = []  # called before each processEvents

    @classmethod
    def process_events(cls):
        if not cls.looked_up:
            cls.looked_up = True
            try:
                # PyDLL: the GIL stays held through processEvents. The events run ParaView's
                # own Python (the Abort button's observers, the progress bar) on this thread;
                # with the GIL released (CDLL) that code can run while the thread reading
                # t2tf's output holds the GIL, and Python aborts ("PyThreadState_Get: ... the
                # GIL is released"). The reader only waits ≤ 50 ms for it.
                # Windows has no handle for "this process" (PyDLL(None) is a TypeError) and
                # MSVC mangles names otherwise: there, and wherever the symbol is not found
                # (a Qt 6 build), the GUI is not pumped during a run (it repaints when the
                # run ends) instead of failing.
                lib = ctypes.PyDLL(None)
                cls.instance = ctypes.c_void_p.in_dll(lib, "_ZN16QCoreApplication4selfE")
                # static void processEvents(QEventLoop::ProcessEventsFlags, int maxtime)
                cls.process = getattr(
                    lib, "_ZN16QCoreApplication13processEventsE6QFlagsIN10QEventLoop17"
                         "ProcessEventsFlagEEi")
                cls.process.argtypes = [ctypes.c_int, ctypes.c_int]
                cls.process.restype = None
            except (OSError, ValueError, AttributeError, TypeError):
                cls.process = None
        if cls.process is None or not cls.instance.value:
            return False
        # All events, for at most 50 ms: while a pipeline updates, ParaView's progress
        # manager drops every mouse press and key press (it lets through those on its
        # progress bar and Abort button, but a press reaches Qt's window object first, where
        # it is dropped), so this repaints and runs timers without letting the user start
        # other work. A run's _AbortButton opens that lock while the pointer is over the
        # button.
        for hook in cls.hooks:
            hook()
        cls.process(0, 50)
        return True


class _QPoint(ctypes.Structure):
    _fields_ = [("x", ctypes.c_int), ("y", ctypes.c_int)]


class _QRect(ctypes.Structure):
    # Qt 5's QRect: left, top, right, bottom (right = left + width - 1).
    _fields_ = [("x1", ctypes.c_int), ("y1", ctypes.c_int), ("x2", ctypes.c_int),
                ("y2", ctypes.c_int)]


class _AbortButton:
    """The Abort button beside ParaView's progress bar, and the main window, during a run.

    In ParaView 5.11 the button is disabled (nothing calls pqProgressManager::setEnableAbort)
    and its press only emits pqProgressManager::abort(), a signal nothing is connected to.
    ParaView's Python has no Qt bindings to connect a slot, so for the length of a run the
    button is enabled through the manager and made checkable: a click leaves it checked, and
    the run asks for that between steps. The main window is watched the same way: a window
    that was shown when the run began and is hidden now was closed (ParaView hides it and
    quits once the event loop gets back control), so the run stops instead of keeping a
    hidden ParaView alive. Where a symbol is missing (Windows, Qt 6, pvpython), nothing is
    watched and the abort flag alone stops a run."""
    looked_up = False
    lib = None
    manager = None  # the pqProgressManager
    window = None  # the main window (QWidget*)
    button = None  # the QToolButton "AbortButton"

    def __init__(self):
        self.active = False
        self.window_shown = False
        try:
            if not self._look_up():
                return
            self.window_shown = self._visible()
            self._enable(True)
            self._call("_ZN15QAbstractButton12setCheckableEb", None, ctypes.c_void_p,
                       ctypes.c_bool)(self.button, True)
            self._set_checked(False)
            self.unblocked = self._unblock(False)
            _Qt.hooks.append(self._guard)
            self.active = True
        except (OSError, ValueError, AttributeError, TypeError):
            self.active = False

    def _unblock(self, on):
        """pqProgressManager::unblockEvents: whether presses pass its lock; returns the
        value it had."""
        return bool(self._call("_ZN17pqProgressManager13unblockEventsEb", ctypes.c_bool,
                               ctypes.c_void_p, ctypes.c_bool)(self.manager, on))

    def _guard(self):
        """Before the GUI's events are processed: open the progress manager's lock on presses
        while the pointer is over the Abort button, close it elsewhere. Qt delivers a press
        to the window object before the widget under the pointer, and the manager drops it
        there, so without this the button never sees a press during a run. The pointer's
        place is asked from the window system (QCursor::pos), so a press that follows the
        pointer's arrival on the button finds the lock open; other presses stay dropped."""
        try:
            pos = self._call("_ZN7QCursor3posEv", _QPoint)()
            corner = self._call("_ZNK7QWidget11mapToGlobalERK6QPoint", _QPoint, ctypes.c_void_p,
                                ctypes.c_void_p)(self.button, ctypes.byref(_QPoint(0, 0)))
            rect = self._call("_ZNK7QWidget13frameGeometryEv", _QRect, ctypes.c_void_p)(
                self.button)
            over = (0 <= pos.x - corner.x <= rect.x2 - rect.x1
                    and 0 <= pos.y - corner.y <= rect.y2 - rect.y1)
            self._unblock(over)
        except (OSError, ValueError, AttributeError, TypeError):
            pass

    @classmethod
    def _call(cls, name, restype, *argtypes):
        f = getattr(cls.lib, name)
        f.restype, f.argtypes = restype, list(argtypes)
        return f

    @classmethod
    def _look_up(cls):
        """Find the progress manager, the main window and its Abort button (once found,
        kept: they live as long as the GUI)."""
        if cls.button:
            return True
        if cls.looked_up:
            return False
        try:
            # PyDLL: the GIL stays held; setEnableAbort and setChecked emit signals.
            cls.lib = ctypes.PyDLL(None)
            core = cls._call("_ZN17pqApplicationCore8instanceEv", ctypes.c_void_p)()
            window = cls._call("_ZN15pqCoreUtilities14findMainWindowEv", ctypes.c_void_p)()
        except (OSError, ValueError, AttributeError, TypeError):
            cls.looked_up = True
            return False
        if not core or not window:
            # pvpython, or a GUI whose window is not made yet: ask again next run.
            return False
        cls.looked_up = True
        find = cls._call(
            "_Z20qt_qFindChild_helperPK7QObjectRK7QStringRK11QMetaObject6QFlagsIN2Qt15"
            "FindChildOptionEE", ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
            ctypes.c_void_p, ctypes.c_int)

        def child(parent, name, meta):
            meta = ctypes.c_void_p.in_dll(cls.lib, meta)
            # 1: Qt::FindChildrenRecursively
            return find(parent, ctypes.byref(cls._qstring(name)), ctypes.addressof(meta), 1)

        manager = child(core, None, "_ZN17pqProgressManager16staticMetaObjectE")
        button = child(window, "AbortButton", "_ZN11QToolButton16staticMetaObjectE")
        if manager and button:
            cls.manager, cls.window, cls.button = manager, window, button
            return True
        return False

    @classmethod
    def _qstring(cls, text):
        """A QString made by QString::fromUtf8 (None: a null one, which matches any object
        name); its few bytes are not released."""
        data = text.encode("utf-8") if text is not None else None
        buf = (ctypes.c_void_p * 1)()
        cls._call("_ZN7QString15fromUtf8_helperEPKci", ctypes.c_void_p, ctypes.c_void_p,
                  ctypes.c_char_p, ctypes.c_int)(ctypes.byref(buf), data, len(data or b""))
        return buf

    def _enable(self, on):
        # Through the progress manager (its enableAbort signal reaches the button), and on
        # the button itself, where the manager is locked by another sender and ignores it.
        self._call("_ZN17pqProgressManager14setEnableAbortEb", None, ctypes.c_void_p,
                   ctypes.c_bool)(self.manager, on)
        self._call("_ZN7QWidget10setEnabledEb", None, ctypes.c_void_p, ctypes.c_bool)(
            self.button, on)

    def _visible(self):
        # QWidget::isVisibleTo(nullptr) is isVisible() (the latter is inline).
        return bool(self._call("_ZNK7QWidget11isVisibleToEPKS_", ctypes.c_bool, ctypes.c_void_p,
                               ctypes.c_void_p)(self.window, None))

    def _set_checked(self, on):
        self._call("_ZN15QAbstractButton10setCheckedEb", None, ctypes.c_void_p,
                   ctypes.c_bool)(self.button, on)

    def requested(self):
        """Whether the Abort button was clicked (or is held down), or the main window was
        closed, since the run began."""
        if not self.active:
            return False
        checked = self._call("_ZNK15QAbstractButton9isCheckedEv", ctypes.c_bool,
                             ctypes.c_void_p)(self.button)
        down = self._call("_ZNK15QAbstractButton6isDownEv", ctypes.c_bool,
                          ctypes.c_void_p)(self.button)
        return bool(checked or down or (self.window_shown and not self._visible()))

    def closed(self):
        """Whether the main window was closed during the run."""
        return self.active and self.window_shown and not self._visible()

    def end(self):
        """The button as ParaView 5.11 has it between runs: unchecked, disabled."""
        if not self.active:
            return
        self.active = False
        if self._guard in _Qt.hooks:
            _Qt.hooks.remove(self._guard)
        self._unblock(self.unblocked)
        self._set_checked(False)
        self._call("_ZN15QAbstractButton12setCheckableEb", None, ctypes.c_void_p,
                   ctypes.c_bool)(self.button, False)
        self._enable(False)


class _GuiProgress:
    """ParaView's progress bar driven from the client, for a run that is no pipeline update
    (a remote run: t2tf runs here while the filter's algorithm lives on the server). Like an
    update, it holds the GUI's input for the run (pqProgressManager::setEnableProgress counts
    it as one), so no second run starts meanwhile. Nothing outside the GUI."""

    def __init__(self):
        self.active = False
        try:
            if _AbortButton._look_up():
                _AbortButton._call("_ZN17pqProgressManager17setEnableProgressEb", None,
                                   ctypes.c_void_p, ctypes.c_bool)(_AbortButton.manager, True)
                self.active = True
        except (OSError, ValueError, AttributeError, TypeError):
            self.active = False

    def update(self, text, fraction):
        if self.active:
            _AbortButton._call("_ZN17pqProgressManager11setProgressERK7QStringi", None,
                               ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int)(
                _AbortButton.manager, ctypes.byref(_AbortButton._qstring(text)),
                int(round(100 * fraction)))

    def end(self):
        if self.active:
            self.active = False
            _AbortButton._call("_ZN17pqProgressManager17setEnableProgressEb", None,
                               ctypes.c_void_p, ctypes.c_bool)(_AbortButton.manager, False)


class Progress:
    """What ParaView shows of a run: the algorithm's progress text ("Text to Transfer
    Function: step k/N, loss L, ETA s") and fraction, refreshed at least once a second,
    with the GUI's events processed in between."""

    def __init__(self, algorithm=None, gui=None):
        self.algorithm = algorithm
        self.gui = gui  # a _GuiProgress: the progress bar of a run with no algorithm
        self.start = time.time()
        self.step, self.steps, self.loss = 0, None, None
        self.first_step = None  # when step 1 ended: the rate is measured after it
        self.eta, self.eta_at = None, None
        self.shown = 0.0

    def on_step(self, step, steps, loss=None, eta=None):
        now = time.time()
        self.step, self.steps, self.loss = int(step), max(1, int(steps)), loss
        if self.first_step is None:
            self.first_step = now
        if eta is None and self.step >= 3:
            # The first step carries one-off work (caption embeddings), so the rate comes
            # from the steps after it, as the CLI's estimate does.
            eta = (now - self.first_step) / (self.step - 1) * (self.steps - self.step)
        self.eta, self.eta_at = eta, now
        self.show()

    def text(self):
        if not self.steps:
            return "%s: starting (%.0f s)" % (TITLE, time.time() - self.start)
        line = "%s: step %d/%d" % (TITLE, self.step, self.steps)
        if self.loss is not None:
            line += ", loss %.4f" % self.loss
        if self.eta is None:
            return line + ", ETA …"
        return line + ", ETA %.0f s" % max(0.0, self.eta - (time.time() - self.eta_at))

    def fraction(self):
        return float(self.step) / self.steps if self.steps else 0.0

    def show(self):
        self.shown = time.time()
        if self.algorithm is not None:
            self.algorithm.SetProgressText(self.text())
            self.algorithm.UpdateProgress(self.fraction())
        if self.gui is not None:
            self.gui.update(self.text(), self.fraction())
        _Qt.process_events()

    def tick(self):
        """Between steps: refresh the text once a second, process GUI events always."""
        if time.time() - self.shown >= 0.5:
            self.show()
        else:
            _Qt.process_events()


class Run:
    """One `t2tf optimize --progress json` child: its progress, cancellation and result."""

    def __init__(self, args, out):
        self.args, self.out = args, out
        self.lines = queue.Queue()
        self.cancelled = False
        self.done = None
        self.tail = []

    def cancel(self):
        if not self.cancelled and self.proc.poll() is None:
            # SIGINT: t2tf finishes the current step and writes the last finished step's TF.
            self.cancelled = True
            self.proc.send_signal(signal.SIGINT)

    def _read(self):
        for line in self.proc.stderr:
            self.lines.put(line)
        self.lines.put(None)

    def run(self, progress=None, aborted=None, timeout=None):
        """Run to the end; `progress` (a Progress) per step and between steps; `aborted()`
        polled to cancel."""
        progress = progress or Progress()
        self.proc = subprocess.Popen(
            self.args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        _runs().append(self)
        try:
            reader = threading.Thread(target=self._read, daemon=True)
            reader.start()
            start = time.time()
            while True:
                if aborted is not None and aborted():
                    self.cancel()
                if timeout is not None and time.time() - start > timeout:
                    self.cancel()
                try:
                    # Short waits, so the GUI's events are processed between them.
                    line = self.lines.get(timeout=0.05)
                except queue.Empty:
                    progress.tick()
                    continue
                if line is None:
                    break
                self._line(line, progress)
            self.proc.wait()
        finally:
            _runs().remove(self)
        # A run stopped by a signal (the cancel sends SIGINT) exits with 128 + the signal after
        # writing the last finished step's result; its done event says so.
        stopped = self.done is not None and self.done.get("interrupted")
        if self.done is None or (self.proc.returncode != 0 and not stopped):
            raise T2tfError(with_advice(
                "t2tf failed (exit status %s): %s"
                % (self.proc.returncode, " | ".join(self.tail[-3:]) or "no output")))
        return self.done

    def _line(self, line, progress):
        line = line.strip()
        try:
            event = json.loads(line)
        except ValueError:
            # Not progress: keep the last lines for the error message.
            if line:
                self.tail.append(line)
            return
        kind = event.get("event")
        if kind == "step":
            progress.on_step(event["step"], event.get("steps", 1), event.get("loss"),
                             event.get("eta_s"))
        elif kind == "done":
            self.done = event
        elif kind == "error" and "message" in event:
            self.tail.append(event["message"])


def optimize(volume, out, prompt, negatives=(), steps=300, views=3, seed=0, model=None,
             tokenizer=None, array=None, reference_image=None, extra=(), progress=None,
             aborted=None, timeout=None, init=None, locks=()):
    """Run the t2tf binary on a volume file, writing into `out`; returns the result (see
    read_result). `progress`: a Progress; `init`: a TF file to start from; `locks`: (min,
    max) data ranges kept as they start."""
    if not (prompt or "").strip() and not reference_image:
        raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")
    args = [find_binary(), "optimize", volume, "--out", out, "--progress", "json"]
    if (prompt or "").strip():
        args += ["--prompt", prompt]
    for n in negatives or ():
        if n.strip():
            args += ["--negative", n]
    args += ["--steps", str(int(steps)), "--views", str(int(views)), "--seed", str(int(seed))]
    if model:
        args += ["--model", model]
    if tokenizer:
        args += ["--tokenizer", tokenizer]
    if array:
        args += ["--array", array]
    if reference_image:
        args += ["--reference-image", reference_image]
    if init:
        args += ["--init", init]
    for lo, hi in locks or ():
        args += ["--lock=%r,%r" % (float(lo), float(hi))]
    args += list(extra)
    done = Run(args, out).run(progress, aborted, timeout)
    return read_result(done, prompt, reference_image)


class _InProcessRun:
    """A run of the t2tf module in this process, as the run list holds it: cancel() is
    answered at the end of the current step."""

    def __init__(self):
        self.cancelled = False

    def cancel(self):
        self.cancelled = True


def optimize_in_process(t2tf, image, array, out, prompt, negatives=(), steps=300, views=3,
                        seed=0, model=None, tokenizer=None, reference_image=None,
                        progress=None, aborted=None, init=None, locks=()):
    """Run t2tf in this process on `image`'s point array `array` (read in place, no file
    written) and save its files into `out`; returns the result as read_result gives it.
    `progress` (a Progress) per step; `aborted()` is asked after each step and stops the
    run there (keeping that step's TF), as cancel() does."""
    if not (prompt or "").strip() and not reference_image:
        raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")
    progress = progress or Progress()
    handle = _InProcessRun()

    def on_event(event):
        if event["event"] == "step":
            progress.on_step(event["step"], event["steps"], event.get("loss"))
        elif event["event"] == "warning":
            message("warning: " + event["message"], False)
        return not (handle.cancelled or (aborted is not None and aborted()))

    _runs().append(handle)
    try:
        volume = t2tf.vtk.volume_from_vtk(image, array)
        run = t2tf.optimize(
            volume, (prompt or "").strip() or None, negatives=[n for n in negatives if n.strip()],
            steps=int(steps), views=int(views), seed=int(seed), model=model or None,
            tokenizer=tokenizer or None, reference_image=reference_image or None,
            progress=on_event, init=init or None, lock=[tuple(l) for l in locks or ()])
        report = run.save(out)
    except (t2tf.Error, ValueError) as e:
        raise T2tfError(with_advice(str(e)))
    finally:
        _runs().remove(handle)
    result = read_result({"out": out, "files": report["outputs"], "interrupted": run.interrupted},
                         prompt, reference_image)
    # An array has no file to reopen, so no pvpython script holds the camera: the run has it.
    result["camera"] = run.camera
    return result


def parse_locks(text):
    """'MIN,MAX; MIN,MAX' (the Lock Ranges property) as [(min, max), ...]."""
    locks = []
    for part in (text or "").replace("\n", ";").split(";"):
        if not part.strip():
            continue
        try:
            lo, hi = (float(v) for v in part.split(","))
        except ValueError:
            raise T2tfError("Lock Ranges: %r is not MIN,MAX (e.g. 120,400; 800,1200)" % part.strip())
        locks.append((lo, hi))
    return locks


def write_current_tf(array, path, source=None):
    """Write the colour and opacity functions ParaView now uses for `array` (and the unit
    distance of `source`'s display) as a preset file: the start of a Refine."""
    with open(path, "w") as f:
        json.dump([current_tf(array, source)], f)
    return path


def current_tf(array, source=None):
    """The colour and opacity functions ParaView now uses for `array` (and the unit distance
    of `source`'s display), as a ParaView JSON preset."""
    import paraview.simple as pvs

    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    rgb, points = list(lut.RGBPoints), list(pwf.Points)
    if len(rgb) < 8 or len(points) < 8:
        raise T2tfError("Refine: %s has no colour and opacity function to start from" % array)
    space = _text(lut.ColorSpace)
    preset = {"Name": "current", "ColorSpace": space, "RGBPoints": rgb, "Points": points}
    if space == "HSV":
        preset["HSVWrap"] = int(lut.HSVWrap)
    if source is not None:
        disp = pvs.GetDisplayProperties(source)
        preset[UNIT_DISTANCE_KEY] = float(disp.ScalarOpacityUnitDistance)
    return preset


def remember_model(model, tokenizer):
    """Keep the Model and Tokenizer of a run that worked as the defaults of new filters, in
    ParaView's user settings (saved at exit, read by the next session)."""
    from paraview import servermanager

    settings = servermanager.vtkSMSettings.GetInstance()
    for prop, value in (("Model", model), ("Tokenizer", tokenizer)):
        settings.SetSetting("filters.TextToTransferFunction." + prop, value or "")


def _file_digest(path):
    """The SHA-256 of a file's bytes; the text itself when it names no file (empty, or a
    file that is not there: the run will say so)."""
    if not path or not os.path.isfile(path):
        return path
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _folder_digest(path):
    """A local model folder by its files' names, sizes and modification times (weights are
    large: not read); a Hub id as itself."""
    if not path or not os.path.isdir(path):
        return path
    files = []
    for name in sorted(os.listdir(path)):
        st = os.stat(os.path.join(path, name))
        files.append((name, st.st_size, st.st_mtime_ns))
    return [os.path.abspath(path), files]


def _script_list(text, name):
    for line in text.splitlines():
        if line.startswith(name + " = "):
            return json.loads(line[len(name) + 3:])
    return None


def preset_name(prompt, reference_image=None):
    """The preset's name in ParaView: "t2tf: " and the prompt (whitespace collapsed, cut at
    60 characters), so Choose Preset shows what each result was made for."""
    what = " ".join((prompt or "").split())
    if not what and reference_image:
        what = "like " + os.path.basename(reference_image)
    if len(what) > 60:
        what = what[:59] + "…"
    return PRESET_PREFIX + (what or "transfer function")


def read_result(done, prompt="", reference_image=None):
    """What the display needs from the files named by t2tf's done event, in memory (the
    folder is removed after the run): preset, points, unit distance, camera, report."""
    out = done["out"]
    files = done.get("files", [])
    preset_file = next(
        (os.path.join(out, f) for f in files
         if f.endswith(".json") and f != "report.json"), None)
    if preset_file is None:
        raise T2tfError("t2tf wrote no preset in " + out)
    with open(preset_file) as f:
        data = json.load(f)
    preset = data[0] if isinstance(data, list) else data
    preset["Name"] = preset_name(prompt, reference_image)
    result = {
        "name": preset["Name"],
        "preset": preset,
        "rgb": [float(v) for v in preset["RGBPoints"]],
        "points": [float(v) for v in preset.get("Points", [])],
        "unit_distance": preset.get(UNIT_DISTANCE_KEY),
        "interrupted": bool(done.get("interrupted")),
        "camera": None,
        "report": "",
    }
    report = os.path.join(out, "report.json")
    if os.path.exists(report):
        with open(report) as f:
            result["report"] = f.read()
    # The camera of t2tf's view: the one its generated pvpython script sets.
    script = next((os.path.join(out, f) for f in files if f.endswith("_paraview.py")), None)
    if script:
        with open(script) as f:
            text = f.read()
        cam = {k: _script_list(text, "CAMERA_" + k.upper())
               for k in ("position", "focal_point", "view_up")}
        angle = re.search(r"^CAMERA_VIEW_ANGLE = (.+)$", text, re.M)
        if all(cam.values()) and angle:
            cam["view_angle"] = float(angle.group(1))
            result["camera"] = cam
    return result


# ---- client side: presets, displays, camera -------------------------------------------

def _presets():
    from paraview import servermanager

    return servermanager.vtkSMTransferFunctionPresets.GetInstance()


def _remove_preset(presets, name):
    """Remove the user presets called `name` (never a built-in one)."""
    removed = 0
    for i in reversed(range(presets.GetNumberOfPresets())):
        if presets.GetPresetName(i) == name and not presets.IsPresetBuiltin(i):
            presets.RemovePreset(i)
            removed += 1
    return removed


def register_preset(result, replaces=None):
    """Add the result to ParaView's preset manager under its name, replacing a preset of
    that name and `replaces` (the name the same filter's previous run registered), so a
    re-run updates its preset instead of adding another. The old one is removed first:
    adding a name that exists is fragile in ParaView 5.10 and later. The preset joins the
    groups "Default" and "User", as a preset imported in Choose Preset does: the dialog
    opens on "Default" and lists only that group's presets."""
    presets = _presets()
    for name in {result["name"], replaces} - {None}:
        _remove_preset(presets, name)
        _PresetGroups.remove(name)
    presets.AddPreset(result["name"], json.dumps(result["preset"]))
    _PresetGroups.add(result["name"])
    return bool(presets.HasPreset(result["name"]))


def remove_presets():
    """Remove every preset this plugin registered ("t2tf: ..."); returns how many."""
    presets = _presets()
    names = {presets.GetPresetName(i) for i in range(presets.GetNumberOfPresets())
             if not presets.IsPresetBuiltin(i)}
    removed = 0
    for name in names:
        if name.startswith(PRESET_PREFIX):
            removed += _remove_preset(presets, name)
            _PresetGroups.remove(name)
    return removed


class _PresetGroups:
    """The preset groups of ParaView's Choose Preset dialog (ParaView 5.11). They live in
    the GUI's pqPresetGroupsManager, which saves them to the setting
    TransferFunctionPresets.Groups on every change and reads it at start-up (else its
    built-in groups). In the GUI the manager itself is called (through ctypes: ParaView's
    Python has no Qt bindings), so the open dialog and the saved setting both follow. In
    pvpython and pvbatch there is no manager: the setting is edited where a GUI saved one;
    where none was saved, the next GUI start loads the built-in groups, which cannot be
    written here without their list, and the preset shows under "All"."""
    GROUPS = ("Default", "User")
    SETTING = "TransferFunctionPresets.Groups"
    looked_up = False
    manager = None
    lib = None

    @classmethod
    def _manager(cls):
        if not cls.looked_up:
            cls.looked_up = True
            try:
                # PyDLL: the GIL stays held, as the manager's signals run ParaView code.
                cls.lib = ctypes.PyDLL(None)
                core = cls._function("_ZN17pqApplicationCore8instanceEv", ctypes.c_void_p)()
                if core:
                    get = cls._function("_ZN17pqApplicationCore7managerERK7QString",
                                        ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)
                    cls.manager = get(core, cls._qstring("PRESET_GROUP_MANAGER")) or None
            except (OSError, ValueError, AttributeError, TypeError):
                cls.manager = None
        return cls.manager

    @classmethod
    def _function(cls, name, restype, *argtypes):
        f = getattr(cls.lib, name)
        f.restype, f.argtypes = restype, list(argtypes)
        return f

    @classmethod
    def _qstring(cls, text):
        """A QString (a pointer to its shared data) made by QString::fromUtf8. Its data is
        not released: a few dozen bytes per call, a few calls per run."""
        data = text.encode("utf-8")
        buf = (ctypes.c_void_p * 1)()
        cls._function("_ZN7QString15fromUtf8_helperEPKci", ctypes.c_void_p, ctypes.c_void_p,
                      ctypes.c_char_p, ctypes.c_int)(ctypes.byref(buf), data, len(data))
        return ctypes.byref(buf)

    @classmethod
    def add(cls, name):
        try:
            manager = cls._manager()
            if manager:
                add = cls._function("_ZN21pqPresetGroupsManager10addToGroupERK7QStringS2_",
                                    None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)
                for group in cls.GROUPS:
                    add(manager, cls._qstring(group), cls._qstring(name))
            else:
                cls._edit_setting(name, add=True)
        except Exception as e:  # the preset is there; only its group is missing
            message("could not add %s to the preset groups: %s" % (name, e), False)

    @classmethod
    def remove(cls, name):
        try:
            manager = cls._manager()
            if manager:
                cls._function("_ZN21pqPresetGroupsManager19removeFromAllGroupsERK7QString",
                              None, ctypes.c_void_p, ctypes.c_void_p)(
                                  manager, cls._qstring(name))
            else:
                cls._edit_setting(name, add=False)
        except Exception as e:
            message("could not remove %s from the preset groups: %s" % (name, e), False)

    @classmethod
    def _edit_setting(cls, name, add):
        from paraview import servermanager

        settings = servermanager.vtkSMSettings.GetInstance()
        text = settings.GetSettingAsString(cls.SETTING, "")
        if not text:
            return
        groups = json.loads(text)
        changed = False
        for group in groups:
            members = group.setdefault("presets", [])
            if add and group.get("groupName") in cls.GROUPS and name not in members:
                members.append(name)
                changed = True
            elif not add and name in members:
                members.remove(name)
                changed = True
                if not members and group.get("groupName") != "Default":
                    group["drop"] = True  # as the manager drops a group it emptied
        groups = [g for g in groups if not g.pop("drop", False)]
        if add:
            have = {g.get("groupName") for g in groups}
            for missing in [g for g in cls.GROUPS if g not in have]:
                groups.append({"groupName": missing, "presets": [name]})
                changed = True
        if changed:
            settings.SetSetting(cls.SETTING, json.dumps(groups, separators=(",", ":")))


def apply_transfer_function(result, array):
    """Set the array's colour and opacity functions to t2tf's points, never rescaled."""
    import paraview.simple as pvs

    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    lut.AutomaticRescaleRangeMode = "Never"
    lut.ColorSpace = "RGB"
    lut.RGBPoints = result["rgb"]
    lut.ScalarRangeInitialized = 1
    if result["points"]:
        pwf.Points = result["points"]
        pwf.ScalarRangeInitialized = 1
    return lut, pwf


def apply_to_display(result, source, view=None, array=None, camera=True):
    """Show `source` as a volume in `view` with t2tf's TF, unit distance and (optionally)
    camera. Returns the display."""
    import paraview.simple as pvs

    view = view or pvs.GetActiveViewOrCreate("RenderView")
    array = array or result.get("array")
    disp = pvs.GetDisplayProperties(source, view)
    disp.Representation = "Volume"
    pvs.ColorBy(disp, ("POINTS", array))
    lut, pwf = apply_transfer_function(result, array)
    disp.LookupTable = lut
    disp.ScalarOpacityFunction = pwf
    if result.get("unit_distance") is not None:
        disp.ScalarOpacityUnitDistance = float(result["unit_distance"])
    if camera and result.get("camera"):
        apply_camera(result["camera"], view)
    return disp


# The view properties apply_camera sets, in the order an undo restores them.
CAMERA_PROPERTIES = ("CameraPosition", "CameraFocalPoint", "CameraViewUp", "CameraViewAngle",
                     "CameraParallelProjection")


def apply_camera(cam, view):
    """Set `view`'s camera to `cam`. Inside an undo set (the GUI's Apply), the change joins
    it: ParaView's undo stack leaves camera proxies out of its records, so without this
    Undo Apply would keep t2tf's camera."""
    undo = _camera_undo_elements(view)
    view.CameraPosition = cam["position"]
    view.CameraFocalPoint = cam["focal_point"]
    view.CameraViewUp = cam["view_up"]
    view.CameraViewAngle = cam["view_angle"]
    view.CameraParallelProjection = 0
    if undo is not None:
        undo()


def _camera_undo_elements(view):
    """Where an undo stack builder listens (ParaView's GUI), note the camera properties of
    `view` now and return a function that notes them again and adds both notes to the undo
    set being recorded (the builder keeps them only while one is, e.g. during Apply); else
    None. An undo set undoes its elements last to first and redoes
    them first to last, so Undo ends on the camera noted first and Redo on the one noted
    second (the pattern of ParaView's own camera undo, vtkSMInteractionUndoStackBuilder)."""
    from paraview import servermanager

    try:
        builder = servermanager.vtkSMProxyManager.GetProxyManager().GetUndoStackBuilder()
    except AttributeError:
        return None
    # The builder adds an element only while a set is being recorded (its Add says whether).
    if builder is None or builder.GetIgnoreAllChanges():
        return None
    proxy = view.SMProxy
    try:
        proxy.SynchronizeCameraProperties()  # the camera as shown, after any interaction
    except AttributeError:
        pass

    def note():
        elements = []
        for name in CAMERA_PROPERTIES:
            element = servermanager.vtkSMPropertyModificationUndoElement()
            element.ModifiedProperty(proxy, name)
            elements.append(element)
        return elements

    before = note()

    def finish():
        for element in before + note():
            builder.Add(element)

    return finish


# Results of filters run in this process, applied to their displays as those appear
# (ParaView creates a filter's display after its first update, so RequestData cannot).
_PENDING = {}
_OBSERVED = []


def _proxy_of(algorithm):
    """The source proxy whose VTK object is `algorithm` (builtin session), else None."""
    from paraview import servermanager

    if servermanager.ActiveConnection is None:
        return None
    for proxy in servermanager.ProxyManager().GetProxiesInGroup("sources").values():
        try:
            if proxy.GetClientSideObject() is algorithm:
                return proxy
        except AttributeError:
            continue
    return None


def _apply_pending(*_):
    """Apply each pending result to every display of its filter not yet given it. Displays
    are found among registered representations (not through views: ParaView registers a
    new display before adding it to its view)."""
    import paraview.simple as pvs
    from paraview import servermanager

    if not _PENDING:
        return
    reprs = servermanager.ProxyManager().GetProxiesInGroup("representations").values()
    for proxy, result, camera, applied in list(_PENDING.values()):
        for disp in reprs:
            try:
                if disp.Input.SMProxy is not proxy.SMProxy:
                    continue
                disp.ScalarOpacityUnitDistance
            except AttributeError:
                continue  # not a display of this filter, or not a 3D one
            key = disp.GetGlobalIDAsString()
            if key in applied:
                continue
            applied.add(key)
            disp.Representation = "Volume"
            # The colour array and functions are set as properties, not through ColorBy:
            # ColorBy rescales a new colour map to the display's data range, which a display
            # registered by a loading state does not know yet ("Could not determine array
            # range."), and t2tf's map is never rescaled anyway.
            disp.ColorArrayName = ["POINTS", result["array"]]
            lut, pwf = apply_transfer_function(result, result["array"])
            disp.LookupTable = lut
            disp.ScalarOpacityFunction = pwf
            if result.get("unit_distance") is not None:
                disp.ScalarOpacityUnitDistance = float(result["unit_distance"])
            if camera and result.get("camera"):
                for view in pvs.GetViews():
                    if view.GetXMLName() == "RenderView":
                        apply_camera(result["camera"], view)


def _watch_displays():
    """Apply pending results whenever a proxy (e.g. a new display) is registered."""
    from paraview import servermanager

    pxm = servermanager.ProxyManager().SMProxyManager
    if pxm not in _OBSERVED:
        pxm.AddObserver("RegisterEvent", _apply_pending)
        _OBSERVED.append(pxm)


# ---- time estimate -------------------------------------------------------------------

# The timing the last run with each model measured (model -> measured_timing(...)).
_TIMINGS = {}


def measured_timing(report, views, wall_seconds):
    """What a run measured, for estimates: the median time of one step per view (steps after
    the first, which carries one-off work), and the start-up (the run's wall time less its
    steps: model loading, caption embeddings, output). None without two timed steps."""
    try:
        steps = [float(s["seconds"]) for s in json.loads(report)["steps"]]
    except (ValueError, KeyError, TypeError):
        return None
    later = sorted(steps[1:])
    if not later or views < 1:
        return None
    per_step = later[len(later) // 2]
    return {"per_view_step": per_step / views,
            "start": max(0.0, wall_seconds - sum(steps))}


def _seconds(value):
    if value >= 120:
        return "%.0f min" % (value / 60.0)
    if value >= 10:
        return "%.0f s" % value
    return "%.1f s" % value


def time_estimate(steps, views, timing):
    """The Time Estimate text for `steps` x `views` from a measured_timing()."""
    if not timing:
        return "known after the first run with this model"
    each = timing["per_view_step"]
    total = steps * views * each + timing["start"]
    ms = 1000.0 * each
    # The total last: the panel's read-only field shows a long text's end.
    return "%d steps x %d views x %s ms + %s start = about %s" % (
        steps, views, "%.1f" % ms if ms < 10 else "%.0f" % ms, _seconds(timing["start"]),
        _seconds(total))


# ---- the filter ----------------------------------------------------------------------

def _text(value):
    """An enumeration property's text (its GetData()), else the value as text."""
    return str(value.GetData() if hasattr(value, "GetData") else value)


def _upstream_file(proxy, array):
    """(path, extra t2tf flags) when the filter's input is a file t2tf reads, else None."""
    try:
        reader = proxy.Input
        name = reader.GetXMLName()
    except AttributeError:
        return None
    if name == "XMLImageDataReader":
        names = list(reader.FileName)  # a FileNameProperty, not a str
        if len(names) == 1 and names[0].lower().endswith(".vti"):
            return (names[0], [])
        return None
    if name == "ImageReader" and len(list(reader.FileNames)) == 1:
        types = {"unsigned char": "uint8", "char": "int8", "unsigned short": "uint16",
                 "short": "int16", "unsigned int": "uint32", "int": "int32",
                 "float": "float32", "double": "float64"}
        dtype = types.get(_text(reader.DataScalarType))
        e = list(reader.DataExtent)
        # FileDimensionality is an enumeration property: compare its text.
        if (dtype is None or reader.NumberOfScalarComponents != 1
                or _text(reader.FileDimensionality) != "3"
                or any(e[i] != 0 for i in (0, 2, 4)) or any(reader.DataOrigin)):
            return None
        dims = "%d,%d,%d" % (e[1] + 1, e[3] + 1, e[5] + 1)
        spacing = ",".join(repr(float(s)) for s in reader.DataSpacing)
        order = "big" if _text(reader.DataByteOrder) == "BigEndian" else "little"
        return (list(reader.FileNames)[0],
                ["--dims", dims, "--dtype", dtype, "--spacing", spacing, "--byte-order", order])
    return None


def write_vti(image, array, path):
    """The image with only `array` (as its scalars) as a .vti file t2tf reads."""
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    copy = vtkImageData()
    copy.SetExtent(image.GetExtent())
    copy.SetOrigin(image.GetOrigin())
    copy.SetSpacing(image.GetSpacing())
    copy.GetPointData().SetScalars(image.GetPointData().GetArray(array))
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(path)
    writer.SetInputData(copy)
    if not writer.Write():
        raise T2tfError("could not write the input to " + path)


def _on_server():
    """(whether this process is a pvserver, its MPI rank)."""
    from paraview.modules.vtkRemotingCore import vtkProcessModule

    pm = vtkProcessModule.GetProcessModule()
    if pm is None:
        return False, 0
    server = pm.GetProcessType() in (vtkProcessModule.PROCESS_SERVER,
                                     vtkProcessModule.PROCESS_DATA_SERVER,
                                     vtkProcessModule.PROCESS_RENDER_SERVER)
    return server, pm.GetPartitionId()


def _input_key(image, array):
    """A digest of what t2tf would read: geometry, array name and values."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    import numpy

    h = hashlib.sha256()
    h.update(repr((image.GetExtent(), image.GetSpacing(), image.GetOrigin(), array)).encode())
    values = numpy.ascontiguousarray(vtk_to_numpy(image.GetPointData().GetArray(array)))
    h.update(str(values.dtype).encode())
    h.update(memoryview(values).cast("B"))
    return h.hexdigest()


# The panel lists properties in this order (ParaView keeps the XML's order); the advanced
# ones show behind the panel's gear button. Every property says what it does in a tooltip.
PROPERTIES_XML = """
<Documentation short_help="Optimize a transfer function for a sentence with t2tf."
    long_help="Optimizes a volume-rendering transfer function (colour and opacity) so that
    renderings of the data match a sentence under CLIP, and shows the data with it.">
  Text To Transfer Function runs t2tf on the input image data: it renders the volume from
  random views, scores the renderings against the Prompt (and against the Negatives) with a
  CLIP model, and optimizes the colour and opacity functions by gradient descent. The result
  is applied to the output's display (colour, opacity, unit distance, no automatic
  rescaling), registered as the preset "t2tf: PROMPT", and kept with a saved state. The run
  time grows with Steps x Views; the progress bar shows the step, the loss and the time
  left, and Abort (or t2tf_plugin.cancel() in Python) stops after the current step, keeping
  that step's transfer function.
</Documentation>
<InputProperty name="Input" command="SetInputConnection">
  <ProxyGroupDomain name="groups"><Group name="sources" /><Group name="filters" /></ProxyGroupDomain>
  <DataTypeDomain name="input_type" composite_data_supported="0">
    <DataType value="vtkImageData" />
  </DataTypeDomain>
  <InputArrayDomain name="input_array" attribute_type="point" number_of_components="1" />
  <Documentation>Image data with a point array of one component.</Documentation>
</InputProperty>
<StringVectorProperty name="Prompt" command="SetPrompt" number_of_elements="1"
    default_values="">
  <Documentation>What the rendering should show, in plain words, e.g. "a potted tree" or
  "the teeth of a CT head".</Documentation>
</StringVectorProperty>
<StringVectorProperty name="Negatives" label="Negatives" command="SetNegative"
    clean_command="ClearNegatives" repeat_command="1" number_of_elements_per_command="1"
    number_of_elements="1" default_values="a blank image">
  <Hints><ShowLabel /></Hints>
  <Documentation>What the rendering should not look like, one phrase per row (default: "a
  blank image"); sampled captions are added to them at every step.</Documentation>
</StringVectorProperty>
<IntVectorProperty name="Steps" command="SetSteps" number_of_elements="1"
    default_values="300">
  <IntRangeDomain name="range" min="1" max="5000" />
  <Documentation>Optimization steps. Each renders Views images and runs CLIP on each, so
  the run time is about Steps x Views x the time of one rendering and CLIP pass (the
  progress bar shows the time left). 300 is the paper's setting; a Refine needs far
  fewer.</Documentation>
</IntVectorProperty>
<IntVectorProperty name="Views" command="SetViews" number_of_elements="1" default_values="3">
  <IntRangeDomain name="range" min="1" max="16" />
  <Documentation>Random views rendered per step (run time grows with them).</Documentation>
</IntVectorProperty>
<StringVectorProperty name="TimeEstimate" label="Time Estimate" command="GetTimeEstimate"
    information_only="1" number_of_elements="1" default_values="" panel_visibility="default">
  <Documentation>How long a run with the applied Steps and Views takes: Steps x Views x
  the time of one step and view that the last run with this Model measured, plus that run's
  start-up (loading the model, caption embeddings). Read-only; it follows Steps and Views
  when they are applied, and is known after the first run.</Documentation>
</StringVectorProperty>
<IntVectorProperty name="Refine" command="SetRefine" number_of_elements="1"
    default_values="0">
  <BooleanDomain name="bool" />
  <Documentation>Start from the colour and opacity functions the array has now (the
  last result, or a preset you chose) instead of t2tf's initialization. Refining needs
  far fewer steps than a fresh run.</Documentation>
</IntVectorProperty>
<StringVectorProperty name="LockRanges" label="Lock Ranges" command="SetLockRanges"
    number_of_elements="1" default_values="">
  <Documentation>Data ranges whose transfer function stays as it starts, e.g.
  "120,400; 800,1200": the rest is optimized around them.</Documentation>
</StringVectorProperty>
<StringVectorProperty name="Model" command="SetModel" number_of_elements="1"
    default_values="openai/clip-vit-base-patch32" panel_visibility="advanced">
  <FileListDomain name="files" />
  <Hints><UseDirectoryName /></Hints>
  <Documentation>The CLIP model: a local model folder (config.json, tokenizer.json and
  weights; the button picks a folder), or a Hugging Face repository id, downloaded into
  the Hugging Face cache on first use (`t2tf model list` shows the cached ones; without
  network, `t2tf model fetch` elsewhere and copy the cache).</Documentation>
</StringVectorProperty>
<StringVectorProperty name="Tokenizer" command="SetTokenizer" number_of_elements="1"
    default_values="" panel_visibility="advanced">
  <FileListDomain name="files" />
  <Hints><FileChooser extensions="json" file_description="tokenizer.json" /></Hints>
  <Documentation>A tokenizer.json to use instead of the model's own (empty: the
  model's).</Documentation>
</StringVectorProperty>
<IntVectorProperty name="Seed" command="SetSeed" number_of_elements="1" default_values="0"
    panel_visibility="advanced">
  <Documentation>Random seed of the views, backgrounds and negatives: the same seed and
  settings give the same transfer function.</Documentation>
</IntVectorProperty>
<StringVectorProperty name="Array" command="SetInputArrayToProcess" number_of_elements="5"
    element_types="0 0 0 0 2" animateable="0" panel_visibility="advanced">
  <ArrayListDomain name="array_list" attribute_type="Scalars" input_domain_name="input_array">
    <RequiredProperties><Property name="Input" function="Input" /></RequiredProperties>
  </ArrayListDomain>
  <Documentation>The point array the transfer function is for (default: the active
  scalars).</Documentation>
</StringVectorProperty>
<StringVectorProperty name="ReferenceImage" label="Reference Image"
    command="SetReferenceImage" number_of_elements="1" default_values=""
    panel_visibility="advanced">
  <FileListDomain name="files" />
  <Hints><FileChooser extensions="png" file_description="PNG image" /></Hints>
  <Documentation>A PNG picture the renderings should look like, instead of (or with) the
  Prompt.</Documentation>
</StringVectorProperty>
<IntVectorProperty name="ApplyCamera" label="Apply Camera" command="SetApplyCamera"
    number_of_elements="1" default_values="0" panel_visibility="advanced">
  <BooleanDomain name="bool" />
  <Documentation>Also set the view's camera to t2tf's reference view after a run (not
  when a saved result is restored). Off by default: like ParaView's own filters, an Apply
  leaves your camera where it is.</Documentation>
</IntVectorProperty>
<StringVectorProperty name="Result" command="SetResult" number_of_elements="1"
    default_values="" panel_visibility="never">
  <Documentation>The last result (transfer function, unit distance, report) with a digest
  of the input and settings it was made from; saved with the state, so loading the state
  shows it without running t2tf again.</Documentation>
</StringVectorProperty>
"""

# Results each filter keeps in memory, so Undo and Redo of an Apply do not run t2tf again.
_CACHED_RESULTS = 8

# Every setting that changes what t2tf computes: part of the key a stored result must match.
_KEYED = ("_prompt", "_negatives", "_steps", "_views", "_seed", "_model", "_tokenizer",
          "_reference", "_refine", "_locks")


@smproxy.filter(name="TextToTransferFunction", label=TITLE, support_reload=False)
@smhint.xml('<ShowInMenu category="t2tf" />')
@smproperty.xml(PROPERTIES_XML)
class TextToTransferFunction(VTKPythonAlgorithmBase):
    """Optimizes a transfer function for a sentence with t2tf and shows the data with it."""

    def __init__(self):
        VTKPythonAlgorithmBase.__init__(
            self, nInputPorts=1, nOutputPorts=1, outputType="vtkImageData")
        self._prompt = ""
        self._negatives = []
        self._steps = 300
        self._views = 3
        self._seed = 0
        self._model = DEFAULT_MODEL
        self._tokenizer = ""
        self._reference = ""
        self._camera = 0
        self._refine = 0
        self._locks = ""
        self._stored = None  # the Result property, parsed
        self._cache = {}  # settings-and-input key -> result, the last _CACHED_RESULTS runs
        self._last_name = None  # the preset name of the last result shown
        self.result = None
        self.error = None
        self.reused = False  # the result shown was not computed by this update
        self.restored = False  # ... and came from the Result property (a loaded state)

    def FillInputPortInformation(self, port, info):
        # Any data object reaches RequestData, which names the problem in one line; the
        # datatype domain above still offers the filter only for image data in the GUI.
        info.Set(self.INPUT_REQUIRED_DATA_TYPE(), "vtkDataObject")
        return 1

    def SetPrompt(self, value):
        self._prompt = value or ""
        self.Modified()

    def SetNegative(self, value):
        self._negatives.append(value)
        self.Modified()

    def ClearNegatives(self):
        self._negatives = []
        self.Modified()

    def SetSteps(self, value):
        self._steps = int(value)
        self.Modified()

    def SetViews(self, value):
        self._views = int(value)
        self.Modified()

    def SetSeed(self, value):
        self._seed = int(value)
        self.Modified()

    def SetModel(self, value):
        self._model = value or ""
        self.Modified()

    def SetTokenizer(self, value):
        self._tokenizer = value or ""
        self.Modified()

    def SetInputArrayToProcess(self, idx, port, connection, field, name):
        VTKPythonAlgorithmBase.SetInputArrayToProcess(self, idx, port, connection, field, name)
        self.Modified()

    def SetReferenceImage(self, value):
        self._reference = value or ""
        self.Modified()

    def SetRefine(self, value):
        self._refine = int(value)
        self.Modified()

    def SetLockRanges(self, value):
        self._locks = value or ""
        self.Modified()

    def SetApplyCamera(self, value):
        self._camera = int(value)
        self.Modified()

    def GetTimeEstimate(self):
        """The Time Estimate property: the run time of the applied Steps and Views."""
        stored = ((self._stored or {}).get("result") or {}).get("timing")
        timing = _TIMINGS.get(self._model) or stored
        return time_estimate(self._steps, self._views, timing)

    def SetResult(self, value):
        # Not Modified(): the stored result is a cache, not a setting. A state sets it before
        # the first update; the filter itself sets it after each run.
        try:
            self._stored = json.loads(value) if value else None
        except ValueError:
            self._stored = None

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        # t2tf needs the whole volume, not a piece.
        info = inInfo[0].GetInformationObject(0)
        sddp = self.GetExecutive()
        if info.Has(sddp.WHOLE_EXTENT()):
            info.Set(sddp.UPDATE_EXTENT(), info.Get(sddp.WHOLE_EXTENT()), 6)
        return 1

    def _array(self, image):
        info = self.GetInputArrayInformation(0)
        name = info.Get(vtkDataObject.FIELD_NAME()) if info is not None else None
        if name and image.GetPointData().GetArray(name) is not None:
            return name
        scalars = image.GetPointData().GetScalars()
        if scalars is not None and scalars.GetName():
            return scalars.GetName()
        if image.GetPointData().GetNumberOfArrays() > 0:
            return image.GetPointData().GetArrayName(0)
        raise T2tfError("the input has no point array to optimize a transfer function for")

    def RequestData(self, request, inInfo, outInfo):
        self.error = None
        try:
            server, _rank = _on_server()
            if server:
                # On a pvserver the filter passes the data through: the client that loaded
                # this plugin runs t2tf on a bounded proxy of it when the filter updates
                # (_RemoteFilters), and applies the result to this output's display. Ranks
                # running t2tf each on a piece could not reach the client's colour maps.
                vtkDataObject.GetData(outInfo).ShallowCopy(vtkDataObject.GetData(inInfo[0]))
                return 1
            data = vtkDataObject.GetData(inInfo[0])
            if not isinstance(data, vtkImageData):
                raise T2tfError(
                    "the input is a %s, not image data (vtkImageData): resample it first, "
                    "e.g. with Resample To Image" % (data.GetClassName() if data else "nothing"))
            out = vtkImageData.GetData(outInfo)
            out.ShallowCopy(data)
            result = self._result_for(data)
        except T2tfError as e:
            return self._fail(str(e))
        except Exception as e:  # a bug of ours: still one line, not a traceback
            return self._fail("internal error: %s: %s" % (type(e).__name__, e))
        self.result = result
        # A cancelled run still produced a TF (the last finished step's): clear the abort
        # flag so the pipeline keeps this output instead of discarding it.
        self.SetAbortExecute(0)
        self._annotate(out, result)
        try:
            self._show(result)
        except Exception as e:  # the TF is in the output; say why it is not shown
            message("could not apply the result to the display: %s" % e)
        return 1

    def _fail(self, text):
        """One message, the input passed through, and the error kept (pvpython's API raises
        it). RequestData succeeds: after two failed updates in a row ParaView stops asking a
        filter for data, so no later Apply would run t2tf again."""
        self.result = None
        self.error = text
        if text:
            message(text)
        self.SetAbortExecute(0)
        return 1

    def _result_for(self, image):
        """The stored result when it was made from this input and these settings (a loaded
        state), else a new run's, stored."""
        array = self._array(image)
        settings = [getattr(self, k) for k in _KEYED] + [array, _input_key(image, array)]
        settings += self._depends_on(array)
        key = hashlib.sha256(json.dumps(settings).encode()).hexdigest()
        stored = self._stored
        if stored and stored.get("key") == key and stored.get("result"):
            self.reused = self.restored = True
            message("restored the saved result (input and settings unchanged): t2tf not run",
                    False)
            return stored["result"]
        self.restored = False
        cached = self._cache.get(key)
        if cached is not None:
            # The settings and input of an earlier run of this filter, back again (Redo
            # Apply, or Undo of a later Apply): its result, without running t2tf.
            self.reused = True
            message("reused the result of an earlier run with the same input and settings: "
                    "t2tf not run", False)
            self._store({"key": key, "result": cached})
            return cached
        self.reused = False
        previous = (stored or {}).get("result", {}).get("name") or self._last_name
        result = self._run(image, array)
        remember_model(self._model, self._tokenizer)
        result["replaces"] = previous
        if result["interrupted"]:
            # Shown and saved, but never reused as the result of these settings.
            self._store({"key": None, "result": result})
        else:
            self._remember(key, result)
            self._store({"key": key, "result": result})
        return result

    def _depends_on(self, array):
        """What a run reads besides the settings and the input: the Refine start's functions,
        and the reference image's, tokenizer's and local model's files (a Hub id stands for
        its own files)."""
        start = None
        if self._refine:
            proxy = _proxy_of(self)
            try:
                start = current_tf(array, proxy.Input if proxy is not None else None)
            except T2tfError:
                start = None  # the run will say why
        return [start, _file_digest(self._reference), _file_digest(self._tokenizer),
                _folder_digest(self._model)]

    def _remember(self, key, result):
        """Keep the last few results by key (a result is a few kilobytes)."""
        self._cache.pop(key, None)
        self._cache[key] = result
        while len(self._cache) > _CACHED_RESULTS:
            self._cache.pop(next(iter(self._cache)))

    def _store(self, stored):
        """Keep the result in the hidden Result property, which a state saves. Set on the
        server-manager property only (not pushed, not marked for Apply): the algorithm has
        it already."""
        self._stored = stored
        proxy = _proxy_of(self)
        if proxy is not None:
            proxy.SMProxy.GetProperty("Result").SetElement(0, json.dumps(stored))

    def _run(self, image, array):
        module = t2tf_module()
        binary = None if module else find_binary()  # fail early, before writing anything
        if not self._prompt.strip() and not self._reference:
            raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")
        # The panel's domains say at least 1; a typed 0 or -3 still reaches the setter.
        for prop, value in (("Steps", self._steps), ("Views", self._views)):
            if value < 1:
                raise T2tfError("%s must be at least 1 (it is %d)" % (prop, value))
        locks = parse_locks(self._locks)
        progress = Progress(self)
        progress.show()
        # In the GUI: the Abort button works during the run, and closing the window stops it.
        button = _AbortButton()

        def aborted():
            return bool(self.GetAbortExecute()) or button.requested()

        # t2tf's files are read into memory and the folder removed, whatever happens.
        out = tempfile.mkdtemp(prefix=_TEMP_PREFIX)
        try:
            init = None
            if self._refine:
                proxy = _proxy_of(self)
                source = proxy.Input if proxy is not None else None
                init = write_current_tf(array, os.path.join(out, "start.json"), source)
            if module:
                _check_module(module)
                result = optimize_in_process(
                    module, image, array, os.path.join(out, "tf"), self._prompt,
                    self._negatives, self._steps, self._views, self._seed,
                    self._model or None, self._tokenizer or None, self._reference or None,
                    progress=progress, aborted=aborted, init=init, locks=locks)
                volume = None
            else:
                result, volume = self._run_binary(image, array, out, progress, init, locks,
                                                  aborted)
        finally:
            closed = button.closed()
            button.end()
            shutil.rmtree(out, ignore_errors=True)
        self.SetProgressText(TITLE)
        self.UpdateProgress(1.0)
        result["array"] = array
        result["volume"] = volume
        result["timing"] = measured_timing(result["report"], self._views,
                                           time.time() - progress.start)
        if result["timing"]:
            _TIMINGS[self._model] = result["timing"]
        if result["interrupted"]:
            message("%s: kept the transfer function of the last finished step"
                    % ("the main window was closed" if closed else "cancelled"), False)
        return result

    def _run_binary(self, image, array, out, progress, init=None, locks=(), aborted=None):
        """`t2tf optimize` on the upstream file, else on the image written to a .vti."""
        proxy = _proxy_of(self)
        upstream = _upstream_file(proxy, array) if proxy is not None else None
        extra = []
        if upstream:
            volume, extra = upstream
            if volume.lower().endswith(".vti"):
                extra = ["--array", array]
        else:
            volume = os.path.join(out, "input.vti")
            write_vti(image, array, volume)
        result = optimize(
            volume, os.path.join(out, "tf"), self._prompt, self._negatives, self._steps,
            self._views, self._seed, self._model or None, self._tokenizer or None,
            reference_image=self._reference or None, extra=extra, progress=progress,
            aborted=aborted or self.GetAbortExecute, init=init, locks=locks)
        return result, volume

    def _annotate(self, out, result):
        fd = out.GetFieldData()
        for key, value in (("t2tf_report", result["report"]), ("t2tf_preset", result["name"])):
            a = vtkStringArray()
            a.SetName(key)
            a.InsertNextValue(value)
            fd.AddArray(a)

    def _show(self, result):
        proxy = _proxy_of(self)
        if proxy is None:
            return  # no client-side proxy (e.g. a plain VTK pipeline): nothing to show
        register_preset(result, self._last_name or result.get("replaces"))
        self._last_name = result["name"]
        apply_transfer_function(result, result["array"])
        # A result restored from a state keeps the state's own camera.
        camera = bool(self._camera) and not self.restored
        _PENDING[id(self)] = (proxy, result, camera, set())
        _watch_displays()
        _apply_pending()
        # The panel shows the new run's timing (it reads Time Estimate again only after an
        # Apply, which may come before this run's update).
        proxy.SMProxy.UpdatePropertyInformation(proxy.SMProxy.GetProperty("TimeEstimate"))


# ---- remote servers ------------------------------------------------------------------

def text_to_transfer_function(source=None, prompt="", negatives=(), steps=300, views=3, seed=0,
                              model=None, tokenizer=None, array=None, reference_image=None,
                              proxy_size=None, view=None, camera=True, timeout=None, extra=(),
                              refine=False, locks=()):
    """Optimize a TF for `source` (default: the active source) and show it with it.
    `refine` starts from the array's current colour and opacity functions; `locks` are
    (min, max) data ranges kept as they start.

    In a builtin session this creates the TextToTransferFunction filter. Connected to a
    remote server it asks the server for a ResampleToImage proxy of at most `proxy_size`
    points per axis (default 256, or T2TF_PROXY_SIZE), fetches only that, runs t2tf here and
    applies the TF to `source`'s own display (full resolution, on the server). `extra` are
    further `t2tf optimize` flags (remote only), e.g. ["--l1", "0.001"].
    Returns (result, proxy_or_filter). Raises T2tfError with a one-line reason.
    """
    import paraview.simple as pvs
    from paraview import servermanager

    source = source or pvs.GetActiveSource()
    if source is None:
        raise T2tfError("no active source: open a volume first")
    if not (prompt or "").strip() and not reference_image:
        raise T2tfError("the prompt is empty: type what the rendering should show")
    if servermanager.ActiveConnection.IsRemote() or t2tf_module() is None:
        find_binary()  # fail early and clearly (remote runs always use the binary)
    source.UpdatePipeline()
    info = source.GetDataInformation()
    if info.GetDataClassName() not in ("vtkImageData", "vtkUniformGrid", "vtkStructuredPoints"):
        raise T2tfError("the input is a %s, not image data (vtkImageData)" % info.GetDataClassName())
    array = array or _active_array(source)
    if not servermanager.ActiveConnection.IsRemote():
        f = _new_filter()(Input=source, Prompt=prompt, Negatives=list(negatives),
                          Steps=steps, Views=views, Seed=seed, Model=model or DEFAULT_MODEL,
                          Tokenizer=tokenizer or "", ReferenceImage=reference_image or "",
                          Refine=int(bool(refine)), ApplyCamera=int(bool(camera)),
                          LockRanges="; ".join("%r,%r" % (float(a), float(b))
                                               for a, b in locks))
        f.Array = ["POINTS", array]
        f.UpdatePipeline()
        algo = f.GetClientSideObject()
        if algo.result is None:
            raise T2tfError(algo.error or "t2tf gave no result (see the messages above)")
        pvs.Show(f, view)
        return algo.result, f
    result, local = remote_optimize(
        source, array, prompt, negatives, steps, views, seed, model, tokenizer,
        reference_image, proxy_size, extra, timeout, refine, locks)
    register_preset(result)
    view = view or pvs.GetActiveViewOrCreate("RenderView")
    pvs.Show(source, view)
    # The full data's own display: on the server, at full resolution. The TF transfers
    # because t2tf's opacity is per normalized box length (docs/DESIGN.md) and the proxy
    # spans the same box (UseInputBounds).
    apply_to_display(result, source, view, array, camera)
    return result, local


def remote_optimize(source, array, prompt, negatives=(), steps=300, views=3, seed=0,
                    model=None, tokenizer=None, reference_image=None, proxy_size=None,
                    extra=(), timeout=None, refine=False, locks=()):
    """The remote run: a ResampleToImage proxy of `source` (at most `proxy_size` points per
    axis) fetched from the server, t2tf run here on it. In the GUI the run shows on
    ParaView's progress bar, holds the GUI's input as a pipeline update does, and stops at
    its Abort button or when the main window is closed. Returns (result, proxy image)."""
    info = source.GetDataInformation()
    size = proxy_size_setting(proxy_size)
    dims = _proxy_dims(info.GetExtent(), size)
    gui = _GuiProgress()
    progress = Progress(gui=gui)
    button = _AbortButton()
    out = tempfile.mkdtemp(prefix=_TEMP_PREFIX)
    try:
        progress.show()
        local, fetched = fetch_proxy(source, dims)
        volume = os.path.join(out, "proxy.vti")
        write_vti(local, array, volume)
        init = (write_current_tf(array, os.path.join(out, "start.json"), source)
                if refine else None)
        result = optimize(volume, os.path.join(out, "tf"), prompt, negatives, steps, views, seed,
                          model, tokenizer, array=array, reference_image=reference_image,
                          extra=extra, progress=progress, aborted=button.requested,
                          timeout=timeout, init=init, locks=locks)
    finally:
        button.end()
        gui.end()
        shutil.rmtree(out, ignore_errors=True)
    if result["interrupted"]:
        message("cancelled: kept the transfer function of the last finished step", False)
    result.update(array=array, volume=None, proxy_dims=dims, fetched_points=fetched)
    return result, local


class _RemoteFilters:
    """The filter in a client-server session, on the client. The filter's algorithm runs on
    the server, where it passes the data through; the client watches its filters and, when
    one updates with settings or data it has not run for (an Apply), runs t2tf here on a
    bounded proxy of the filter's input (remote_optimize: progress bar, Abort, the GUI held
    during the run) and applies the transfer function to the filter's own display, rendered
    on the server at full resolution. Once per Apply: a repeated update with the same
    settings and data (a render, a view's update) runs nothing, and no update starts a run
    while one runs. Watched once per process, whichever copy of this module loads first."""

    @staticmethod
    def state():
        _runs()  # makes the module every copy of this one shares
        shared = sys.modules["_t2tf_plugin_runs"]
        if not hasattr(shared, "remote"):
            shared.remote = {"sessions": [], "filters": set(), "keys": {}, "running": False,
                             "results": {}}
        return shared.remote

    @classmethod
    def watch(cls):
        """In a client process: follow the sessions, so that filters made in a remote one
        are watched."""
        from paraview import servermanager

        if _on_server()[0]:
            return
        pxm = servermanager.vtkSMProxyManager.GetProxyManager()
        state = cls.state()
        if pxm is None or state.get("watching"):
            return
        state["watching"] = True
        pxm.AddObserver(servermanager.vtkSMProxyManager.ActiveSessionChanged,
                        lambda *_: cls.on_session())
        cls.on_session()

    @classmethod
    def on_session(cls):
        from paraview import servermanager

        spxm = servermanager.vtkSMProxyManager.GetProxyManager().GetActiveSessionProxyManager()
        state = cls.state()
        if spxm is None or any(s is spxm for s in state["sessions"]):
            return
        state["sessions"].append(spxm)
        spxm.AddObserver("RegisterEvent", lambda *_: cls.on_register(spxm))

    @classmethod
    def on_register(cls, spxm):
        """Watch the session's TextToTransferFunction filters not watched yet (a register
        event does not say which proxy it is for in Python: the sources are few)."""
        state = cls.state()
        session = spxm.GetSession()
        if session is None or not session.IsA("vtkSMSessionClient"):
            return  # a builtin session: the filter runs itself
        sources = spxm.GetNumberOfProxies("sources")
        for i in range(sources):
            proxy = spxm.GetProxy("sources", spxm.GetProxyName("sources", i))
            if proxy is None or proxy.GetXMLName() != "TextToTransferFunction":
                continue
            gid = proxy.GetGlobalIDAsString()
            if gid in state["filters"]:
                continue
            state["filters"].add(gid)
            proxy.AddObserver("UpdateDataEvent", lambda obj, _e: cls.on_update(obj))

    @classmethod
    def on_update(cls, smproxy):
        from paraview import servermanager

        state = cls.state()
        if state["running"]:
            return
        proxy = servermanager._getPyProxy(smproxy)
        try:
            key = cls.key(proxy)
        except Exception as e:  # the input went away: nothing to run on
            message("internal error: %s: %s" % (type(e).__name__, e))
            return
        gid = smproxy.GetGlobalIDAsString()
        if state["keys"].get(gid) == key:
            return
        state["keys"][gid] = key
        state["running"] = True
        try:
            cls.run(proxy, gid)
        except T2tfError as e:
            message(str(e))
        except Exception as e:  # a bug of ours: still one line, not a traceback
            message("internal error: %s: %s" % (type(e).__name__, e))
        finally:
            state["running"] = False

    @staticmethod
    def key(proxy):
        """The settings and the input's data as the server describes them."""
        names = ("Prompt", "Negatives", "Steps", "Views", "Seed", "Model", "Tokenizer",
                 "ReferenceImage", "Refine", "LockRanges", "Array")
        values = [[str(v) for v in proxy.GetProperty(n)] for n in names]
        source = proxy.Input
        info = source.GetDataInformation()
        values += [source.GetGlobalIDAsString(), info.GetDataClassName(),
                   list(info.GetExtent()), list(info.GetBounds()), info.GetNumberOfPoints(),
                   sorted((a.GetName(), list(a.GetRange())) for a in source.PointData)]
        return json.dumps(values, default=str)

    @classmethod
    def run(cls, proxy, gid):
        import paraview.simple as pvs

        source = proxy.Input
        info = source.GetDataInformation()
        if info.GetDataClassName() not in ("vtkImageData", "vtkUniformGrid",
                                           "vtkStructuredPoints"):
            raise T2tfError("the input is a %s, not image data (vtkImageData): resample it "
                            "first, e.g. with Resample To Image" % info.GetDataClassName())
        prompt = proxy.Prompt or ""
        reference = proxy.ReferenceImage or None
        if not prompt.strip() and not reference:
            raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)")
        for name in ("Steps", "Views"):
            value = int(getattr(proxy, name))
            if value < 1:
                raise T2tfError("%s must be at least 1 (it is %d)" % (name, value))
        array = (list(proxy.Array) + ["", ""])[1] or _active_array(source)
        find_binary()
        result, _local = remote_optimize(
            source, array, prompt, [n for n in proxy.Negatives], int(proxy.Steps),
            int(proxy.Views), int(proxy.Seed), proxy.Model or None, proxy.Tokenizer or None,
            reference, None, (), None, bool(proxy.Refine), parse_locks(proxy.LockRanges))
        remember_model(proxy.Model, proxy.Tokenizer)
        state = cls.state()
        register_preset(result, state["results"].get(gid))
        state["results"][gid] = result["name"]
        # The filter's display (the full data, on the server), as it appears.
        _PENDING[gid] = (proxy, result, bool(proxy.ApplyCamera), set())
        _watch_displays()
        _apply_pending()
        for view in pvs.GetViews():
            view.StillRender()


def _new_filter():
    """paraview.simple's constructor of the filter (named after its label:
    TextToTransferFunction). LoadPlugin(path, ns=globals()) puts it into the caller's
    namespace only, so it is made here from the proxy definitions when simple lacks it."""
    import paraview.simple as pvs
    from paraview import servermanager

    make = getattr(pvs, "TextToTransferFunction", None)
    if make is None:
        filters = servermanager.ActiveConnection.ProxiesNS.filters
        if not hasattr(filters, "TextToTransferFunction"):
            raise T2tfError("the TextToTransferFunction filter is not loaded: "
                            "LoadPlugin(path to t2tf_plugin.py) first")
        make = pvs._create_func("TextToTransferFunction", filters)
    return make


def proxy_size_setting(proxy_size=None):
    """Points per axis of the remote proxy: the argument, else T2TF_PROXY_SIZE, else 256."""
    raw = proxy_size if proxy_size is not None else os.environ.get("T2TF_PROXY_SIZE")
    if raw is None or str(raw).strip() == "":
        return PROXY_SIZE
    try:
        size = int(raw)
    except ValueError:
        raise T2tfError("the proxy size must be a whole number of points per axis, not %r" % raw)
    if size < 2:
        raise T2tfError("the proxy size must be at least 2 points per axis, not %d" % size)
    return size


def fetch_proxy(source, dims):
    """Resample `source` on the server with ParaView's ResampleToImage to `dims` points over
    its own bounds and bring only that to the client. Returns (image, points fetched).

    Under MPI the resampled image is distributed: rank r holds a piece whose extent shares a
    boundary plane with its neighbour's. servermanager.Fetch with no rank would merge the
    pieces with vtkAppendFilter (an unstructured grid), so each rank's piece is fetched on its
    own (Fetch(proxy, rank)) and the pieces are put back into one image by extent here
    (vtkImageAppend with PreserveExtents)."""
    import paraview.simple as pvs
    from paraview import servermanager
    from vtkmodules.vtkFiltersCore import vtkImageAppend

    resample = pvs.ResampleToImage(Input=source)
    try:
        resample.UseInputBounds = 1
        resample.SamplingDimensions = list(dims)
        resample.UpdatePipeline()
        ranks = max(1, servermanager.ActiveConnection.GetNumberOfDataPartitions())
        pieces = []
        for rank in range(ranks):
            # Always by rank: with no rank Fetch merges through vtkAppendFilter, which turns
            # image data into an unstructured grid even on one rank.
            piece = servermanager.Fetch(resample, rank)
            if piece is not None and piece.GetNumberOfPoints() > 0:
                pieces.append(piece)
    finally:
        pvs.Delete(resample)
    if not pieces:
        raise T2tfError("the server's ResampleToImage proxy of the data is empty")
    fetched = sum(p.GetNumberOfPoints() for p in pieces)
    if len(pieces) == 1:
        image = pieces[0]
    else:
        append = vtkImageAppend()
        append.PreserveExtentsOn()
        for piece in pieces:
            append.AddInputData(piece)
        append.Update()
        image = append.GetOutput()
    got = list(image.GetDimensions())
    if got != list(dims):
        raise T2tfError("the server's proxy has %s points per axis, expected %s" % (got, list(dims)))
    return image, fetched


def _active_array(source):
    info = source.GetPointDataInformation()
    if info.GetNumberOfArrays() == 0:
        raise T2tfError("the input has no point array to optimize a transfer function for")
    try:
        active = source.PointData.keys()
    except AttributeError:
        active = []
    return active[0] if active else info.GetArray(0).GetName()


def _proxy_dims(extent, size):
    """Points per axis of the proxy: the data's own, scaled down so none exceeds `size`."""
    dims = [extent[2 * i + 1] - extent[2 * i] + 1 for i in range(3)]
    scale = min(1.0, float(size) / max(dims))
    return [max(2, min(size, int(round(d * scale)))) for d in dims]


try:
    _RemoteFilters.watch()
except Exception as e:  # the filter still works in a builtin session
    message("client-server sessions are not watched: %s" % e, False)
