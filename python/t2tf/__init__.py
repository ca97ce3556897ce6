"""t2tf: optimize a volume-rendering transfer function from a sentence with CLIP.

The same library as the `t2tf` command, with NumPy arrays in and out::

    import t2tf

    volume = t2tf.read_volume("neghip_64x64x64_uint8.raw")  # or t2tf.Volume(array)
    result = t2tf.optimize(volume, "a protein molecule", steps=100)
    result.save("neghip-tf")                    # the files `t2tf optimize` writes
    values, rgba = result.transfer_function.sample(256)
    picture = t2tf.render(volume, result.transfer_function, size=512)
    series = t2tf.read_series("run.pvd")     # one TF for a whole time series
    result = t2tf.optimize(series, "the vortex rings")

Arrays are indexed [z, y, x] (x fastest, as VTK and raw files store values). Runs release
the GIL; `optimize`'s `progress` callback sees each step and stops the run by returning
False. Errors are `t2tf.Error` subclasses with one-line messages, their `kind` and
`option` attributes saying what kind of problem and which keyword it concerns.
"""
from ._t2tf import (
    DEFAULT_MODEL,
    BudgetError,
    Error,
    FormatError,
    Model,
    ModelError,
    OutputError,
    RenderError,
    Result,
    SettingsError,
    Series,
    TransferFunction,
    Volume,
    VolumeError,
    __version__,
    load_model,
    optimize,
    read_series,
    read_volume,
    render,
)

__all__ = [
    "DEFAULT_MODEL",
    "BudgetError",
    "Error",
    "FormatError",
    "Model",
    "ModelError",
    "OutputError",
    "RenderError",
    "Result",
    "SettingsError",
    "Series",
    "TransferFunction",
    "Volume",
    "VolumeError",
    "__version__",
    "load_model",
    "optimize",
    "read_series",
    "read_volume",
    "render",
]
