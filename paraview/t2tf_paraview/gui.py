"""The ParaView GUI while t2tf runs: events processed, the Abort button and the main window
able to stop the run, and a progress bar for a run that is no pipeline update.

ParaView 5.11 leaves its Abort button disabled and connected to nothing, and its progress
manager drops every mouse press during an update (a press reaches Qt's window object before
the button, and is dropped there). So for the length of a run the button is enabled and made
checkable (a click leaves it checked, which the run reads between steps), presses are let
through while the pointer is over it, and afterwards the button is as ParaView had it. A main
window that was shown when the run began and is hidden now was closed (ParaView quits once
its event loop runs again), so the run stops too. Outside the GUI, or where native.py cannot
call the GUI, none of this happens and the abort flag alone stops a run.
"""
from . import native

# Called before each round of events: the running RunWatch's pointer check.
_before_events = []


def pump():
    """Process the GUI's events for at most 50 ms: repaints and timers run, while the
    progress manager keeps other input held as during any pipeline update."""
    for hook in list(_before_events):
        hook()
    return bool(native.process_events(50))


class RunWatch:
    """The Abort button and the main window during one run (see the module's docstring)."""

    def __init__(self):
        self.active = False
        self.window_shown = False
        widgets = native.gui_widgets()
        if not widgets:
            return
        self.manager, self.window, self.button = widgets
        self.window_shown = native.visible(self.window) is True
        if not (native.enable_abort(self.manager, self.button, True)
                and native.set_checkable(self.button, True)
                and native.set_checked(self.button, False)):
            return
        self.unblocked = native.unblock_events(self.manager, False)
        _before_events.append(self._let_presses_through)
        self.active = True

    def _let_presses_through(self):
        """Open the progress manager's lock on presses while the pointer is over the Abort
        button, close it elsewhere. The pointer's place comes from the window system, so a
        press that follows the pointer's arrival on the button finds the lock open."""
        over = native.pointer_over(self.button)
        if over is not None:
            native.unblock_events(self.manager, over)

    def closed(self):
        """Whether the main window was closed during the run."""
        return self.active and self.window_shown and native.visible(self.window) is False

    def requested(self):
        """Whether the Abort button was clicked (or is held down), or the main window was
        closed, since the run began."""
        return self.active and (native.pressed(self.button) is True or self.closed())

    def end(self):
        """The button as ParaView 5.11 has it between runs: unchecked, disabled."""
        if not self.active:
            return
        self.active = False
        if self._let_presses_through in _before_events:
            _before_events.remove(self._let_presses_through)
        native.unblock_events(self.manager, bool(self.unblocked))
        native.set_checked(self.button, False)
        native.set_checkable(self.button, False)
        native.enable_abort(self.manager, self.button, False)


class ProgressBar:
    """ParaView's progress bar driven from the client, for a run that is no pipeline update
    (t2tf runs here while the filter's algorithm lives on a server). Like an update it holds
    the GUI's input for the run, so no second run starts meanwhile. Nothing outside the GUI."""

    def __init__(self):
        widgets = native.gui_widgets()
        self.manager = widgets[0] if widgets else None
        self.active = bool(self.manager) and bool(native.enable_progress(self.manager, True))

    def update(self, text, fraction):
        if self.active:
            native.set_progress(self.manager, text, round(100 * fraction))

    def end(self):
        if self.active:
            self.active = False
            native.enable_progress(self.manager, False)
