"""What t2tf reads from ParaView: the input image and its array, the input's own file when
t2tf can read that file itself, and digests of everything a run depends on (a result is
reused only when they match)."""
import hashlib
import json
import os

from vtkmodules.vtkCommonDataModel import vtkImageData

from .errors import T2tfError

# Data classes t2tf can read (ParaView's data information names them).
IMAGE_CLASSES = ("vtkImageData", "vtkUniformGrid", "vtkStructuredPoints")


def not_image(class_name):
    """The error for input that is not image data."""
    return T2tfError("the input is a %s, not image data (vtkImageData): resample it first, "
                     "e.g. with Resample To Image" % class_name, "volume")


def on_server():
    """Whether this process is a pvserver (or one of its ranks)."""
    from paraview.modules.vtkRemotingCore import vtkProcessModule

    pm = vtkProcessModule.GetProcessModule()
    return pm is not None and pm.GetProcessType() in (
        vtkProcessModule.PROCESS_SERVER, vtkProcessModule.PROCESS_DATA_SERVER,
        vtkProcessModule.PROCESS_RENDER_SERVER)


def proxy_of(algorithm):
    """The source proxy whose VTK object is `algorithm` (builtin session), else None."""
    from paraview import servermanager

    if servermanager.ActiveConnection is None:
        return None
    for proxy in servermanager.ProxyManager().GetProxiesInGroup("sources").values():
        try:
            if proxy.GetClientSideObject() is algorithm:
                return proxy
        except AttributeError:
            continue
    return None


def active_array(source):
    """The point array a source proxy colours by (else its first)."""
    info = source.GetPointDataInformation()
    if info.GetNumberOfArrays() == 0:
        raise T2tfError("the input has no point array to optimize a transfer function for",
                        "volume", "array")
    try:
        active = source.PointData.keys()
    except AttributeError:
        active = []
    return active[0] if active else info.GetArray(0).GetName()


def _text(value):
    """An enumeration property's text (its GetData()), else the value as text."""
    return str(value.GetData() if hasattr(value, "GetData") else value)


_RAW_TYPES = {"unsigned char": "uint8", "char": "int8", "unsigned short": "uint16",
              "short": "int16", "unsigned int": "uint32", "int": "int32", "float": "float32",
              "double": "float64"}


def upstream_file(proxy):
    """(path, t2tf flags) when the filter `proxy`'s input is a file t2tf reads as ParaView
    does (a .vti, a raw file of one component from its origin), else None."""
    try:
        reader = proxy.Input
        name = reader.GetXMLName()
    except AttributeError:
        return None
    if name == "XMLImageDataReader":
        names = list(reader.FileName)  # a FileNameProperty, not a str
        if len(names) == 1 and names[0].lower().endswith(".vti"):
            return (names[0], [])
        return None
    if name == "ImageReader" and len(list(reader.FileNames)) == 1:
        dtype = _RAW_TYPES.get(_text(reader.DataScalarType))
        e = list(reader.DataExtent)
        # FileDimensionality is an enumeration property: compare its text.
        if (dtype is None or reader.NumberOfScalarComponents != 1
                or _text(reader.FileDimensionality) != "3"
                or any(e[i] != 0 for i in (0, 2, 4)) or any(reader.DataOrigin)):
            return None
        dims = "%d,%d,%d" % (e[1] + 1, e[3] + 1, e[5] + 1)
        spacing = ",".join(repr(float(s)) for s in reader.DataSpacing)
        order = "big" if _text(reader.DataByteOrder) == "BigEndian" else "little"
        return (list(reader.FileNames)[0],
                ["--dims", dims, "--dtype", dtype, "--spacing", spacing, "--byte-order", order])
    return None


def write_vti(image, array, path):
    """The image with only `array` (as its scalars) as a .vti file t2tf reads."""
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    copy = vtkImageData()
    copy.SetExtent(image.GetExtent())
    copy.SetOrigin(image.GetOrigin())
    copy.SetSpacing(image.GetSpacing())
    copy.GetPointData().SetScalars(image.GetPointData().GetArray(array))
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(path)
    writer.SetInputData(copy)
    if not writer.Write():
        raise T2tfError("could not write the input to " + path, "io")


def write_series(series, array, folder):
    """The time steps [(time, image), ...] as one .vti per step and `input.vti.series` (the
    file series JSON that t2tf and ParaView read, names relative to it) in `folder`; returns
    the .series file's path."""
    files = []
    for i, (time, image) in enumerate(series):
        name = "input_%04d.vti" % i
        write_vti(image, array, os.path.join(folder, name))
        files.append({"name": name, "time": float(time)})
    path = os.path.join(folder, "input.vti.series")
    with open(path, "w") as f:
        json.dump({"file-series-version": "1.0", "files": files}, f, indent=1)
    return path


def image_digest(image, array):
    """A digest of what t2tf would read: geometry, array name and values."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    import numpy

    h = hashlib.sha256()
    h.update(repr((image.GetExtent(), image.GetSpacing(), image.GetOrigin(), array)).encode())
    values = numpy.ascontiguousarray(vtk_to_numpy(image.GetPointData().GetArray(array)))
    h.update(str(values.dtype).encode())
    h.update(memoryview(values).cast("B"))
    return h.hexdigest()


def file_digest(path):
    """The SHA-256 of a file's bytes; the text itself when it names no file (empty, or a
    file that is not there: the run will say so)."""
    if not path or not os.path.isfile(path):
        return path
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def folder_digest(path):
    """A local model folder by its files' names, sizes and modification times (weights are
    large: not read); a Hub id as itself."""
    if not path or not os.path.isdir(path):
        return path
    files = []
    for name in sorted(os.listdir(path)):
        st = os.stat(os.path.join(path, name))
        files.append((name, st.st_size, st.st_mtime_ns))
    return [os.path.abspath(path), files]


def key(values):
    """The key a stored result must match: a digest of `values` (JSON)."""
    return hashlib.sha256(json.dumps(values).encode()).hexdigest()
