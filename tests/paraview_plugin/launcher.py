"""pvpython script for tests/paraview/paraview_plugin.rs, run through paraview/bin/t2tf-paraview
without LoadPlugin: writes which t2tf plugins ParaView's plugin tracker lists (name, loaded),
whether the TextToTransferFunction filter is defined, and the environment the launcher set,
as JSON (argv: result.json)."""
import json
import os
import sys

import paraview.simple  # noqa: F401 (makes the builtin session the plugins load into)
from paraview import servermanager
from paraview.modules.vtkRemotingCore import vtkPVPluginTracker

tracker = vtkPVPluginTracker.GetInstance()
definitions = servermanager.ActiveConnection.Session.GetProxyDefinitionManager()
res = {
    "plugins": [[tracker.GetPluginName(i), bool(tracker.GetPluginLoaded(i)),
                 tracker.GetPluginFileName(i)]
                for i in range(tracker.GetNumberOfPlugins())
                if tracker.GetPluginFileName(i).endswith(".py")],
    "filter": definitions.GetProxyDefinition("filters", "TextToTransferFunction") is not None,
    "PV_PLUGIN_PATH": os.environ.get("PV_PLUGIN_PATH"),
    "PYTHONPATH": os.environ.get("PYTHONPATH"),
}
try:  # a module of the environment `--venv` named, when the test gave one
    import t2tf_launcher_probe
    res["venv_module"] = t2tf_launcher_probe.__file__
except ImportError:
    res["venv_module"] = None
with open(sys.argv[1], "w") as fh:
    json.dump(res, fh)
