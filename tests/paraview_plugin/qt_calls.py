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
