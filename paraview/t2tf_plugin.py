"""ParaView plugin: "Text To Transfer Function" (XML name TextToTransferFunction).

Load this file with Tools > Manage Plugins > Load New, with PV_PLUGIN_PATH naming its folder,
or from pvpython with LoadPlugin(path, ns=globals()); see README.md beside it. The plugin is
the package t2tf_paraview/ in this folder (its __init__ maps its modules): ParaView's loader
executes this file as a module of its own (once per LoadPlugin, in the client and in each
pvserver rank), so it only makes that package importable, imports it (once per process,
whatever runs this file again) and names the filter, which ParaView finds here. A folder on
PV_PLUGIN_PATH is scanned for .py files, not sub-folders, so the package's modules are never
taken for plugins.

In Python, `import t2tf_plugin` (this folder on sys.path) gives the API:
text_to_transfer_function, cancel, remove_presets, apply_to_display, parse_locks, T2tfError.
"""
import os
import sys

_here = os.path.dirname(os.path.abspath(__file__))
if not os.path.isdir(os.path.join(_here, "t2tf_paraview")):
    raise ImportError("t2tf_plugin.py needs the folder t2tf_paraview beside it, in " + _here)
if _here not in sys.path:
    sys.path.insert(0, _here)
# The filter's class: ParaView's loader looks for it in this module.
from t2tf_paraview import TextToTransferFunction  # noqa: E402
from t2tf_paraview import (T2tfError, __version__, apply_camera, apply_to_display,  # noqa: E402
                           apply_transfer_function, cancel, parse_locks, register_preset,
                           remove_presets, start, text_to_transfer_function)

_package = sys.modules["t2tf_paraview"].__file__
if os.path.realpath(os.path.dirname(os.path.dirname(_package))) != os.path.realpath(_here):
    # Another copy of the plugin was loaded first in this process: that one runs.
    from t2tf_paraview.errors import say

    say("t2tf_plugin.py of %s loaded, but this process already runs the package %s"
        % (_here, _package), False)
start()

__all__ = ["TextToTransferFunction", "T2tfError", "__version__", "apply_camera",
           "apply_to_display", "apply_transfer_function", "cancel", "parse_locks",
           "register_preset", "remove_presets", "text_to_transfer_function"]
