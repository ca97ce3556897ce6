"""Problems the user can fix, said once in ParaView's words.

A failure of the plugin is one line in ParaView's output window (stderr in pvpython), never a
traceback. t2tf's own errors carry a kind and the library name of the option concerned (the
binary's final `{"event": "error", ...}` line with --progress json, the Python module's
exception attributes); the table below turns those into what to change in ParaView. The
message itself is shown as t2tf wrote it: where kind and option are missing (an older
t2tf), only the kind's generic hint is added, and the text is never rewritten.
"""
from vtkmodules.vtkCommonCore import vtkOutputWindow

# ParaView names the pipeline item and the pvpython function after the label without its
# spaces: TextToTransferFunction1, as ParaView's own "Resample To Image" gives ResampleToImage1.
TITLE = "Text To Transfer Function"


class T2tfError(Exception):
    """A problem the user can fix: str() is the one line shown. `kind` and `option` say what
    kind of problem and which t2tf option (library field name) it concerns, when known."""

    def __init__(self, text, kind=None, option=None):
        Exception.__init__(self, text)
        self.kind = kind
        self.option = option


def say(text, error=True):
    """One line in ParaView's output window (stderr in pvpython), prefixed with the title."""
    window = vtkOutputWindow.GetInstance()
    line = "%s: %s\n" % (TITLE, text)
    if error:
        window.DisplayErrorText(line)
    else:
        window.DisplayText(line)


# t2tf's options (the library's field names) and the properties that set them: (label, whether
# it sits behind the panel's gear button). "dims" and "budget" have no property.
PROPERTIES = {
    "prompt": ("Prompt", False), "negatives": ("Negatives", False), "steps": ("Steps", False),
    "views": ("Views", False), "lock": ("Lock Ranges", False), "model": ("Model", True),
    "tokenizer": ("Tokenizer", True), "seed": ("Seed", True), "array": ("Array", True),
    "reference_image": ("Reference Image", True),
}

# What to do in ParaView, by (kind, option); (kind, None) serves every option of that kind
# not listed. An invalid option that is a property and has no line of its own is "change the
# X property".
HINTS = {
    ("model_unavailable", None):
        "set the Model property (advanced) to a local model folder, or run `t2tf model fetch` "
        "where there is network and copy the Hugging Face cache here",
    ("model_unavailable", "tokenizer"):
        "set the Tokenizer property (advanced) to a tokenizer.json file",
    ("invalid_option", "model"):
        "set the Model property (advanced) to a local model folder or a Hugging Face "
        "repository id",
    ("invalid_option", "tokenizer"):
        "set the Tokenizer property (advanced) to a tokenizer.json file",
    ("invalid_option", "dims"):
        "check the reader's Data Extent, Data Scalar Type and Data Byte Order",
    ("invalid_option", None): "check the filter's properties",
    ("empty_prompt", None): "type what the rendering should show in the Prompt property",
    ("memory", None): "lower Views, or make the input smaller with Resample To Image",
    ("volume", None): "give image data with a point array of one component "
                      "(Resample To Image makes image data)",
    ("volume", "array"): "choose another point array in the Array property (advanced)",
    ("volume", "dims"): "check the reader's Data Extent, Data Scalar Type and Data Byte Order",
    ("io", None): "check that the temporary folder (TMPDIR) has room and can be written",
    ("io", "reference_image"): "set the Reference Image property (advanced) to a PNG file",
}

# The Python module's exception classes and the kind each stands for, for a module that does
# not set `kind` itself.
_KIND_OF_CLASS = {"ModelError": "model_unavailable", "SettingsError": "invalid_option",
                  "VolumeError": "volume", "FormatError": "volume", "OutputError": "io",
                  "BudgetError": "memory"}


def hint(kind, option):
    """What to do in ParaView about a t2tf error of this kind and option; None when there
    is nothing to add."""
    if (kind, option) in HINTS:
        return HINTS[(kind, option)]
    if kind == "invalid_option" and option in PROPERTIES:
        label, advanced = PROPERTIES[option]
        return "change the %s property%s" % (label, " (advanced)" if advanced else "")
    return HINTS.get((kind, None))


def from_t2tf(text, kind=None, option=None):
    """A T2tfError for t2tf's message `text`: the message as t2tf wrote it, then what to do
    in ParaView."""
    line = "t2tf: " + " ".join(str(text).split())
    advice = hint(kind, option)
    if advice:
        line += "; in ParaView, " + advice
    return T2tfError(line, kind, option)


def from_exception(error):
    """A T2tfError for an exception of the t2tf Python module: its kind and option when it
    has them, else the kind its class stands for."""
    kind = getattr(error, "kind", None)
    if kind is None:
        kind = next((k for c, k in _KIND_OF_CLASS.items()
                     if any(b.__name__ == c for b in type(error).__mro__)), "other")
    return from_t2tf(error, kind, getattr(error, "option", None))
