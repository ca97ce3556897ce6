"""Type stubs of the compiled module `t2tf._t2tf` (crates/python)."""
import os
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

_Path = Union[str, "os.PathLike[str]"]
_Size = Union[int, str]
# What optimize and render take as a volume: a Volume, a file's path or an array.
_VolumeLike = Union["Volume", _Path, npt.ArrayLike]
_Triple = Union[Tuple[float, float, float], Sequence[float], npt.ArrayLike]

DEFAULT_MODEL: str
__version__: str

class Error(Exception):
    """Base class of every t2tf error.

    `kind` says what kind of problem it is, for a caller to word its own advice: one of
    "invalid_option", "model_unavailable", "memory", "empty_prompt", "volume", "io", "other".
    `option` is the library's name of the option it is about, or None: the keyword ("dims",
    "model", "views"), but "budget" for max_memory and "locks" for lock. The same values as
    the `t2tf` command's final `{"event": "error", ...}` line with `--progress json`.
    """

    kind: str
    option: Optional[str]

class VolumeError(Error):
    """A volume that cannot be read or used."""

class ModelError(Error):
    """A CLIP model that cannot be found or loaded."""

class SettingsError(Error):
    """A setting out of its valid range."""

class FormatError(Error):
    """A transfer-function file that cannot be read or written."""

class RenderError(Error):
    """A picture that cannot be rendered."""

class OutputError(Error):
    """Output files that cannot be written."""

class BudgetError(Error):
    """Something that does not fit the memory budget."""

class Volume:
    """A scalar volume: its values normalized, its statistics and mip levels.

    `values` is a 3-D array indexed [z, y, x] (x fastest, as VTK and raw files store it)
    of integers or floats; NaN and infinite values are empty space. A C-contiguous array
    of uint8, int8, uint16, int16, uint32, int32, uint64, int64, float32 or float64 (either
    byte order) is read in place: the volume keeps it and reads its memory, so do not
    change it while the volume lives. Other arrays (Fortran order, strided views, bool,
    float16, lists) are copied to a C-contiguous array first. `spacing` and `origin` are
    (x, y, z) in world units.
    """

    def __init__(
        self,
        values: npt.ArrayLike,
        spacing: Optional[_Triple] = None,
        origin: Optional[_Triple] = None,
    ) -> None: ...
    @property
    def shape(self) -> Tuple[int, int, int]:
        """(nz, ny, nx)."""
    @property
    def spacing(self) -> Tuple[float, float, float]:
        """World distance between neighbouring points along x, y, z."""
    @property
    def origin(self) -> Tuple[float, float, float]:
        """World position of point [0, 0, 0] (x, y, z)."""
    @property
    def range(self) -> Tuple[float, float]:
        """(min, max) of the finite values, in data units."""
    @property
    def dtype(self) -> str:
        """NumPy's name of the values' type ("uint8", "float32", ...)."""
    @property
    def non_finite(self) -> int:
        """How many values are NaN or infinite."""
    @property
    def path(self) -> Optional[Path]:
        """The file the volume was read from; None for an array."""
    def to_numpy(self) -> np.ndarray:
        """The values in data units, read-only, indexed [z, y, x]."""

class Series:
    """A time series of volumes, to optimize one transfer function for all its steps
    (`optimize(series, prompt)`): from `read_series` or `Series.from_arrays`. Its data range
    is that of all its steps, so the TF means the same data values at every time."""

    @staticmethod
    def from_arrays(
        arrays: Sequence[npt.ArrayLike],
        times: Optional[Sequence[float]] = None,
        *,
        spacing: Optional[_Triple] = None,
        origin: Optional[_Triple] = None,
    ) -> "Series":
        """3-D arrays indexed [z, y, x] of one shape at increasing `times` (None: 0, 1, 2,
        ...), with `spacing` and `origin` (x, y, z) in world units, read in place where their
        layout allows, as `Volume` reads one."""
    @property
    def times(self) -> List[float]:
        """The time of each step used."""
    @property
    def files(self) -> Optional[List[Path]]:
        """The file of each step used; None for a series of arrays."""
    @property
    def collection(self) -> Optional[Path]:
        """The .pvd or .series file the series was read from, if any."""
    @property
    def range(self) -> Tuple[float, float]:
        """(min, max) of the finite values over every step used: the TF's data range."""
    @property
    def step_ranges(self) -> List[Tuple[float, float]]:
        """Each step's own (min, max)."""
    def __len__(self) -> int: ...

