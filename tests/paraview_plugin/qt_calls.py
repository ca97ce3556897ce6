"""Qt and ParaView GUI functions called through ctypes, for the GUI startup scripts
(gui_presets.py, gui_undo.py): ParaView's Python has no Qt bindings. The process's own
symbols (`ctypes.PyDLL(None)`: calls hold the GIL, as they may push properties to a Python
algorithm), looked up by their Itanium C++ names."""
import ctypes

lib = ctypes.PyDLL(None)


def function(name, restype, *argtypes):
    """The symbol `name` as a function of these result and argument types."""
    f = getattr(lib, name)
    f.restype, f.argtypes = restype, list(argtypes)
    return f


def qstring(text):
    """A QString (one pointer: 8 bytes) made by QString::fromUtf8; None gives a null one.
    Pass it where a function takes a QString by value or by const reference: either way
    the C++ ABI passes the object's address, which this array gives."""
    data = text.encode() if text is not None else None
    buf = (ctypes.c_void_p * 1)()
    function("_ZN7QString15fromUtf8_helperEPKci", ctypes.c_void_p, ctypes.c_void_p,
             ctypes.c_char_p, ctypes.c_int)(ctypes.byref(buf), data, len(data or b""))
    return buf


# ---- widgets and real input, for the GUI tests that click ----------------------------------

FIND_RECURSIVELY = 1  # Qt::FindChildrenRecursively


def meta(name):
    """The address of a class's staticMetaObject, e.g. meta("_ZN11QToolButton16staticMetaObjectE")."""
    return ctypes.addressof(ctypes.c_void_p.in_dll(lib, name))


def find_child(parent, name, meta_name):
    """The first descendant of `parent` of that class and object name (None: any name)."""
    find = function("_Z20qt_qFindChild_helperPK7QObjectRK7QStringRK11QMetaObject6QFlagsIN2Qt15"
                    "FindChildOptionEE", ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                    ctypes.c_void_p, ctypes.c_int)
    return find(parent, ctypes.byref(qstring(name)), meta(meta_name), FIND_RECURSIVELY)


def find_children(parent, meta_name):
    """Every descendant of `parent` of that class. The QList<void*> is one pointer to its
    data (ref, alloc, begin, end as ints, then the items), starting as Qt's shared empty
    list; its memory is not released."""
    find = function("_Z23qt_qFindChildren_helperPK7QObjectRK7QStringRK11QMetaObjectP5QListIPvE"
                    "6QFlagsIN2Qt15FindChildOptionEE", None, ctypes.c_void_p, ctypes.c_void_p,
                    ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int)
    found = (ctypes.c_void_p * 1)(ctypes.addressof(ctypes.c_char.in_dll(
        lib, "_ZN9QListData11shared_nullE")))
    find(parent, ctypes.byref(qstring(None)), meta(meta_name), ctypes.byref(found),
         FIND_RECURSIVELY)
    data = found[0]
    begin, end = ctypes.c_int.from_address(data + 8).value, ctypes.c_int.from_address(data + 12).value
    return [ctypes.c_void_p.from_address(data + 16 + 8 * i).value for i in range(begin, end)]


def read_qstring(buf):
    """The text of a QString (one pointer to QArrayData: ref, size, alloc, then the offset of
    the UTF-16 characters from the header)."""
    d = buf[0]
    size = ctypes.c_int.from_address(d + 4).value
    offset = ctypes.c_ssize_t.from_address(d + 16).value
    return ctypes.string_at(d + offset, 2 * size).decode("utf-16-le")


def label_text(label):
    """QLabel::text(): a QString returned by value, through the hidden result pointer."""
    buf = (ctypes.c_void_p * 1)()
    function("_ZNK6QLabel4textEv", None, ctypes.c_void_p, ctypes.c_void_p)(
        ctypes.byref(buf), label)
    return read_qstring(buf)


def visible(widget):
    """QWidget::isVisible() (inline in Qt 5): isVisibleTo(nullptr) is the same."""
    return bool(function("_ZNK7QWidget11isVisibleToEPKS_", ctypes.c_bool, ctypes.c_void_p,
                         ctypes.c_void_p)(widget, None))


def enabled(widget):
    """QWidget::isEnabled() (inline in Qt 5): isEnabledTo(nullptr) is the same."""
    return bool(function("_ZNK7QWidget11isEnabledToEPKS_", ctypes.c_bool, ctypes.c_void_p,
                         ctypes.c_void_p)(widget, None))


def main_window():
    return function("_ZN15pqCoreUtilities14findMainWindowEv", ctypes.c_void_p)()


