"""ParaView macro: "Text To Transfer Function" on the active source.

Add it with Macros > Import new macro... (this file). Run on the active source (image
data), it optimizes a transfer function with t2tf and shows the source with it: in a builtin
session through the TextToTransferFunction filter of t2tf_plugin.py, connected to a remote
pvserver through a bounded ResampleToImage proxy (t2tf_plugin.text_to_transfer_function).

The prompt comes from, in this order, and the macro says which:
  1. a dialog, in the ParaView GUI (or an interactive pvpython) when its Python has tkinter
     (ParaView's Python has no Qt bindings of its own, so no Qt dialog is offered; set
     T2TF_NO_DIALOG=1 to skip it);
  2. the environment variable T2TF_PROMPT;
  3. a file next to the data: NAME.prompt.txt beside NAME.vti/NAME.raw, else t2tf_prompt.txt
     in the data's folder (first non-empty line).
Other settings come from the environment: T2TF_MODEL, T2TF_TOKENIZER, T2TF_STEPS, T2TF_VIEWS,
T2TF_SEED, T2TF_NEGATIVES (separated by ';'), T2TF_REFINE=1 (start from the array's current
colour and opacity functions), T2TF_LOCK (data ranges kept as they start, "MIN,MAX; MIN,MAX"),
T2TF_PROXY_SIZE (remote proxy, points per axis), and T2TF_PLUGIN (the plugin file when it is not beside this macro). Problems are one line in
the output window, never a traceback.
"""
import importlib.util
import os
import sys

TITLE = "Text To Transfer Function"


def _plugin_module():
    """t2tf_plugin: already imported, else from T2TF_PLUGIN, the folder above this one (the
    repository's paraview/), beside this file, or on PV_PLUGIN_PATH (ParaView copies imported
    macros elsewhere, so several places)."""
    if "t2tf_plugin" in sys.modules:
        return sys.modules["t2tf_plugin"]
    places = [os.environ.get("T2TF_PLUGIN", "")]
    here = globals().get("__file__")
    if here:
        folder = os.path.dirname(os.path.abspath(here))
        places.append(os.path.join(os.path.dirname(folder), "t2tf_plugin.py"))
        places.append(os.path.join(folder, "t2tf_plugin.py"))
    for folder in os.environ.get("PV_PLUGIN_PATH", "").split(os.pathsep):
        if folder:
            places.append(os.path.join(folder, "t2tf_plugin.py"))
    for path in places:
        if path and os.path.isfile(path):
            spec = importlib.util.spec_from_file_location("t2tf_plugin", path)
            module = importlib.util.module_from_spec(spec)
            sys.modules["t2tf_plugin"] = module
            spec.loader.exec_module(module)
            module.PLUGIN_FILE = path
            return module
    return None


def _say(text, error=False):
    from vtkmodules.vtkCommonCore import vtkOutputWindow

    line = "%s: %s\n" % (TITLE, text)
    window = vtkOutputWindow.GetInstance()
    window.DisplayErrorText(line) if error else window.DisplayText(line)


def interactive():
    """Whether this Python runs interactively: the ParaView GUI (its Python shell and macros
    run with sys.argv == ['']; its executable is vtkpython, like pvpython's) or an
    interactive pvpython, not a pvpython/pvbatch script."""
    return list(sys.argv) in ([], [""]) and bool(os.environ.get("DISPLAY"))


def _dialog(initial=""):
    """A prompt typed into a small Tk dialog; None when no dialog is possible here."""
    if not interactive() or os.environ.get("T2TF_NO_DIALOG"):
        return None
    try:
        import tkinter
        from tkinter import simpledialog
    except ImportError:
        return None
    try:
        root = tkinter.Tk()
        root.withdraw()
        try:
            return simpledialog.askstring(TITLE, "What should the rendering show?",
                                          initialvalue=initial, parent=root)
        finally:
            root.destroy()
    except tkinter.TclError:
        return None


