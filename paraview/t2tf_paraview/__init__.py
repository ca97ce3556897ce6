"""The t2tf ParaView plugin, a package that paraview/t2tf_plugin.py (the file ParaView loads)
imports, so that the filter's parts can be read one at a time:

- proxy: the filter, its properties (decorators on the setters) and RequestData, which only
  computes; watch: what the client does after the filter updates (shows the result; runs
  t2tf for a filter on a pvserver); api: text_to_transfer_function.
- run: one t2tf run (Request, Volume, cancel) with two back ends: binary (`t2tf optimize
  --progress json` as a child process) and in_process (the t2tf Python module); progress:
  the progress text; results: a run's files read into memory; timing: the Time Estimate;
  inputs: what t2tf reads and the digests a reused result must match; temporaries: the runs'
  folders; remote: the bounded proxy of data on a pvserver.
- display: the TF on displays and the camera; presets: the preset manager and Choose
  Preset's groups; gui: the GUI during a run; native: every ctypes call (Qt and ParaView's
  C++ functions, the Windows process check), each feature off when its symbol is missing.
- errors: T2tfError and the hints that name ParaView's properties.

Imported once per process (whichever copy of t2tf_plugin.py runs first), so the runs in
progress, the binary found and the watched sessions are one for the whole process.
"""
# The t2tf release this plugin belongs to: a binary or module of another is refused.
__version__ = "0.1.0"

from .errors import TITLE, T2tfError  # noqa: E402 (modules below read __version__)
from .run import cancel, parse_locks  # noqa: E402
from .display import apply_camera, apply_to_display, apply_transfer_function  # noqa: E402
from .presets import register as register_preset, remove_all as remove_presets  # noqa: E402
from .api import text_to_transfer_function  # noqa: E402
from .proxy import TextToTransferFunction  # noqa: E402
from . import temporaries, watch  # noqa: E402

__all__ = ["__version__", "TITLE", "T2tfError", "cancel", "parse_locks", "apply_camera",
           "apply_to_display", "apply_transfer_function", "register_preset", "remove_presets",
           "text_to_transfer_function", "TextToTransferFunction", "start"]

_started = False


def start():
    """What loading the plugin does in this process, once: remove the temporary folders of
    runs whose ParaView was killed, and (in a client) watch the sessions' filters."""
    global _started
    if _started:
        return
    _started = True
    temporaries.remove_stale()
    try:
        watch.start()
    except Exception as e:  # the filter still runs; only showing its result would not
        from .errors import say

        say("the filters' results cannot be shown: %s" % e, False)
