"""VTK image data as a t2tf volume, without writing a file (ParaView, pvpython, PyVista).

Only `vtkmodules.util.numpy_support` is needed, so this works with ParaView's own VTK.
"""
from . import Volume


def volume_from_vtk(image, array=None):
    """A `Volume` over one point array of a `vtkImageData` (default: the active scalars,
    else the first array). The array is read in place where its type allows: the volume
    keeps the VTK array's memory alive through NumPy, so the image may be dropped."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    point_data = image.GetPointData()
    if array is None:
        scalars = point_data.GetScalars()
        data = scalars if scalars is not None else point_data.GetArray(0)
    else:
        data = point_data.GetArray(array)
    if data is None:
        named = " %r" % array if array is not None else ""
        raise ValueError("the image has no point array" + named)
    if data.GetNumberOfComponents() != 1:
        raise ValueError("point array %r has %d components; t2tf needs one"
                         % (data.GetName(), data.GetNumberOfComponents()))
    nx, ny, nz = image.GetDimensions()
    values = vtk_to_numpy(data).reshape(nz, ny, nx)
    extent = image.GetExtent()
    spacing = image.GetSpacing()
    # Point (i, j, k) of the extent sits at origin + (i, j, k) * spacing: the first point's
    # position is the volume's origin.
    origin = tuple(image.GetOrigin()[a] + extent[2 * a] * spacing[a] for a in range(3))
    return Volume(values, spacing=tuple(spacing), origin=origin)
