"""What the client (the GUI, pvpython) does after a Text To Transfer Function filter updates.

The filter's RequestData only computes; ParaView creates a filter's display after its first
update, and the GUI state belongs to the client, so the result is shown from here, on the
filter proxy's UpdateDataEvent: the preset is registered (replacing the filter's previous
one), the array's functions set, each display of the filter (now and as they appear) made a
volume with the TF and, with Apply Camera, the view given t2tf's camera; the Result property
(saved with a state) and the Time Estimate follow, and the Model and Tokenizer of a run that
worked become the defaults of new filters.

In a client-server session the filter's algorithm runs on the server, where it passes the
data through; here the client runs t2tf on a bounded proxy of the filter's input (remote.py)
when the filter updates with settings or data it has not run for, once per Apply: a render or
an update with the same settings runs nothing, and none starts while one runs.
"""
import json

from . import display, inputs, presets, remote
from .errors import T2tfError, say


class _Filter:
    """What the client did for one filter proxy: the result it shows (the displays that have
    it, whether they get t2tf's camera), the preset its last result registered, and, for a
    remote filter, the settings and data it last ran for."""

    def __init__(self, proxy, is_remote):
        self.proxy = proxy  # the servermanager proxy
        self.remote = is_remote
        self.result = None
        self.camera = False
        self.displays = set()  # global ids of the displays that show the result
        self.preset = None
        self.key = None


_started = False
_sessions = []  # session proxy managers observed, each with its filters (global id -> _Filter)
_running = False  # a client-side run is under way: no update starts another


def start():
    """In a client process: follow the sessions, so that each session's filters are
    watched. Once per process (the package is imported once)."""
    global _started
    from paraview import servermanager

    if _started or inputs.on_server():
        return
    pxm = servermanager.vtkSMProxyManager.GetProxyManager()
    if pxm is None:
        return
    _started = True
    pxm.AddObserver(servermanager.vtkSMProxyManager.ActiveSessionChanged,
                    lambda *_: _guarded(_on_session))
    _on_session()


def _on_session():
    from paraview import servermanager

    spxm = servermanager.vtkSMProxyManager.GetProxyManager().GetActiveSessionProxyManager()
    if spxm is None or any(s is spxm for s, _ in _sessions):
        return
    filters = {}
    _sessions.append((spxm, filters))
    spxm.AddObserver("RegisterEvent", lambda obj, _e: _guarded(_on_register, obj, filters))
    spxm.AddObserver("UnRegisterEvent", lambda obj, _e: _guarded(_forget_deleted, obj, filters))


def _guarded(call, *args):
    """An observer's work: a problem is one line, never a traceback from VTK's callback."""
    try:
        call(*args)
    except T2tfError as e:
        say(str(e))
    except Exception as e:  # a bug of ours: still one line
        say("internal error: %s: %s" % (type(e).__name__, e))


def _filter_proxies(spxm):
    """The session's TextToTransferFunction proxies (vtkSMProxy), by global id."""
    found = {}
    for i in range(spxm.GetNumberOfProxies("sources")):
        proxy = spxm.GetProxy("sources", spxm.GetProxyName("sources", i))
        if proxy is not None and proxy.GetXMLName() == "TextToTransferFunction":
            found[proxy.GetGlobalIDAsString()] = proxy
    return found


def _on_register(spxm, filters):
    """Watch the session's filters not watched yet (a register event does not say which
    proxy it is for in Python: the sources are few), then give new displays their result."""
    from paraview import servermanager

    session = spxm.GetSession()
    is_remote = session is not None and session.IsA("vtkSMSessionClient")
    for gid, smproxy in _filter_proxies(spxm).items():
        if gid not in filters:
            filters[gid] = _Filter(servermanager._getPyProxy(smproxy), is_remote)
            smproxy.AddObserver("UpdateDataEvent",
                                lambda obj, _e: _guarded(_on_update, obj, filters))
    _show_on_displays()


def _forget_deleted(spxm, filters):
    """Drop the records of the filters no longer registered (deleted ones)."""
    live = _filter_proxies(spxm)
    for gid in [g for g in filters if g not in live]:
        del filters[gid]


def _on_update(smproxy, filters):
    """After a filter's update: show a new result of its own (builtin), or run t2tf for it
    here (remote)."""
    state = filters.get(smproxy.GetGlobalIDAsString())
    if state is None:
        return
    if state.remote:
        _run_remote(state)
        return
    algorithm = smproxy.GetClientSideObject()
    result = getattr(algorithm, "result", None)
    if result is None or result is state.result:
        return  # a failure (said by the filter) or the result already shown
    proxy = state.proxy
    # A result restored from a state keeps the state's own camera.
    _show(state, result, bool(proxy.ApplyCamera) and not algorithm.restored,
          state.preset or result.get("replaces"))
    # The hidden Result property, which a state saves: set on the proxy only (not pushed, not
    # marked for Apply), as the algorithm has it already.
    smproxy.GetProperty("Result").SetElement(0, json.dumps(algorithm.stored))
    if not algorithm.reused:
        _remember_model(proxy)
    # The panel reads Time Estimate again only after an Apply, which may come before this.
    smproxy.UpdatePropertyInformation(smproxy.GetProperty("TimeEstimate"))


def _run_remote(state):
    global _running
    import paraview.simple as pvs

    if _running:
        return
    key = remote.filter_key(state.proxy)
    if state.key == key:
        return
    state.key = key
    _running = True
    try:
        result = remote.run_filter(state.proxy)
    finally:
        _running = False
    _remember_model(state.proxy)
    _show(state, result, bool(state.proxy.ApplyCamera), state.preset)
    for view in pvs.GetViews():
        view.StillRender()


def _show(state, result, camera, replaces):
    presets.register(result, replaces)
    state.preset = result["name"]
    display.apply_transfer_function(result, result["array"])
    state.result, state.camera, state.displays = result, camera, set()
    _show_on_displays()


def _show_on_displays():
    """Give each display of a watched filter its filter's result, once. Displays are found
    among registered representations (not through views: ParaView registers a new display
    before adding it to its view)."""
    shown = [f for _, filters in _sessions for f in filters.values() if f.result is not None]
    if not shown:
        return
    # Imported only now: importing paraview.simple from the register events of the GUI's
    # start-up (its Filters menu being built) crashes ParaView 5.11.
    import paraview.simple as pvs
    from paraview import servermanager

    reprs = servermanager.ProxyManager().GetProxiesInGroup("representations").values()
    for state in shown:
        for disp in reprs:
            try:
                if disp.Input.SMProxy is not state.proxy.SMProxy:
                    continue
                disp.ScalarOpacityUnitDistance
            except AttributeError:
                continue  # not a display of this filter, or not a 3D one
            key = disp.GetGlobalIDAsString()
            if key in state.displays:
                continue
            state.displays.add(key)
            display.show_volume(disp, state.result, state.result["array"])
            if state.camera and state.result.get("camera"):
                for view in pvs.GetViews():
                    if view.GetXMLName() == "RenderView":
                        display.apply_camera(state.result["camera"], view)


def _remember_model(proxy):
    """Keep the Model and Tokenizer of a run that worked as the defaults of new filters, in
    ParaView's user settings (saved at exit, read by the next session)."""
    from paraview import servermanager

    settings = servermanager.vtkSMSettings.GetInstance()
    for name in ("Model", "Tokenizer"):
        settings.SetSetting("filters.TextToTransferFunction." + name,
                            getattr(proxy, name) or "")
