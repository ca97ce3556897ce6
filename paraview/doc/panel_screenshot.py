"""Startup script for the ParaView GUI that sets up what paraview/doc/properties_panel.png
shows: the plugin loaded, a volume read, the Text To Transfer Function filter applied and
selected, so its property panel is on screen. Run by take_panel_screenshot.sh, which grabs
the virtual screen. Paths come from the environment: T2TF_PLUGIN, T2TF_VOLUME (a 64³ uint8
.raw), T2TF_MODEL, T2TF_TOKENIZER (T2TF_BIN names the t2tf binary)."""
import os
import sys

import paraview.simple as pvs

env = os.environ
if env.get("T2TF_GUI_INFO"):
    # What tells the GUI's Python from pvpython (for t2tf_macro.in_gui).
    from paraview import servermanager

    with open(env["T2TF_GUI_INFO"], "w") as f:
        f.write("argv %r\nprocess type %s\n" % (
            sys.argv, servermanager.vtkProcessModule.GetProcessModule().GetProcessType()))
        f.write("\n".join(sorted(sys.modules)))
pvs.LoadPlugin(env["T2TF_PLUGIN"], ns=globals())
reader = pvs.ImageReader(FileNames=[env["T2TF_VOLUME"]])
reader.DataScalarType = "unsigned char"
reader.DataExtent = [0, 63, 0, 63, 0, 63]
reader.ScalarArrayName = "ImageFile"
reader.UpdatePipeline()  # so the Array property's list knows ImageFile
f = TextToTransferFunction(Input=reader, Prompt="a protein molecule", Steps=5, Views=1, Seed=3,
                           Model=env["T2TF_MODEL"], Tokenizer=env["T2TF_TOKENIZER"])
pvs.Show(f)
pvs.SetActiveSource(f)
pvs.Render()
