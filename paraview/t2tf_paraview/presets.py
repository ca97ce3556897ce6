"""Results as presets in ParaView's preset manager ("t2tf: PROMPT"), in the groups of the
Choose Preset dialog.

ParaView 5.11's Choose Preset opens on the group "Default" and lists only its presets, so a
preset joins "Default" and "User" as one imported in the dialog does. The groups belong to the
GUI's pqPresetGroupsManager, which saves them to the setting TransferFunctionPresets.Groups
on every change and reads it at start-up. In the GUI the manager is called (native.py), so
the open dialog and the saved setting follow; in pvpython and pvbatch the setting is edited
where a GUI saved one (where none was, the next GUI start loads its built-in groups, which
cannot be written here without their list, and the preset shows under "All").
"""
import json

from . import native
from .errors import say
from .results import PRESET_PREFIX

GROUPS = ("Default", "User")
SETTING = "TransferFunctionPresets.Groups"


def _presets():
    from paraview import servermanager

    return servermanager.vtkSMTransferFunctionPresets.GetInstance()


def _remove(presets, name):
    """Remove the user presets called `name` (never a built-in one)."""
    removed = 0
    for i in reversed(range(presets.GetNumberOfPresets())):
        if presets.GetPresetName(i) == name and not presets.IsPresetBuiltin(i):
            presets.RemovePreset(i)
            removed += 1
    return removed


def register(result, replaces=None):
    """Add the result under its name, replacing a preset of that name and `replaces` (the
    name the same filter's previous run registered), so a re-run updates its preset instead
    of adding another. The old one is removed first: adding a name that exists is fragile in
    ParaView 5.10 and later."""
    presets = _presets()
    for name in {result["name"], replaces} - {None}:
        _remove(presets, name)
        _leave_groups(name)
    presets.AddPreset(result["name"], json.dumps(result["preset"]))
    _join_groups(result["name"])
    return bool(presets.HasPreset(result["name"]))


def remove_all():
    """Remove every preset this plugin registered ("t2tf: ..."); returns how many."""
    presets = _presets()
    names = {presets.GetPresetName(i) for i in range(presets.GetNumberOfPresets())
             if not presets.IsPresetBuiltin(i)}
    removed = 0
    for name in names:
        if name.startswith(PRESET_PREFIX):
            removed += _remove(presets, name)
            _leave_groups(name)
    return removed


def _join_groups(name):
    try:
        manager = native.preset_group_manager()
        if not (manager and all(native.add_to_group(manager, g, name) for g in GROUPS)):
            _edit_setting(name, add=True)
    except Exception as e:  # the preset is there; only its group is missing
        say("could not add %s to the preset groups: %s" % (name, e), False)


def _leave_groups(name):
    try:
        manager = native.preset_group_manager()
        if not (manager and native.remove_from_all_groups(manager, name)):
            _edit_setting(name, add=False)
    except Exception as e:
        say("could not remove %s from the preset groups: %s" % (name, e), False)


def _edit_setting(name, add):
    """Add `name` to (or remove it from) the groups a GUI saved in the setting."""
    from paraview import servermanager

    settings = servermanager.vtkSMSettings.GetInstance()
    text = settings.GetSettingAsString(SETTING, "")
    if not text:
        return
    groups = json.loads(text)
    changed = False
    for group in groups:
        members = group.setdefault("presets", [])
        if add and group.get("groupName") in GROUPS and name not in members:
            members.append(name)
            changed = True
        elif not add and name in members:
            members.remove(name)
            changed = True
            if not members and group.get("groupName") != "Default":
                group["drop"] = True  # as the manager drops a group it emptied
    groups = [g for g in groups if not g.pop("drop", False)]
    if add:
        have = {g.get("groupName") for g in groups}
        for missing in [g for g in GROUPS if g not in have]:
            groups.append({"groupName": missing, "presets": [name]})
            changed = True
    if changed:
        settings.SetSetting(SETTING, json.dumps(groups, separators=(",", ":")))