def read_series(
    paths: Union[_Path, Sequence[_Path]],
    *,
    time_range: Optional[Tuple[float, float]] = None,
    time_steps: Optional[Sequence[int]] = None,
    array: Optional[str] = None,
    spacing: Optional[_Triple] = None,
) -> Series:
    """Read a time series as `t2tf optimize` reads one: a ParaView .pvd or .series file, a
    glob pattern ("run_*.vti") or a list of files (ordered as ParaView orders a file series;
    a VTK XML file's TimeValue is its time, else its index). `time_range` (t0, t1) or
    `time_steps` (indices) select the steps used."""

def read_volume(
    path: _Path,
    *,
    dims: Optional[Tuple[int, int, int]] = None,
    dtype: Any = None,
    spacing: Optional[_Triple] = None,
    byte_order: Optional[str] = None,
    array: Optional[str] = None,
) -> Volume:
    """Read a `.raw`, `.vti` or legacy `.vtk` volume as `t2tf optimize` does.

    Raw files named NAME_XxYxZ_DTYPE.raw describe themselves; others need `dims` (x, y, z)
    and `dtype` ("uint16", np.uint16, ...). `byte_order` is "little" or "big"; `array`
    picks a point array of a .vti/.vtk file; `spacing` replaces the file's.
    """

class TransferFunction:
    """Colour and opacity points in data units, in the colour space their file gave."""

    @staticmethod
    def load(
        path: _Path, preset: Optional[str] = None, *, max_preset_size: int = 64 << 20
    ) -> "TransferFunction":
        """Read a ParaView JSON preset (.json), ParaView XML (.xml) or VisIt table (.ct).

        Files larger than ``max_preset_size`` bytes are refused before they are read."""
    @staticmethod
    def from_points(
        rgb_points: npt.ArrayLike,
        opacity_points: npt.ArrayLike = (),
        *,
        name: str = "tf",
        unit_distance: Optional[float] = None,
    ) -> "TransferFunction":
        """From rows (value, r, g, b) and (value, opacity) in data units, ascending, in
        [0, 1]; opacity for `unit_distance` world units (None: the volume's mean spacing)."""
    def save(self, path: _Path) -> None:
        """Write it in the format the extension names (.json, .xml or .ct)."""
    @property
    def name(self) -> str: ...
    @property
    def range(self) -> Tuple[float, float]:
        """(first, last) data value of its points."""
    @property
    def unit_distance(self) -> Optional[float]:
        """ScalarOpacityUnitDistance its opacities are meant for (world units)."""
    @property
    def rgb_points(self) -> np.ndarray:
        """Rows (value, r, g, b), in the preset's colour space."""
    @property
    def opacity_points(self) -> np.ndarray:
        """Rows (value, opacity)."""
    def sample(self, n: int = 256) -> Tuple[np.ndarray, np.ndarray]:
        """`n` values evenly over `range` and RGBA there: ((n,), (n, 4)), RGB colours."""

def render(
    volume: _VolumeLike,
    tf: Union[TransferFunction, _Path],
    *,
    yaw: float = 30.0,
    pitch: float = 10.0,
    distance: float = 2.5,
    size: int = 512,
    up: str = "z",
    background: str = "gray:0.3",
    seed: int = 0,
    unit_distance: Optional[float] = None,
) -> np.ndarray:
    """One view as `t2tf render` draws it: uint8 (size, size, 3), row 0 at the top.

    Angles in degrees, `distance` in bounding radii; `up` is x, y, z, -x, -y or -z;
    `background` is gray, gray:V, white, black, checkerboard, noise or fourier.
    """

class Model:
    """A CLIP model loaded once, to run several optimizations with: what `load_model` returns
    and `optimize(model=...)` takes. `id` is the Hub id or folder it was loaded from."""

    @property
    def id(self) -> str: ...