def data_files(source):
    """The files behind `source` or its nearest upstream reader (first inputs upward)."""
    proxy = source
    for _ in range(64):
        for name in ("FileName", "FileNames"):
            prop = proxy.GetProperty(name)
            if prop is not None:
                value = prop.GetData()
                names = [value] if isinstance(value, str) else list(value or [])
                return [n for n in names if n]
        prop = proxy.GetProperty("Input")
        value = prop.GetData() if prop is not None else None
        if isinstance(value, (list, tuple)):
            value = value[0] if value else None
        if value is None:
            return []
        proxy = getattr(value, "Proxy", value)  # an OutputPort names its proxy
    return []


def prompt_file(source):
    """(prompt, path) from NAME.prompt.txt or t2tf_prompt.txt next to the data, else None."""
    for data in data_files(source):
        stem = os.path.splitext(data)[0]
        for path in (stem + ".prompt.txt",
                     os.path.join(os.path.dirname(data), "t2tf_prompt.txt")):
            if os.path.isfile(path):
                with open(path, encoding="utf-8") as f:
                    for line in f:
                        if line.strip():
                            return line.strip(), path
    return None


def read_prompt(source, environ=None):
    """(prompt, where it came from) by the order in this file's docstring; ("", why) if none."""
    environ = os.environ if environ is None else environ
    typed = _dialog(environ.get("T2TF_PROMPT", ""))
    if typed is not None:
        return typed.strip(), "the dialog"
    if environ.get("T2TF_PROMPT", "").strip():
        return environ["T2TF_PROMPT"].strip(), "the environment variable T2TF_PROMPT"
    found = prompt_file(source)
    if found:
        return found[0], found[1]
    return "", "nowhere: no dialog here, T2TF_PROMPT unset, no NAME.prompt.txt or " \
               "t2tf_prompt.txt next to the data"


def run(source=None, environ=None, view=None):
    """The macro's work; returns t2tf_plugin's (result, proxy_or_filter), or None after
    saying what went wrong."""
    import paraview.simple as pvs
    from paraview import servermanager

    environ = os.environ if environ is None else environ
    plugin = _plugin_module()
    if plugin is None:
        _say("t2tf_plugin.py not found: set T2TF_PLUGIN to its path, or put it beside this "
             "macro or on PV_PLUGIN_PATH", error=True)
        return None
    source = source or pvs.GetActiveSource()
    if source is None:
        _say("no active source: open a volume and select it first", error=True)
        return None
    prompt, origin = read_prompt(source, environ)
    if not prompt:
        _say("no prompt (read from %s)" % origin, error=True)
        return None
    _say("prompt %r from %s" % (prompt, origin))
    remote = servermanager.ActiveConnection.IsRemote()
    if not remote and not hasattr(pvs, "TextToTransferFunction"):
        # The filter runs in this process: load the plugin that defines it.
        pvs.LoadPlugin(getattr(plugin, "PLUGIN_FILE", plugin.__file__), remote=False,
                       ns=vars(pvs))
    negatives = [n for n in environ.get("T2TF_NEGATIVES", "a blank image").split(";") if n.strip()]
    try:
        locks = plugin.parse_locks(environ.get("T2TF_LOCK", ""))
        return plugin.text_to_transfer_function(
            source, prompt, negatives=negatives,
            refine=environ.get("T2TF_REFINE", "") not in ("", "0"), locks=locks,
            steps=int(environ.get("T2TF_STEPS", "300")),
            views=int(environ.get("T2TF_VIEWS", "3")),
            seed=int(environ.get("T2TF_SEED", "0")),
            model=environ.get("T2TF_MODEL") or None,
            tokenizer=environ.get("T2TF_TOKENIZER") or None,
            proxy_size=environ.get("T2TF_PROXY_SIZE") or None, view=view)
    except plugin.T2tfError as e:
        _say(str(e), error=True)
    except ValueError as e:  # a malformed number in the environment
        _say("bad setting in the environment: %s" % e, error=True)
    return None


# Run when ParaView executes this file as a macro (not when imported as t2tf_macro); the
# outcome stays in LAST for whoever ran it.
if __name__ != "t2tf_macro":
    LAST = run()
