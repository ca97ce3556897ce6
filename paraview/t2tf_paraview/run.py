"""One t2tf run, whichever way t2tf is had.

A Request is what to optimize (checked here, once, for every caller); a Volume is what t2tf
reads. run() picks the back end: the t2tf Python module in this process (in_process.py) when
this Python can import it and T2TF_BIN names no binary, else the t2tf binary as a child
process (binary.py). Either way the run shows its progress, processes the GUI's events, stops
after the current step when asked (keeping that step's TF), writes into a temporary folder
that is removed afterwards, and returns the result in memory (results.py).
"""
import json
import os
import threading
import time

from . import binary, gui, in_process, temporaries, timing
from .errors import T2tfError, say
from .progress import Progress

# Every run in progress, as the event that cancel() sets: the package is imported once per
# process, so every copy of the plugin's entry module reaches the same list.
_active = []


def cancel():
    """Ask every running t2tf to stop after its current step (it keeps that step's TF)."""
    for cancelled in list(_active):
        cancelled.set()


class Request:
    """The settings of one run (the filter's properties, text_to_transfer_function's
    arguments). `start`: a preset (dict) to start from (Refine); `locks`: (min, max) data
    ranges kept as they start; `extra`: more `t2tf optimize` flags (the binary only)."""

    def __init__(self, prompt="", negatives=(), steps=300, views=3, seed=0, model=None,
                 tokenizer=None, reference_image=None, locks=(), start=None, extra=()):
        self.prompt = prompt or ""
        self.negatives = [n for n in negatives or () if n.strip()]
        self.steps, self.views, self.seed = int(steps), int(views), int(seed)
        self.model, self.tokenizer = model or None, tokenizer or None
        self.reference_image = reference_image or None
        self.locks = [(float(lo), float(hi)) for lo, hi in locks or ()]
        self.start = start
        self.extra = list(extra or ())

    def check(self):
        """The settings' own problems, before anything runs."""
        if not self.prompt.strip() and not self.reference_image:
            raise T2tfError("the prompt is empty: type what the rendering should show (Prompt)",
                            "empty_prompt", "prompt")
        # The panel's domains say at least 1; a typed 0 or -3 still reaches the setter.
        for name, value in (("Steps", self.steps), ("Views", self.views)):
            if value < 1:
                raise T2tfError("%s must be at least 1 (it is %d)" % (name, value),
                                "invalid_option", name.lower())


def parse_locks(text):
    """The Lock Ranges property's text, "MIN,MAX; MIN,MAX", as [(min, max), ...]."""
    locks = []
    for part in (text or "").replace("\n", ";").split(";"):
        if not part.strip():
            continue
        try:
            lo, hi = (float(v) for v in part.split(","))
        except ValueError:
            raise T2tfError("Lock Ranges: %r is not MIN,MAX (e.g. 120,400; 800,1200)"
                            % part.strip(), "invalid_option", "lock")
        locks.append((lo, hi))
    return locks


class Volume:
    """What t2tf reads: the point array `array` of an image (vtkImageData), given or made by
    `fetch()` once the run has started (a remote proxy, fetched under the progress bar), and
    `file`: (path, flags) of the same data as a file t2tf reads itself, or None. `series`:
    [(time, image), ...], the time steps to optimize one TF for (All Time Steps), or None;
    `image` is then the first step's."""

    def __init__(self, array, image=None, fetch=None, file=None, series=None):
        self.array, self.image, self.fetch, self.file = array, image, fetch, file
        self.series = series

    def image_data(self):
        if self.image is None:
            self.image = self.fetch()
        return self.image


def back_end(request):
    """The back end a run of `request` uses, found and version-checked (fails early, before
    anything is written)."""
    module = None if request.extra else in_process.module()
    return in_process.Backend(module) if module else binary.Backend(binary.find())


def run(request, volume, algorithm=None, timeout=None):
    """Run t2tf for `request` on `volume`; returns the result (results.read, plus array,
    volume: the file t2tf read or None, timing). `algorithm` (the filter) shows the
    progress and its abort flag stops the run; without one, the GUI's progress bar shows it.
    Raises T2tfError."""
    request.check()
    back = back_end(request)
    bar = None if algorithm is not None else gui.ProgressBar()
    progress = Progress(algorithm, bar)
    watch = gui.RunWatch()
    cancelled = threading.Event()
    start = time.time()

    def aborted():
        return bool(cancelled.is_set() or watch.requested()
                    or (algorithm is not None and algorithm.GetAbortExecute())
                    or (timeout is not None and time.time() - start > timeout))

    folder = temporaries.make()
    _active.append(cancelled)
    try:
        progress.show()
        init = None
        if request.start is not None:
            init = os.path.join(folder, "start.json")
            with open(init, "w") as f:
                json.dump([request.start], f)
        result = back.run(request, volume, folder, init, progress, aborted)
    finally:
        _active.remove(cancelled)
        closed = watch.closed()
        watch.end()
        if bar is not None:
            bar.end()
        temporaries.remove(folder)
    progress.finish()
    result["array"] = volume.array
    result["timing"] = timing.measured(result["report"], request.views, time.time() - start)
    timing.remember(request.model, result["timing"])
    if result["interrupted"]:
        say("%s: kept the transfer function of the last finished step"
            % ("the main window was closed" if closed else "cancelled"), False)
    return result
