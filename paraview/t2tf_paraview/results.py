"""A run's result, read into memory from the files t2tf wrote (their folder is removed after
the run): the preset (named after the prompt), its colour and opacity points, the unit
distance, t2tf's camera and the report. Saved states keep this dictionary as JSON."""
import json
import os
import re

from .errors import T2tfError

UNIT_DISTANCE_KEY = "t2tfScalarOpacityUnitDistance"
# Every preset this plugin registers starts with this, so remove_presets() finds them.
PRESET_PREFIX = "t2tf: "


def preset_name(prompt, reference_image=None):
    """The preset's name: "t2tf: " and the prompt (whitespace collapsed, cut at 60
    characters), so Choose Preset shows what each result was made for."""
    what = " ".join((prompt or "").split())
    if not what and reference_image:
        what = "like " + os.path.basename(reference_image)
    if len(what) > 60:
        what = what[:59] + "…"
    return PRESET_PREFIX + (what or "transfer function")


def _script_list(text, name):
    for line in text.splitlines():
        if line.startswith(name + " = "):
            return json.loads(line[len(name) + 3:])
    return None


def _camera(script):
    """The camera t2tf's generated pvpython script sets, or None."""
    with open(script) as f:
        text = f.read()
    cam = {k: _script_list(text, "CAMERA_" + k.upper())
           for k in ("position", "focal_point", "view_up")}
    angle = re.search(r"^CAMERA_VIEW_ANGLE = (.+)$", text, re.M)
    if not (all(cam.values()) and angle):
        return None
    cam["view_angle"] = float(angle.group(1))
    return cam


def read(out, files, interrupted, prompt="", reference_image=None):
    """The result of a run that wrote `files` into the folder `out`."""
    preset_file = next((os.path.join(out, f) for f in files
                        if f.endswith(".json") and f != "report.json"), None)
    if preset_file is None:
        raise T2tfError("t2tf wrote no preset in " + out)
    with open(preset_file) as f:
        data = json.load(f)
    preset = data[0] if isinstance(data, list) else data
    preset["Name"] = preset_name(prompt, reference_image)
    result = {
        "name": preset["Name"],
        "preset": preset,
        "rgb": [float(v) for v in preset["RGBPoints"]],
        "points": [float(v) for v in preset.get("Points", [])],
        "unit_distance": preset.get(UNIT_DISTANCE_KEY),
        "interrupted": bool(interrupted),
        "camera": None,
        "report": "",
    }
    report = os.path.join(out, "report.json")
    if os.path.exists(report):
        with open(report) as f:
            result["report"] = f.read()
    script = next((os.path.join(out, f) for f in files if f.endswith("_paraview.py")), None)
    if script:
        result["camera"] = _camera(script)
    return result
