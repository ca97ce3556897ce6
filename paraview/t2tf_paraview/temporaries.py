"""The temporary folders t2tf writes into.

Each run writes into a folder `t2tf-plugin-PID-*` that is removed when the run ends, also
after a failure or a cancel: what the display needs is read into memory first. A ParaView
killed mid-run leaves its folder behind; the next start of the plugin removes the folders of
processes that are gone.
"""
import os
import re
import shutil
import tempfile

from . import native

_PREFIX = "t2tf-plugin-%d-" % os.getpid()


def make():
    """A new folder for one run."""
    return tempfile.mkdtemp(prefix=_PREFIX)


def remove(path):
    shutil.rmtree(path, ignore_errors=True)


def remove_stale():
    """Remove the folders of runs whose process is gone; returns their names."""
    removed = []
    root = tempfile.gettempdir()
    try:
        names = os.listdir(root)
    except OSError:
        return removed
    for name in names:
        m = re.match(r"t2tf-plugin-(\d+)-", name)
        if not m or int(m.group(1)) == os.getpid() or native.process_alive(int(m.group(1))):
            continue
        path = os.path.join(root, name)
        if os.path.isdir(path) and not os.path.islink(path):
            remove(path)
            removed.append(name)
    return removed
