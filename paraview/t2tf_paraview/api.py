"""text_to_transfer_function: the plugin's Python API (pvpython, the macro), for any source,
in a builtin session (through the filter) or connected to a pvserver (through a bounded
proxy, remote.py). Raises T2tfError with a one-line reason, so a script stops where t2tf
could not run."""
from . import display, inputs, presets, remote, run
from .errors import T2tfError
from .run import Request

DEFAULT_MODEL = "openai/clip-vit-base-patch32"


def new_filter():
    """paraview.simple's constructor of the filter (named after its label:
    TextToTransferFunction). LoadPlugin(path, ns=globals()) puts it into the caller's
    namespace only, so it is made here from the proxy definitions when simple lacks it."""
    import paraview.simple as pvs
    from paraview import servermanager

    make = getattr(pvs, "TextToTransferFunction", None)
    if make is None:
        filters = servermanager.ActiveConnection.ProxiesNS.filters
        if not hasattr(filters, "TextToTransferFunction"):
            raise T2tfError("the TextToTransferFunction filter is not loaded: "
                            "LoadPlugin(path to t2tf_plugin.py) first")
        make = pvs._create_func("TextToTransferFunction", filters)
    return make


def text_to_transfer_function(source=None, prompt="", negatives=(), steps=300, views=3, seed=0,
                              model=None, tokenizer=None, array=None, reference_image=None,
                              proxy_size=None, view=None, camera=True, timeout=None, extra=(),
                              refine=False, locks=()):
    """Optimize a TF for `source` (default: the active source) and show it with it.
    `refine` starts from the array's current colour and opacity functions; `locks` are
    (min, max) data ranges kept as they start.

    In a builtin session this creates the TextToTransferFunction filter. Connected to a
    remote server it asks the server for a ResampleToImage proxy of at most `proxy_size`
    points per axis (default 256, or T2TF_PROXY_SIZE), fetches only that, runs t2tf here and
    applies the TF to `source`'s own display (full resolution, on the server). `extra` are
    further `t2tf optimize` flags (remote only; they need the binary), e.g. ["--l1", "0.001"].
    Returns (result, proxy_or_filter). Raises T2tfError with a one-line reason.
    """
    import paraview.simple as pvs
    from paraview import servermanager

    source = source or pvs.GetActiveSource()
    if source is None:
        raise T2tfError("no active source: open a volume first")
    is_remote = servermanager.ActiveConnection.IsRemote()
    request = Request(prompt, negatives, steps, views, seed, model, tokenizer, reference_image,
                      locks, extra=extra if is_remote else ())
    request.check()
    run.back_end(request)  # fail early and clearly: no binary, or one of another version
    source.UpdatePipeline()
    info = source.GetDataInformation()
    if info.GetDataClassName() not in inputs.IMAGE_CLASSES:
        raise inputs.not_image(info.GetDataClassName())
    array = array or inputs.active_array(source)
    if not is_remote:
        f = new_filter()(Input=source, Prompt=prompt, Negatives=list(negatives),
                         Steps=steps, Views=views, Seed=seed, Model=model or DEFAULT_MODEL,
                         Tokenizer=tokenizer or "", ReferenceImage=reference_image or "",
                         Refine=int(bool(refine)), ApplyCamera=int(bool(camera)),
                         LockRanges="; ".join("%r,%r" % lock for lock in request.locks))
        f.Array = ["POINTS", array]
        f.UpdatePipeline()
        algorithm = f.GetClientSideObject()
        if algorithm.result is None:
            raise algorithm.failure or T2tfError("t2tf gave no result (see the messages above)")
        pvs.Show(f, view)
        return algorithm.result, f
    if refine:
        request.start = display.current_tf(array, source)
    result, local = remote.optimize(source, array, request, proxy_size, timeout)
    presets.register(result)
    view = view or pvs.GetActiveViewOrCreate("RenderView")
    pvs.Show(source, view)
    display.apply_to_display(result, source, view, array, camera)
    return result, local
