"""The examples in examples/python run and make their pictures (the pvpython one is in
test_paraview.py)."""
import os
import subprocess
import sys

import numpy as np

from conftest import REPO, read_png, require, require_module, run_in_group, xvfb_run

EXAMPLES = REPO / "examples" / "python"


def test_the_notebook_script_runs(tmp_path):
    subprocess.run([sys.executable, str(EXAMPLES / "notebook.py")], cwd=tmp_path, check=True,
                   capture_output=True, timeout=300)
    assert (tmp_path / "notebook-tf" / "notebook-tf.json").is_file()
    assert (tmp_path / "notebook-tf" / "report.json").is_file()


def test_pyvista_renders_the_optimized_tf(tmp_path):
    require_module("pyvista")
    # VTK's off-screen window needs an X server: a virtual one where there is none.
    command = [sys.executable, str(EXAMPLES / "pyvista_volume.py"), "--steps", "5",
               "--out", "view.png"]
    if not os.environ.get("DISPLAY"):
        require("xvfb-run")
        command = xvfb_run() + command
    out = run_in_group(command, cwd=tmp_path, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    picture = read_png(tmp_path / "view.png")
    assert picture.shape == (512, 512, 3)
    # The background is gray 0.3; the volume covers part of the view in other colours.
    background = np.all(np.abs(picture.astype(int) - 77) <= 1, axis=2)
    assert 0.05 < 1 - background.mean() < 0.95, "no volume in the picture"