def load_model(
    model: Optional[_Path] = None,
    *,
    tokenizer: Optional[_Path] = None,
    revision: Optional[str] = None,
    precision: str = "auto",
    max_memory: Optional[_Size] = None,
) -> Model:
    """Load a CLIP model once, to run several optimizations with (`optimize(model=...)`).

    Parameters:
        model: a Hugging Face Hub id (downloaded into the Hugging Face cache on first use)
            or a local folder with config.json, tokenizer.json and the weights; None:
            DEFAULT_MODEL.
        tokenizer: a tokenizer.json to use instead of the model's own; None: its own.
        revision: branch, tag, pull-request ref or commit of a Hub model; None: main.
        precision: number format of CLIP's products: "auto" (bf16 where this CPU has a
            bf16 kernel, AMX or AVX512_BF16, and a calibration kept per CPU measures it
            faster, else f32), "f32" (bit-reproducible) or "bf16".
        max_memory: memory budget for the weights, bytes (int) or a size like "16G";
            None: what the system has.

    Raises ModelError when the model cannot be found or loaded.
    """

def cli_main(argv: Sequence[Union[str, "os.PathLike[str]"]]) -> int:
    """Run the `t2tf` command line on `argv` (program name first) and return its exit status.
    The GIL is released while it runs; an `optimize` run's report.json records `argv`."""

class Result:
    """What `optimize` returns. It holds about 3 MiB, nearly all of it the preview."""

    @property
    def transfer_function(self) -> TransferFunction:
        """The optimized TF in data units, as the written files hold it."""
    @property
    def report(self) -> Dict[str, Any]:
        """What report.json holds (prompt, settings, steps, steps_run, scores, timings)."""
    @property
    def preview(self) -> np.ndarray:
        """The four preview views tiled: uint8 (height, width, 3)."""
    @property
    def steps_run(self) -> int: ...
    @property
    def interrupted(self) -> bool:
        """Whether the run was stopped before its last step."""
    @property
    def camera(self) -> Dict[str, Any]:
        """ParaView camera of the first preview view: position, focal_point, view_up,
        view_angle."""
    def save(self, out_dir: _Path, name: Optional[str] = None) -> Dict[str, Any]:
        """Write the files `t2tf optimize` writes into `out_dir`; returns the report
        written. `name` defaults to the CLI's rule for `--out out_dir` (the folder's name)."""

Progress = Callable[[Dict[str, Any]], Optional[bool]]

