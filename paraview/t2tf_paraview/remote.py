"""t2tf on data that lives on a pvserver: the server resamples it with ParaView's own
ResampleToImage to a bounded proxy over the data's own bounds, only that proxy comes to the
client, and t2tf runs here on it. The TF transfers to the full data's display (rendered on the
server at full resolution) because t2tf's opacity is per normalized box length
(docs/DESIGN.md) and the proxy spans the same box. Ranks running t2tf each on a piece could
not reach the client's colour maps, so the server's ranks run no t2tf."""
import json
import os

from . import inputs
from .display import current_tf
from .errors import T2tfError
from .run import Request, Volume, parse_locks, run

# Default bound of the proxy (points per axis).
PROXY_SIZE = 256


def proxy_size_setting(proxy_size=None):
    """Points per axis of the proxy: the argument, else T2TF_PROXY_SIZE, else 256."""
    raw = proxy_size if proxy_size is not None else os.environ.get("T2TF_PROXY_SIZE")
    if raw is None or str(raw).strip() == "":
        return PROXY_SIZE
    try:
        size = int(raw)
    except ValueError:
        raise T2tfError("the proxy size must be a whole number of points per axis, not %r" % raw)
    if size < 2:
        raise T2tfError("the proxy size must be at least 2 points per axis, not %d" % size)
    return size


def proxy_dims(extent, size):
    """Points per axis of the proxy: the data's own, scaled down so none exceeds `size`."""
    dims = [extent[2 * i + 1] - extent[2 * i] + 1 for i in range(3)]
    scale = min(1.0, float(size) / max(dims))
    return [max(2, min(size, int(round(d * scale)))) for d in dims]


def fetch_proxy(source, dims):
    """Resample `source` on the server to `dims` points over its own bounds and bring only
    that here. Returns (image, points fetched).

    Under MPI the resampled image is distributed: rank r holds a piece whose extent shares a
    boundary plane with its neighbour's. servermanager.Fetch with no rank merges pieces with
    vtkAppendFilter (an unstructured grid, even on one rank), so each rank's piece is fetched
    on its own and the pieces are put back into one image by extent (vtkImageAppend with
    PreserveExtents)."""
    import paraview.simple as pvs
    from paraview import servermanager
    from vtkmodules.vtkFiltersCore import vtkImageAppend

    resample = pvs.ResampleToImage(Input=source)
    try:
        resample.UseInputBounds = 1
        resample.SamplingDimensions = list(dims)
        resample.UpdatePipeline()
        ranks = max(1, servermanager.ActiveConnection.GetNumberOfDataPartitions())
        pieces = []
        for rank in range(ranks):
            piece = servermanager.Fetch(resample, rank)
            if piece is not None and piece.GetNumberOfPoints() > 0:
                pieces.append(piece)
    finally:
        pvs.Delete(resample)
    if not pieces:
        raise T2tfError("the server's ResampleToImage proxy of the data is empty")
    fetched = sum(p.GetNumberOfPoints() for p in pieces)
    if len(pieces) == 1:
        image = pieces[0]
    else:
        append = vtkImageAppend()
        append.PreserveExtentsOn()
        for piece in pieces:
            append.AddInputData(piece)
        append.Update()
        image = append.GetOutput()
    got = list(image.GetDimensions())
    if got != list(dims):
        raise T2tfError("the server's proxy has %s points per axis, expected %s"
                        % (got, list(dims)))
    return image, fetched


def optimize(source, array, request, proxy_size=None, timeout=None):
    """Run t2tf here for `request` on a proxy of `source` (at most `proxy_size` points per
    axis); the proxy is fetched once the run shows on the progress bar. Returns (result,
    proxy image); the result says the proxy's dims and the points fetched."""
    info = source.GetDataInformation()
    if info.GetDataClassName() not in inputs.IMAGE_CLASSES:
        raise inputs.not_image(info.GetDataClassName())
    dims = proxy_dims(info.GetExtent(), proxy_size_setting(proxy_size))
    fetched = []

    def fetch():
        image, points = fetch_proxy(source, dims)
        fetched.append(points)
        return image

    volume = Volume(array, fetch=fetch)
    result = run(request, volume, timeout=timeout)
    # The proxy's file, where one was written, is gone with the run's folder.
    result.update(volume=None, proxy_dims=dims, fetched_points=fetched[0])
    return result, volume.image


def filter_key(proxy):
    """A filter's settings and its input's data as the server describes them: a run is due
    when they change."""
    names = ("Prompt", "Negatives", "Steps", "Views", "Seed", "Model", "Tokenizer",
             "ReferenceImage", "Refine", "LockRanges", "Array")
    values = [[str(v) for v in proxy.GetProperty(n)] for n in names]
    source = proxy.Input
    info = source.GetDataInformation()
    values += [source.GetGlobalIDAsString(), info.GetDataClassName(),
               list(info.GetExtent()), list(info.GetBounds()), info.GetNumberOfPoints(),
               sorted((a.GetName(), list(a.GetRange())) for a in source.PointData)]
    return json.dumps(values, default=str)


def filter_request(proxy):
    """The Request a filter proxy's properties make (without its Refine start)."""
    return Request(
        proxy.Prompt or "", list(proxy.Negatives), int(proxy.Steps), int(proxy.Views),
        int(proxy.Seed), proxy.Model or None, proxy.Tokenizer or None,
        proxy.ReferenceImage or None, parse_locks(proxy.LockRanges))


def _time_step_count(source):
    """How many time steps a source proxy reports (0 for none)."""
    try:
        values = source.TimestepValues
    except AttributeError:
        return 0
    if values is None:
        return 0
    try:
        return len(list(values))
    except TypeError:  # one value comes as a number
        return 1


def run_filter(proxy):
    """The client's run for a filter whose algorithm lives on the server: t2tf on a proxy of
    the filter's input. Returns the result."""
    source = proxy.Input
    info = source.GetDataInformation()
    if info.GetDataClassName() not in inputs.IMAGE_CLASSES:
        raise inputs.not_image(info.GetDataClassName())
    if int(getattr(proxy, "AllTimeSteps", 0)) and _time_step_count(source) > 1:
        # Each step would be one more resample and fetch from the server under the same
        # Apply; not supported yet.
        raise T2tfError("All Time Steps is not supported in client-server mode: turn it off "
                        "to optimize for the current time step, or open the data in a builtin "
                        "session", "invalid_option", "all_time_steps")
    request = filter_request(proxy)
    request.check()
    array = (list(proxy.Array) + ["", ""])[1] or inputs.active_array(source)
    if int(proxy.Refine):
        # A Refine starts from the functions the array has now.
        request.start = current_tf(array, source)
    return optimize(source, array, request)[0]
