"""A result shown in ParaView: the array's colour and opacity functions set to t2tf's points
(never rescaled), the display as a volume with t2tf's unit distance, optionally t2tf's camera
(joining the undo set of the GUI's Apply), and the functions ParaView has now read back as the
start of a Refine."""
from .errors import T2tfError
from .results import UNIT_DISTANCE_KEY

# The view properties apply_camera sets, in the order an undo restores them.
CAMERA_PROPERTIES = ("CameraPosition", "CameraFocalPoint", "CameraViewUp", "CameraViewAngle",
                     "CameraParallelProjection")


def _text(value):
    return str(value.GetData() if hasattr(value, "GetData") else value)


def apply_transfer_function(result, array):
    """Set the array's colour and opacity functions to t2tf's points, never rescaled."""
    import paraview.simple as pvs

    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    lut.AutomaticRescaleRangeMode = "Never"
    lut.ColorSpace = "RGB"
    lut.RGBPoints = result["rgb"]
    lut.ScalarRangeInitialized = 1
    if result["points"]:
        pwf.Points = result["points"]
        pwf.ScalarRangeInitialized = 1
    return lut, pwf


def show_volume(disp, result, array):
    """`disp` as a volume coloured by `array` with the result's functions and unit distance.
    The colour array and functions are set as properties, not through ColorBy: ColorBy
    rescales a new colour map to the display's data range, which a display registered by a
    loading state does not know yet ("Could not determine array range."), and t2tf's map is
    never rescaled anyway."""
    disp.Representation = "Volume"
    disp.ColorArrayName = ["POINTS", array]
    lut, pwf = apply_transfer_function(result, array)
    disp.LookupTable = lut
    disp.ScalarOpacityFunction = pwf
    if result.get("unit_distance") is not None:
        disp.ScalarOpacityUnitDistance = float(result["unit_distance"])


def apply_to_display(result, source, view=None, array=None, camera=True):
    """Show `source` as a volume in `view` with t2tf's TF, unit distance and (optionally)
    camera. Returns the display."""
    import paraview.simple as pvs

    view = view or pvs.GetActiveViewOrCreate("RenderView")
    array = array or result.get("array")
    disp = pvs.GetDisplayProperties(source, view)
    disp.Representation = "Volume"
    pvs.ColorBy(disp, ("POINTS", array))
    show_volume(disp, result, array)
    if camera and result.get("camera"):
        apply_camera(result["camera"], view)
    return disp


def apply_camera(cam, view):
    """Set `view`'s camera to `cam`. Inside an undo set (the GUI's Apply), the change joins
    it: ParaView's undo stack leaves camera proxies out of its records, so without this
    Undo Apply would keep t2tf's camera."""
    undo = _camera_undo_elements(view)
    view.CameraPosition = cam["position"]
    view.CameraFocalPoint = cam["focal_point"]
    view.CameraViewUp = cam["view_up"]
    view.CameraViewAngle = cam["view_angle"]
    view.CameraParallelProjection = 0
    if undo is not None:
        undo()


def _camera_undo_elements(view):
    """Where an undo stack builder listens (ParaView's GUI), note the camera properties of
    `view` now and return a function that notes them again and adds both notes to the undo
    set being recorded (the builder keeps them only while one is, e.g. during Apply); else
    None. An undo set undoes its elements last to first and redoes them first to last, so
    Undo ends on the camera noted first and Redo on the one noted second (the pattern of
    ParaView's own camera undo, vtkSMInteractionUndoStackBuilder)."""
    from paraview import servermanager

    try:
        builder = servermanager.vtkSMProxyManager.GetProxyManager().GetUndoStackBuilder()
    except AttributeError:
        return None
    if builder is None or builder.GetIgnoreAllChanges():
        return None
    proxy = view.SMProxy
    try:
        proxy.SynchronizeCameraProperties()  # the camera as shown, after any interaction
    except AttributeError:
        pass

    def note():
        elements = []
        for name in CAMERA_PROPERTIES:
            element = servermanager.vtkSMPropertyModificationUndoElement()
            element.ModifiedProperty(proxy, name)
            elements.append(element)
        return elements

    before = note()

    def finish():
        for element in before + note():
            builder.Add(element)

    return finish


def current_tf(array, source=None):
    """The colour and opacity functions ParaView now uses for `array` (and the unit distance
    of `source`'s display), as a ParaView JSON preset: the start of a Refine."""
    import paraview.simple as pvs

    lut = pvs.GetColorTransferFunction(array)
    pwf = pvs.GetOpacityTransferFunction(array)
    rgb, points = list(lut.RGBPoints), list(pwf.Points)
    if len(rgb) < 8 or len(points) < 8:
        raise T2tfError("Refine: %s has no colour and opacity function to start from" % array)
    space = _text(lut.ColorSpace)
    preset = {"Name": "current", "ColorSpace": space, "RGBPoints": rgb, "Points": points}
    if space == "HSV":
        preset["HSVWrap"] = int(lut.HSVWrap)
    if source is not None:
        disp = pvs.GetDisplayProperties(source)
        preset[UNIT_DISTANCE_KEY] = float(disp.ScalarOpacityUnitDistance)
    return preset