@overload
def optimize(  # type: ignore[overload-overlap]  # a str is also a Sequence[str]
    volume: Union[_VolumeLike, "Series"],
    prompt: Optional[str] = None,
    *,
    negatives: Sequence[str] = (),
    steps: int = 300,
    views: int = 3,
    seed: int = 0,
    model: Union[None, _Path, Model] = None,
    tokenizer: Optional[_Path] = None,
    revision: Optional[str] = None,
    precision: str = "auto",
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
    reference_image: Optional[_Path] = None,
    max_memory: Optional[_Size] = None,
    lr: float = 10.0,
    momentum: float = 0.75,
    prior_weight: float = 0.02,
    prior_ab: float = 0.5,
    prior_start: int = 100,
    l1: float = 2e-5,
    l2: float = 8e-4,
    control_points: int = 32,
    negatives_per_step: int = 128,
    negatives_file: Optional[_Path] = None,
    up: str = "z",
    step_size: Optional[float] = None,
    level: Optional[int] = None,
    render_size: Optional[int] = None,
    caption_cache: Union[bool, None, _Path] = True,
    init: Union[None, _Path, TransferFunction] = None,
    preset: Optional[str] = None,
    lock: Sequence[Tuple[float, float]] = (),
) -> Result: ...
@overload
def optimize(
    volume: Union[_VolumeLike, "Series"],
    prompt: Sequence[str],
    *,
    negatives: Sequence[str] = (),
    steps: int = 300,
    views: int = 3,
    seed: int = 0,
    model: Union[None, _Path, Model] = None,
    tokenizer: Optional[_Path] = None,
    revision: Optional[str] = None,
    precision: str = "auto",
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
    reference_image: Optional[_Path] = None,
    max_memory: Optional[_Size] = None,
    lr: float = 10.0,
    momentum: float = 0.75,
    prior_weight: float = 0.02,
    prior_ab: float = 0.5,
    prior_start: int = 100,
    l1: float = 2e-5,
    l2: float = 8e-4,
    control_points: int = 32,
    negatives_per_step: int = 128,
    negatives_file: Optional[_Path] = None,
    up: str = "z",
    step_size: Optional[float] = None,
    level: Optional[int] = None,
    render_size: Optional[int] = None,
    caption_cache: Union[bool, None, _Path] = True,
    init: Union[None, _Path, TransferFunction] = None,
    preset: Optional[str] = None,
    lock: Sequence[Tuple[float, float]] = (),
) -> List[Result]:
    """Optimize a transfer function so renderings of `volume` match `prompt` (Algorithm 1 with
    the paper's defaults; each keyword is the `t2tf optimize` flag of that name).

    Returns a Result; a list of prompts returns a list of Results, one run per prompt with
    the model and the volume loaded once (the same seed gives each prompt the TF of its own
    run).

    Parameters:
        volume: a Volume, a volume file's path (read as read_volume reads it), a 3-D
            array indexed [z, y, x], or a Series (one TF for all its steps).
        prompt: what the renderings should show, e.g. "a potted tree"; or a list of them.
        negatives: captions to suppress; empty: "a blank image".
        steps: SGD steps; 0: the result is the start (the initialization, or init).
        views: random views per step, their gradients averaged.
        seed: seed of the views, backgrounds, negatives and initial colours.
        model: a Hub id, a local model folder or a loaded Model; None: DEFAULT_MODEL. A
            run of 0 steps from an init with opacity loads none.
        tokenizer: a tokenizer.json to use instead of the model's own.
        revision: branch, tag, pull-request ref or commit of a Hub model; None: main.
        precision: number format of CLIP's products: "auto" (the default: bf16 where this
            CPU runs it faster, else f32), "f32" (bit-reproducible) or "bf16".
        threads: worker threads; None: one per CPU. The same volume, settings, seed and
            threads give the CLI's TF bit for bit.
        progress: a function called with a dict per event (see below); returning False
            stops the run.
        reference_image: a PNG whose CLIP embedding is matched instead of a prompt.
        max_memory: memory budget, bytes (int) or a size like "16G"; None: what the
            system has.
        init: a TF to start from instead of the paper's initialization: a TF file's path
            or a TransferFunction (such as an earlier result's).
        preset: the preset of init's file to start from, when it holds several.
        lock: data ranges [(min, max), ...] whose TF stays as it starts.
        lr: initial learning rate, annealed linearly to 0.
        momentum: SGD momentum, in [0, 1).
        prior_weight: weight of the Beta prior on the rays' final transmittance.
        prior_ab: a = b of the Beta(a, b) prior; below 1 favours clear or opaque rays.
        prior_start: first step (0-based) with the prior switched on.
        l1: weight of the L1 term on the control points' densities.
        l2: weight of the L2 term pulling colours towards 0.5.
        control_points: control points of the TF.
        negatives_per_step: negatives drawn from the caption pool per step.
        negatives_file: a caption file (one per line) replacing the built-in pool.
        up: the world axis pointing up in the views: x, y, z, -x, -y or -z.
        step_size: ray-marching step in voxels; None: the renderer's.
        level: mip level to render from (0: full resolution); None: chosen from the
            pixel size.
        render_size: cast rays at this image side and upsample to CLIP's; None: CLIP's
            size.
        caption_cache: the folder caption embeddings are cached in; True: the user's
            cache folder; False or None: not cached.

    Progress events: {"event": "phase", "phase": ...} as a phase begins; after each step
    {"event": "step", "step": 1-based, "total": the run's steps, "loss": the loss, and its
    parts "clip", "prior", "l1", "l2", with "prompt_probability", "lr", ...};
    {"event": "warning", "message": ...}; and while a model downloads (files of 10 MiB or
    more), {"event": "download", "file": ..., "state": "started" | "progress" | "finished" |
    "stopped", "done": bytes, "total": bytes or None}, which cannot stop the download
    (without a callback, downloads are shown on stderr). Returning False stops the run after that step
    and the partial result is returned (its `interrupted` is True). Ctrl-C, or an exception
    raised by `progress`, also stops the run after the current step and is then raised;
    the partial result is dropped.
    """
