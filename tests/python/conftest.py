"""Shared paths and helpers of the Python tests (run after `pip install .`, see TESTING.md).

Every optimization uses the tiny test model tests/fixtures/clip/quick_gelu with the CLIP
tokenizer in ../shared, so runs take well under a second.
"""
import importlib
import importlib.util
import os
import shutil
import subprocess
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
VOLUMES = SHARED / "data" / "volumes"
NEGHIP = VOLUMES / "neghip_64x64x64_uint8.raw"
HEADSQ = VOLUMES / "headsq_64x64x93_uint16.raw"
MODEL = REPO / "tests" / "fixtures" / "clip" / "quick_gelu"
TOKENIZER = SHARED / "data" / "clip" / "tokenizer.json"
PRESET = REPO / "tests" / "fixtures" / "paraview" / "paraview_written_preset.json"

# A few cheap steps with the tiny model: what the tests of the optimizer run.
QUICK = dict(model=str(MODEL), tokenizer=str(TOKENIZER), steps=3, views=1, seed=3,
             negatives_per_step=8, threads=2)


@pytest.fixture(autouse=True, scope="session")
def caption_cache(tmp_path_factory):
    """Caption embeddings cached in a folder of the session's, not the user's cache (the
    CLI run by the tests inherits the variable)."""
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("cache"))


@pytest.fixture(scope="session")
def neghip():
    """The neghip volume as a C-ordered uint8 array indexed [z, y, x]."""
    return np.fromfile(NEGHIP, dtype=np.uint8).reshape(64, 64, 64)


def t2tf_command():
    """The `t2tf` command the wheel installed: beside this Python (a venv need not be
    activated), else on PATH."""
    beside = Path(sys.executable).parent / "t2tf"
    exe = str(beside) if beside.is_file() else shutil.which("t2tf")
    if exe is None:
        pytest.fail("the t2tf command is not on PATH: install the package (pip install .)")
    return exe


def xvfb_run():
    """`xvfb-run` searching for a free display from a number drawn per call: from the default
    99 every `xvfb-run -a` probes the same numbers, and two starting together can take the same
    one ("bad X server connection")."""
    import random
    return ["xvfb-run", "-a", "-n", str(random.randrange(200, 30200))]


def run_in_group(command, timeout, **kwargs):
    """`subprocess.run(command, capture_output=True, text=True)` in a process group of its own,
    which is stopped afterwards whatever happens: a timeout kills only the direct child in
    `subprocess.run`, and `xvfb-run` killed that way leaves its Xvfb (and pvpython) running."""
    import signal
    if os.name != "posix":
        # No process groups to stop elsewhere (these commands need xvfb-run, a Unix tool).
        return subprocess.run(command, capture_output=True, text=True, timeout=timeout, **kwargs)
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)

    def stop_group():
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(proc.pid, sig)
            except (ProcessLookupError, PermissionError):
                return
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass

    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        stop_group()
        proc.communicate()
        raise
    stop_group()
    return subprocess.CompletedProcess(command, proc.returncode, out, err)


def require(tool, env="T2TF_REQUIRE_PARAVIEW"):
    """Skip unless `tool` is on PATH; fail instead when `env` is 1 (CI)."""
    if shutil.which(tool) is None:
        missing(tool, env)


def require_module(name, env="T2TF_REQUIRE_PYVISTA"):
    """The module `name`: skip without it; fail instead when `env` is 1 (CI)."""
    if importlib.util.find_spec(name.split(".")[0]) is None:
        missing(name, env)
    return importlib.import_module(name)


def missing(what, env):
    if os.environ.get(env) == "1":
        pytest.fail("%s not found but %s=1" % (what, env))
    pytest.skip("%s not found" % what)


def read_png(path):
    """An 8-bit RGB PNG (as t2tf writes them: no interlace, no palette) as uint8 (h, w, 3)."""
    data = Path(path).read_bytes()
    pos, idat = 8, b""
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            assert (depth, colour) == (8, 2), "not 8-bit RGB"
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw = zlib.decompress(idat)
    stride = 3 * width
    out = np.zeros((height, stride), dtype=np.int32)
    for y in range(height):
        kind = raw[y * (stride + 1)]
        row = np.frombuffer(raw, np.uint8, stride, y * (stride + 1) + 1).astype(np.int32)
        out[y] = _unfilter(kind, row, out[y - 1] if y else np.zeros(stride, np.int32))
    return out.astype(np.uint8).reshape(height, width, 3)


def _unfilter(kind, row, up):
    """One PNG row undone from its filter (types 0 to 4), 3 bytes per pixel."""
    if kind == 0:
        return row
    if kind == 2:
        return (row + up) & 255
    out = np.zeros_like(row)
    for i in range(len(row)):
        left = out[i - 3] if i >= 3 else 0
        corner = up[i - 3] if i >= 3 else 0
        if kind == 1:
            pred = left
        elif kind == 3:
            pred = (left + up[i]) // 2
        else:
            p = left + up[i] - corner
            pa, pb, pc = abs(p - left), abs(p - up[i]), abs(p - corner)
            pred = left if pa <= pb and pa <= pc else (up[i] if pb <= pc else corner)
        out[i] = (row[i] + pred) & 255
    return out