def process_events(seconds):
    """Run the GUI's event loop for `seconds` (QCoreApplication::processEvents, 50 ms at a
    time), as it runs between a script's statements only when something calls it."""
    import time
    process = function("_ZN16QCoreApplication13processEventsE6QFlagsIN10QEventLoop17"
                       "ProcessEventsFlagEEi", None, ctypes.c_int, ctypes.c_int)
    end = time.time() + seconds
    while time.time() < end:
        process(0, 50)


class _Point(ctypes.Structure):
    _fields_ = [("x", ctypes.c_int), ("y", ctypes.c_int)]


class _Rect(ctypes.Structure):
    _fields_ = [("x1", ctypes.c_int), ("y1", ctypes.c_int), ("x2", ctypes.c_int),
                ("y2", ctypes.c_int)]


def screen_center(widget):
    """The centre of `widget` on the screen (QWidget::frameGeometry, then mapToGlobal)."""
    rect = function("_ZNK7QWidget13frameGeometryEv", _Rect, ctypes.c_void_p)(widget)
    local = _Point((rect.x2 - rect.x1 + 1) // 2, (rect.y2 - rect.y1 + 1) // 2)
    return function("_ZNK7QWidget11mapToGlobalERK6QPoint", _Point, ctypes.c_void_p,
                    ctypes.c_void_p)(widget, ctypes.byref(local))


class X11:
    """Real input through the X server (the XTEST extension, as xdotool sends it): the
    events reach ParaView through its own X connection, like a user's."""

    def __init__(self):
        self.x = ctypes.CDLL("libX11.so.6")
        self.xtst = ctypes.CDLL("libXtst.so.6")
        self.x.XOpenDisplay.restype = ctypes.c_void_p
        self.x.XOpenDisplay.argtypes = [ctypes.c_char_p]
        self.x.XFlush.argtypes = [ctypes.c_void_p]
        self.x.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
        self.xtst.XTestFakeMotionEvent.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int,
                                                   ctypes.c_int, ctypes.c_ulong]
        self.xtst.XTestFakeButtonEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int,
                                                   ctypes.c_ulong]
        self.display = self.x.XOpenDisplay(None)
        if not self.display:
            raise RuntimeError("cannot open the X display")

    def move_to(self, widget):
        """Move the pointer to the middle of `widget`; returns the screen point."""
        p = screen_center(widget)
        self.xtst.XTestFakeMotionEvent(self.display, -1, p.x, p.y, 0)
        self.x.XSync(self.display, 0)
        return [p.x, p.y]

    def press(self):
        """Click the left button where the pointer is (released 30 ms later)."""
        self.xtst.XTestFakeButtonEvent(self.display, 1, 1, 0)
        self.xtst.XTestFakeButtonEvent(self.display, 1, 0, 30)
        self.x.XSync(self.display, 0)

    def click(self, widget):
        """Move the pointer to the middle of `widget` and click there, when the GUI is idle
        (a run's event pumping wants the pointer there before the press: see move_to and
        press)."""
        point = self.move_to(widget)
        self.press()
        return point

    def close_window(self, widget):
        """Ask the window manager's way for `widget`'s window to close: a WM_DELETE_WINDOW
        client message, what a window's close button sends."""
        class ClientMessage(ctypes.Structure):
            _fields_ = [("type", ctypes.c_int), ("serial", ctypes.c_ulong),
                        ("send_event", ctypes.c_int), ("display", ctypes.c_void_p),
                        ("window", ctypes.c_ulong), ("message_type", ctypes.c_ulong),
                        ("format", ctypes.c_int), ("data", ctypes.c_long * 5),
                        ("pad", ctypes.c_long * 12)]
        self.x.XInternAtom.restype = ctypes.c_ulong
        self.x.XInternAtom.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int]
        self.x.XSendEvent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int,
                                      ctypes.c_long, ctypes.c_void_p]
        window = function("_ZNK7QWidget5winIdEv", ctypes.c_ulong, ctypes.c_void_p)(widget)
        event = ClientMessage()
        event.type = 33  # ClientMessage
        event.display = self.display
        event.window = window
        event.message_type = self.x.XInternAtom(self.display, b"WM_PROTOCOLS", 0)
        event.format = 32
        event.data[0] = self.x.XInternAtom(self.display, b"WM_DELETE_WINDOW", 0)
        event.data[1] = 0  # CurrentTime
        self.x.XSendEvent(self.display, window, 0, 0, ctypes.byref(event))
        self.x.XSync(self.display, 0)
