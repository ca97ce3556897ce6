"""The binary back end: `t2tf optimize --progress json` as a child process.

The binary is T2TF_BIN, else the first `t2tf` on PATH, else one beside t2tf_plugin.py; the
one found is kept for the session (a t2tf put on PATH later does not take over), said once
with its version, and refused when its version is not the plugin's. t2tf reads the input's
own file when it has one (a .vti, or a raw file with its layout as flags), else the image
written to a .vti; a time series (All Time Steps) as one .vti per step and a NAME.vti.series
file with their times. Progress comes as JSON lines on stderr; SIGINT makes t2tf finish the
current step and write that step's TF.
"""
import json
import os
import queue
import shutil
import signal
import subprocess
import threading

from . import __version__, errors, inputs, results
from .errors import T2tfError, say

# Where t2tf_plugin.py is: a t2tf copied beside it is found there.
_PLUGIN_FOLDER = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_pinned = None  # the binary found on PATH or beside the plugin, kept for the session
_checked = set()  # (path, size, mtime) of binaries whose version was checked


def find():
    """The t2tf executable, of this plugin's version."""
    global _pinned
    env = os.environ.get("T2TF_BIN")
    if env:
        if os.path.isfile(env) and os.access(env, os.X_OK):
            return _checked_version(env)
        raise T2tfError("T2TF_BIN=%s is not an executable file" % env)
    if _pinned and os.path.isfile(_pinned):
        return _checked_version(_pinned)
    found = shutil.which("t2tf")
    for name in ("t2tf", "t2tf.exe"):
        beside = os.path.join(_PLUGIN_FOLDER, name)
        if not found and os.path.isfile(beside) and os.access(beside, os.X_OK):
            found = beside
    if not found:
        raise T2tfError("the t2tf binary was not found: set T2TF_BIN, put t2tf on PATH, or "
                        "copy it beside " + _PLUGIN_FOLDER)
    _pinned = os.path.abspath(found)
    return _checked_version(_pinned)


def _checked_version(path):
    """`path`, once its version is this plugin's (asked once per file and change)."""
    st = os.stat(path)
    key = (os.path.abspath(path), st.st_size, st.st_mtime_ns)
    if key in _checked:
        return path
    try:
        said = subprocess.run([path, "--version"], capture_output=True, text=True,
                              timeout=60).stdout.split()
    except (OSError, subprocess.SubprocessError) as e:
        raise T2tfError("the t2tf binary %s does not run: %s" % (path, e))
    version = said[-1] if len(said) == 2 and said[0] == "t2tf" else " ".join(said) or "unknown"
    if version != __version__:
        raise T2tfError(
            "the t2tf binary %s is version %s, but this plugin is %s: install t2tf %s (from "
            "the same release as this plugin), or set T2TF_BIN to it"
            % (path, version, __version__, __version__))
    say("using the t2tf binary %s (t2tf %s)" % (path, version), False)
    _checked.add(key)
    return path


class Backend:
    """Runs the binary at `path`."""

    def __init__(self, path):
        self.path = path

    def arguments(self, request, volume, folder, init):
        """The command line, and the file t2tf reads (written into `folder` when the input
        has no file of its own)."""
        if volume.series:
            path, flags = inputs.write_series(volume.series, volume.array, folder), []
        elif volume.file:
            path, flags = volume.file
        else:
            path, flags = os.path.join(folder, "input.vti"), []
            inputs.write_vti(volume.image_data(), volume.array, path)
        if path.lower().endswith((".vti", ".vti.series")):
            flags = flags + ["--array", volume.array]
        args = [self.path, "optimize", path, "--out", os.path.join(folder, "tf"),
                "--progress", "json"]
        if request.prompt.strip():
            args += ["--prompt", request.prompt]
        for n in request.negatives:
            args += ["--negative", n]
        args += ["--steps", str(request.steps), "--views", str(request.views),
                 "--seed", str(request.seed)]
        for flag, value in (("--model", request.model), ("--tokenizer", request.tokenizer),
                            ("--reference-image", request.reference_image), ("--init", init)):
            if value:
                args += [flag, value]
        args += ["--lock=%r,%r" % lock for lock in request.locks]
        return args + flags + request.extra, path

    def run(self, request, volume, folder, init, progress, aborted):
        args, path = self.arguments(request, volume, folder, init)
        done = _Child(args).run(progress, aborted)
        result = results.read(done["out"], done.get("files", []), done.get("interrupted"),
                              request.prompt, request.reference_image)
        result["volume"] = path
        return result


class _Child:
    """One `t2tf optimize --progress json` process: its events, its stop, its end."""

    def __init__(self, args):
        self.args = args
        self.lines = queue.Queue()
        self.done = None
        self.error = None  # t2tf's error event: message, kind, option
        self.tail = []  # the last lines that were not events, for a message

    def _read(self):
        for line in self.proc.stderr:
            self.lines.put(line)
        self.lines.put(None)

    def run(self, progress, aborted):
        """Run to the end, showing steps on `progress`; SIGINT once `aborted()`. Returns the
        done event."""
        self.proc = subprocess.Popen(self.args, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True)
        # A thread reads stderr so that this one can process the GUI's events meanwhile.
        threading.Thread(target=self._read, daemon=True).start()
        stopping = False
        while True:
            if not stopping and aborted():
                stopping = True
                if self.proc.poll() is None:
                    self.proc.send_signal(signal.SIGINT)
            try:
                line = self.lines.get(timeout=0.05)
            except queue.Empty:
                progress.tick()
                continue
            if line is None:
                break
            self._line(line, progress)
        self.proc.wait()
        # A run stopped by SIGINT exits with 128 + the signal after writing the last finished
        # step's result; its done event says so.
        stopped = self.done is not None and self.done.get("interrupted")
        if self.done is not None and (self.proc.returncode == 0 or stopped):
            return self.done
        if self.error is not None:
            raise errors.from_t2tf(self.error.get("message", ""), self.error.get("kind"),
                                   self.error.get("option"))
        raise T2tfError("t2tf failed (exit status %s): %s"
                        % (self.proc.returncode, " | ".join(self.tail[-3:]) or "no output"))

    def _line(self, line, progress):
        line = line.strip()
        try:
            event = json.loads(line)
        except ValueError:
            event = None
        if not isinstance(event, dict):
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
            self.error = event
