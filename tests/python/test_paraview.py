"""t2tf in ParaView's own Python (pvpython under xvfb): `import t2tf`, the plugin's filter
running in-process on a source with no file (a Wavelet) and cancelled through ParaView's
abort flag, and the pvpython example. Skipped without pvpython and xvfb-run, unless
T2TF_REQUIRE_PARAVIEW=1 (CI).

pvpython sees only the installed `t2tf` package (a folder linking to it on PYTHONPATH), so
it runs with ParaView's own NumPy, as after `pip install --user .` for that Python.
"""
import json
import os
import subprocess
from pathlib import Path

import pytest

import t2tf
from conftest import MODEL, NEGHIP, REPO, TOKENIZER, require, run_in_group, xvfb_run

DRIVER = REPO / "tests" / "paraview_plugin" / "driver.py"
PLUGIN = REPO / "paraview" / "t2tf_plugin.py"


@pytest.fixture(scope="module")
def pv_env(tmp_path_factory):
    """pvpython's environment: paraview/compat and the installed t2tf package only."""
    require("pvpython")
    require("xvfb-run")
    only = tmp_path_factory.mktemp("pythonpath")
    (only / "t2tf").symlink_to(Path(t2tf.__file__).parent)
    env = dict(os.environ)
    env.pop("T2TF_BIN", None)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "paraview" / "compat"), str(only)])
    return env


def pvpython(args, env, cwd):
    # A display lost to another X server starting at the same moment is retried.
    for _ in range(3):
        out = run_in_group(xvfb_run() + ["pvpython", "--dr"] + [str(a) for a in args],
                           env=env, cwd=cwd, timeout=600)
        if out.returncode == 0 or "bad X server connection" not in out.stderr:
            break
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout + out.stderr


def run_driver(mode, env, tmp_path):
    result = tmp_path / (mode + ".json")
    text = pvpython([DRIVER, PLUGIN, mode, NEGHIP, MODEL, TOKENIZER, result,
                     tmp_path / (mode + ".png"), 96], env, tmp_path)
    assert "in-process" in text and "t2tf binary" not in text, text
    return json.loads(result.read_text()), text


def test_pvpython_imports_t2tf(pv_env, tmp_path):
    script = tmp_path / "version.py"
    script.write_text("import numpy, t2tf\n"
                      "print('t2tf', t2tf.__version__, 'numpy', numpy.__version__)\n")
    assert ("t2tf " + t2tf.__version__) in pvpython([script], pv_env, tmp_path)


def test_the_plugin_runs_in_process_on_a_source_without_a_file(pv_env, tmp_path):
    res, _ = run_driver("nofile", pv_env, tmp_path)
    preset = res["preset"]
    assert res["representation"] == "Volume" and res["color_array"] == "RTData"
    assert res["rgb"] == pytest.approx(preset["RGBPoints"], rel=1e-9)
    assert res["points"] == pytest.approx(preset["Points"], rel=1e-9)
    assert res["unit_distance"] == preset["t2tfScalarOpacityUnitDistance"]
    assert res["has_preset"] and not res["interrupted"]
    assert res["volume"] is None, "the in-process run wrote the input to a file"
    for key, value in res["result_camera"].items():  # the run's camera is the view's
        assert res["camera"][key] == pytest.approx(value), key
    report = json.loads(res["report"])
    assert report["volume"]["path"] == "(in memory)" and report["steps_run"] == 5


def test_the_abort_flag_stops_an_in_process_run(pv_env, tmp_path):
    res, text = run_driver("cancel", pv_env, tmp_path)
    assert res["interrupted"], text
    report = json.loads(res["report"])
    assert 1 <= report["steps_run"] < 2000
    assert "cancelled: kept the transfer function" in text


def test_the_pvpython_example_runs(pv_env, tmp_path):
    text = pvpython([REPO / "examples" / "python" / "pvpython_optimize.py", "--steps", "3"],
                    pv_env, tmp_path)
    assert "wrote pvpython_optimize.png" in text
    assert (tmp_path / "pvpython_optimize.png").is_file()
