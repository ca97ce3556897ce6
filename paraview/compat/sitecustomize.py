"""Lets ParaView 5.11.0 load Python plugins on Python >= 3.11.

That ParaView's paraview/detail/pythonalgorithm.py (which every Python plugin goes through)
does `from inspect import getargspec`, a function Python 3.11 removed, so loading any Python
plugin fails. It only reads `.args`, which getfullargspec also gives. Put this folder on
PYTHONPATH before starting paraview, pvpython, pvbatch or pvserver; Python imports this file
at start-up, and it then runs the next sitecustomize on the path (e.g. the distribution's).
"""
import inspect
import os
import sys

if not hasattr(inspect, "getargspec"):
    inspect.getargspec = inspect.getfullargspec


def _chain():
    here = os.path.dirname(os.path.abspath(__file__))
    for folder in sys.path:
        path = os.path.join(folder or ".", "sitecustomize.py")
        if os.path.abspath(folder or ".") != here and os.path.isfile(path):
            with open(path) as f:
                exec(compile(f.read(), path, "exec"), {"__name__": "sitecustomize", "__file__": path})
            return


_chain()
