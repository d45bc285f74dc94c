"""What an export takes: the chosen objects (checked), the armatures they need, the actions that animate them."""
from __future__ import annotations

import bpy

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import actions, skin

#: Object types an export writes.
EXPORTED_TYPES = ("MESH", "ARMATURE")
#: Object types exported as parents of exported objects (their transforms carry the children's motion).
PARENT_TYPES = ("MESH", "ARMATURE", "EMPTY")


def resolve_objects(names=None, scene_if_none_selected: bool = False) -> tuple:
    """The objects to export and notes about what was left out.

    ``names``: object names (the command line's ``--objects``); ``None``: the selected objects, or — with
    ``scene_if_none_selected`` (the command line) and nothing selected — every mesh and armature of the
    scene.  Names listed
    twice are exported once (noted).  Refused: an unknown name (``missing_object``); nothing that is a mesh
    or an armature (``nothing_to_export``); an object in Edit Mode (``mode``: its data is stale).

    Returns
    -------
    (list of bpy.types.Object, list of str)
    """
    notes = []
    if names is not None:
        chosen = []
        for name in names:
            ob = bpy.data.objects.get(name)
            if ob is None:
                raise ShapeSpaceError(f"no object named {name!r} to export", ErrorCode.MISSING_OBJECT)
            if ob in chosen:
                notes.append(f"{name} was given more than once; exported once")
                continue
            chosen.append(ob)
    else:
        chosen = []
        for ob in bpy.context.selected_objects:
            if ob not in chosen:
                chosen.append(ob)
        if not chosen and scene_if_none_selected:
            chosen = [ob for ob in bpy.context.scene.objects if ob.type in EXPORTED_TYPES]
    if not chosen:
        raise ShapeSpaceError("nothing to export: select a mesh (shape keys, skin) or an armature",
                              ErrorCode.NOTHING_TO_EXPORT)
    usable = [ob for ob in chosen if ob.type in EXPORTED_TYPES]
    skipped = [f"{ob.name} ({ob.type.lower()})" for ob in chosen if ob.type not in EXPORTED_TYPES]
    if not usable:
        raise ShapeSpaceError(f"nothing to export: {', '.join(skipped)} — select a mesh or an armature",
                              ErrorCode.NOTHING_TO_EXPORT)
    if skipped:
        notes.append(f"not exported (not a mesh or armature): {', '.join(skipped)}")
    for ob in usable:
        if ob.mode == "EDIT":
            raise ShapeSpaceError(f"{ob.name!r} is in Edit Mode: leave Edit Mode first (its mesh data is not up "
                                  "to date until then)", ErrorCode.MODE)
        if ob.type == "MESH" and len(ob.data.vertices) == 0:
            raise ShapeSpaceError(f"mesh {ob.name!r} has no vertices: nothing to export", ErrorCode.EMPTY)
    return usable, notes


def with_dependencies(objects) -> list:
    """``objects`` plus what their motion needs: the armatures their Armature modifiers use and every parent
    up the hierarchy (an animated parent moves its children), in a stable order."""
    out = list(objects)
    todo = list(objects)
    while todo:
        ob = todo.pop(0)
        needed = [m.object for m in skin.armature_modifiers(ob) if m.object is not None] if ob.type == "MESH" else []
        if ob.parent is not None:
            needed.append(ob.parent)
        for dep in needed:
            if dep.type in PARENT_TYPES and dep not in out:
                out.append(dep)
                todo.append(dep)
    return out


def _animated_ids(ob) -> list:
    ids = [ob]
    if ob.type == "MESH" and ob.data.shape_keys is not None:
        ids.append(ob.data.shape_keys)
    return ids


def animating_actions(objects) -> list:
    """The actions that animate ``objects`` (their transforms, bones, shape keys), each once."""
    found = []
    for ob in objects:
        for id_block in _animated_ids(ob):
            act = actions.active_action(id_block)
            if act is not None and act not in found and actions.fcurves(act, id_block):
                found.append(act)
    return found


def driven_keys(obj) -> list:
    """Names of ``obj``'s shape keys whose value a driver sets (in-betweens, combinations, any driver)."""
    key = obj.data.shape_keys if obj.type == "MESH" else None
    if key is None or key.animation_data is None:
        return []
    out = []
    for fc in key.animation_data.drivers:
        path = fc.data_path
        if path.startswith('key_blocks["') and path.endswith('"].value') and not fc.mute:
            name = path[len('key_blocks["'):-len('"].value')].replace('\\"', '"').replace("\\\\", "\\")
            if name in key.key_blocks:
                out.append(name)
    return out
