"""The in-process back end: the t2tf Python module, run in ParaView's own process.

Used when this Python can import `t2tf` (installed for the Python ParaView uses, or a virtual
environment the launcher put on the path) and T2TF_BIN names no binary. The point array goes
over through vtk_to_numpy, read in place: no input file is written. Steps arrive through the
module's progress callback, whose answer stops the run after the current step.
"""
import os

from . import __version__, errors, results
from .errors import T2tfError, say

_said = []  # the module files already named in the output window


def module():
    """The t2tf module, or None to run the binary: when T2TF_BIN names one, or when this
    Python cannot import the module."""
    if os.environ.get("T2TF_BIN"):
        return None
    try:
        import t2tf
        import t2tf.vtk  # noqa: F401 (the VTK bridge the filter uses)
    except ImportError:
        return None
    return t2tf


def _series(t2tf, series, array):
    """The time steps [(time, image), ...] as a t2tf.Series (one TF for all of them), each
    step's point array `array` read in place; geometry from the first step (the filter
    checked that all steps share it)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    arrays = []
    for _, image in series:
        data = image.GetPointData().GetArray(array)
        if data is None:
            raise ValueError("the image has no point array %r" % array)
        if data.GetNumberOfComponents() != 1:
            raise ValueError("point array %r has %d components; t2tf needs one"
                             % (array, data.GetNumberOfComponents()))
        nx, ny, nz = image.GetDimensions()
        arrays.append(vtk_to_numpy(data).reshape(nz, ny, nx))
    image = series[0][1]
    extent, spacing = image.GetExtent(), image.GetSpacing()
    origin = tuple(image.GetOrigin()[a] + extent[2 * a] * spacing[a] for a in range(3))
    return t2tf.Series.from_arrays(arrays, times=[float(t) for t, _ in series],
                                   spacing=tuple(spacing), origin=origin)


class Backend:
    """Runs `t2tf_module` (the imported module), once its version is the plugin's."""

    def __init__(self, t2tf_module):
        if t2tf_module.__version__ != __version__:
            raise T2tfError(
                "the t2tf module %s is version %s, but this plugin is %s: install t2tf %s in "
                "the Python ParaView uses, or set T2TF_BIN to a t2tf %s binary"
                % (t2tf_module.__file__, t2tf_module.__version__, __version__, __version__,
                   __version__))
        if t2tf_module.__file__ not in _said:
            say("running t2tf %s in-process (%s)" % (t2tf_module.__version__,
                                                     t2tf_module.__file__), False)
            _said.append(t2tf_module.__file__)
        self.t2tf = t2tf_module

    def run(self, request, volume, folder, init, progress, aborted):
        t2tf = self.t2tf

        def on_event(event):
            if event["event"] == "step":
                progress.on_step(event["step"], event["steps"], event.get("loss"))
            elif event["event"] == "warning":
                say("warning: " + event["message"], False)
            return not aborted()

        out = os.path.join(folder, "tf")
        try:
            if volume.series:
                data = _series(t2tf, volume.series, volume.array)
            else:
                data = t2tf.vtk.volume_from_vtk(volume.image_data(), volume.array)
        except ValueError as e:  # the array is missing or has several components
            raise errors.from_t2tf(e, "volume", "array")
        try:
            run = t2tf.optimize(
                data, request.prompt.strip() or None, negatives=request.negatives,
                steps=request.steps, views=request.views, seed=request.seed,
                model=request.model, tokenizer=request.tokenizer,
                reference_image=request.reference_image, progress=on_event, init=init,
                lock=request.locks)
            report = run.save(out)
        except (t2tf.Error, ValueError) as e:
            raise errors.from_exception(e)
        result = results.read(out, report["outputs"], run.interrupted, request.prompt,
                              request.reference_image)
        # An array has no file to reopen, so no pvpython script holds the camera: the run has.
        result["camera"] = run.camera
        result["volume"] = None
        return result
