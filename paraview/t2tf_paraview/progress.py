"""What ParaView shows of a run while it goes: "Text To Transfer Function: step k/N, loss L,
ETA s" as the algorithm's progress text (or on the GUI's progress bar when the run is no
pipeline update), refreshed at least once a second even before t2tf's first step, with the
GUI's events processed in between so ParaView stays responsive."""
import time

from . import gui
from .errors import TITLE


class Progress:
    """The progress of one run, shown through `algorithm` (a VTK algorithm) and/or `bar`
    (a gui.ProgressBar)."""

    def __init__(self, algorithm=None, bar=None):
        self.algorithm = algorithm
        self.bar = bar
        self.start = time.time()
        self.step, self.steps, self.loss = 0, None, None
        self.first_step = None  # when step 1 ended: the rate is measured after it
        self.eta, self.eta_at = None, None
        self.shown = 0.0

    def on_step(self, step, steps, loss=None, eta=None):
        now = time.time()
        self.step, self.steps, self.loss = int(step), max(1, int(steps)), loss
        if self.first_step is None:
            self.first_step = now
        if eta is None and self.step >= 3:
            # The first step carries one-off work (caption embeddings), so the rate comes
            # from the steps after it, as the CLI's estimate does.
            eta = (now - self.first_step) / (self.step - 1) * (self.steps - self.step)
        self.eta, self.eta_at = eta, now
        self.show()

    def text(self):
        if not self.steps:
            return "%s: starting (%.0f s)" % (TITLE, time.time() - self.start)
        line = "%s: step %d/%d" % (TITLE, self.step, self.steps)
        if self.loss is not None:
            line += ", loss %.4f" % self.loss
        if self.eta is None:
            return line + ", ETA …"
        return line + ", ETA %.0f s" % max(0.0, self.eta - (time.time() - self.eta_at))

    def fraction(self):
        return float(self.step) / self.steps if self.steps else 0.0

    def show(self):
        self.shown = time.time()
        if self.algorithm is not None:
            self.algorithm.SetProgressText(self.text())
            self.algorithm.UpdateProgress(self.fraction())
        if self.bar is not None:
            self.bar.update(self.text(), self.fraction())
        gui.pump()

    def tick(self):
        """Between steps: refresh the text twice a second, process GUI events always."""
        if time.time() - self.shown >= 0.5:
            self.show()
        else:
            gui.pump()

    def finish(self):
        """The run is over: the algorithm's progress reads the title alone, at the end."""
        if self.algorithm is not None:
            self.algorithm.SetProgressText(TITLE)
            self.algorithm.UpdateProgress(1.0)
