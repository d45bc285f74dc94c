"""Control sets stored on a face (issue #25 item 5): read, check, edit and mirror ``Object['shapespace_controls']``.

The blob lives on the face mesh object (:data:`core.blobs.CONTROL_SET`; its entries: :mod:`core.rig.stored`).
Every read checks it (damage raises ``corrupt_metadata`` naming the object, the property and the channel);
:func:`damage` is Check Rig's finding for an entry that does not read when the blob itself does.  Every verb
validates and computes first and writes the blob once at the end: on failure the file is as before.
"""
from __future__ import annotations

import re
from dataclasses import replace

import bpy

from ...core import blobs
from ...core.errors import ErrorCode
from ...core.result import Issue, ShapeSpaceError
from ...core.rig.controls import Channel, ChannelKind, ControlSet
from ...core.rig.stored import (
    BONE_KINDS,
    StoredChannel,
    add_entries,
    blob_from_entries,
    entries_from_blob,
    mirror_entries,
    mirror_entry,
)
from .. import storage
from .channels import bone_channel, property_channel, shape_key_channel
from .evaluate import check_editable

__all__ = ["PROP", "SCHEMA", "add_bones", "add_entries_of", "add_path", "armature_for", "clear", "control_set",
           "damage", "entry_of", "face_for", "mirror", "path_owner", "read", "remove", "set_bounds", "set_enabled",
           "status", "to_channel", "write"]

PROP = blobs.CONTROL_SET.prop
SCHEMA = blobs.CONTROL_SET.schema

_NAME = r'"((?:[^"\\]|\\.)*)"'
_BONE_PROP = re.compile(rf"^pose\.bones\[{_NAME}\]\[{_NAME}\]$")
_OBJECT_PROP = re.compile(rf"^\[{_NAME}\]$")
_KEY = re.compile(rf"^data\.shape_keys\.key_blocks\[{_NAME}\]\.value$")


def _unescape(text: str) -> str:
    return text.replace('\\"', '"').replace("\\\\", "\\")


# -- reading and writing -----------------------------------------------------------------------------------------

def read(obj) -> tuple:
    """``(armature name, [StoredChannel])`` stored on the face ``obj`` (``('', [])`` when none); damage raises."""
    data = storage.read_id_blob(obj, PROP, SCHEMA)
    return entries_from_blob(data, storage.where(obj, PROP))


def status(obj) -> tuple:
    """``(armature name, entries, problem)`` for panels: never raises (``problem`` is '' or one line)."""
    try:
        armature, entries = read(obj)
        return armature, entries, ""
    except ShapeSpaceError as exc:
        return "", [], str(exc)


def write(obj, armature: str, entries) -> None:
    """Store ``entries`` (and the armature's name) on the face ``obj`` (checked as a read would check them)."""
    check_editable([obj])
    data = blob_from_entries(armature, entries)
    entries_from_blob(data, storage.where(obj, PROP))
    storage.write_id_blob(obj, PROP, SCHEMA, data)


def damage(obj) -> list:
    """``core.Issue`` errors (``corrupt_metadata``) when the face's control set reads as a blob but one of its
    channels does not (for Check Rig; a blob that does not read at all is :func:`bridge.storage.damaged_blobs`'s
    finding)."""
    if obj is None or obj.type != "MESH" or PROP not in obj or storage.damaged_blobs(obj, (blobs.CONTROL_SET,)):
        return []
    try:
        read(obj)
    except ShapeSpaceError as exc:
        return [Issue("error", "corrupt_metadata", str(exc))]
    return []


def clear(obj) -> int:
    """Remove the face's control set; returns how many channels it had (damaged data is removed too)."""
    check_editable([obj])
    if PROP not in obj:
        return 0
    _, entries, _problem = status(obj)
    del obj[PROP]
    return len(entries)


# -- entries and channels ------------------------------------------------------------------------------------------

def _object(name: str):
    ob = bpy.data.objects.get(name)
    if ob is None:
        raise ShapeSpaceError(f"no object {name!r}", ErrorCode.MISSING_OBJECT)
    return ob


def to_channel(entry: StoredChannel) -> Channel:
    """The rig's channel for a stored entry, as the rig is now (rotation mode, constraints, locks, ranges), with
    the entry's bounds override."""
    ob = _object(entry.object)
    if entry.kind in BONE_KINDS:
        ch = bone_channel(ob, entry.owner, entry.kind.value, entry.index)
    elif entry.kind == ChannelKind.SHAPE_KEY:
        ch = shape_key_channel(ob, entry.owner)
    else:
        ch = _property(ob, entry.path)
    lo = ch.lo if entry.lo is None else entry.lo
    hi = ch.hi if entry.hi is None else entry.hi
    if lo > hi:
        raise ShapeSpaceError(f"channel {ch.name!r}: bounds [{lo:g}, {hi:g}] (override and the rig's) are not an "
                              "interval", ErrorCode.RANGE)
    return replace(ch, lo=lo, hi=hi)


def _property(ob, path: str) -> Channel:
    m = _BONE_PROP.match(path)
    if m:
        return property_channel(ob, _unescape(m[2]), _unescape(m[1]))
    m = _OBJECT_PROP.match(path)
    if m:
        return property_channel(ob, _unescape(m[1]))
    raise ShapeSpaceError(f"data path {path!r} of {ob.name!r} is not a custom property (['name'] or "
                          "pose.bones['bone']['name']) or a shape-key slider", ErrorCode.MISSING_PROPERTY)


def entry_of(ch: Channel, enabled: bool = True) -> StoredChannel:
    """The stored entry of a channel read from the rig (no bounds override)."""
    if ch.kind in BONE_KINDS:
        owner = _unescape(re.match(rf"^pose\.bones\[{_NAME}\]", ch.path)[1])
    elif ch.kind == ChannelKind.SHAPE_KEY:
        owner = _unescape(_KEY.match(ch.path)[1])
    else:
        m = _BONE_PROP.match(ch.path)
        owner = _unescape(m[1]) if m else _unescape(_OBJECT_PROP.match(ch.path)[1])
    return StoredChannel(ch.kind, ch.owner, owner, ch.path, ch.index, None, None, enabled)


def control_set(obj, enabled_only: bool = True) -> ControlSet:
    """The face's stored channels as a :class:`ControlSet` (enabled ones by default), read from the rig now."""
    _, entries = read(obj)
    chosen = [e for e in entries if e.enabled or not enabled_only]
    if not chosen:
        raise ShapeSpaceError(f"{obj.name!r} has no {'enabled ' if enabled_only else ''}stored control channels: "
                              "propose or add some (Rig ▸ Controls)", ErrorCode.NO_CHANNELS)
    return ControlSet(tuple(to_channel(e) for e in chosen))


# -- the face a context means ----------------------------------------------------------------------------------

def _stored_armature(ob) -> str:
    try:
        return read(ob)[0]
    except ShapeSpaceError:
        return ""


def face_for(active, selected=()):
    """The face mesh an edit means: the active mesh; with an armature active (Pose Mode), the selected mesh, else
    the one mesh whose control set names the armature, else the one mesh it deforms (Armature modifier).

    Raises
    ------
    ShapeSpaceError
        Naming the armature when no mesh or more than one fits.
    """
    if active is None or active.type not in ("MESH", "ARMATURE"):
        raise ShapeSpaceError("select the face mesh (or its armature in Pose Mode)", ErrorCode.NOT_MESH)
    if active.type == "MESH":
        return active
    rules = (lambda: [o for o in selected if o.type == "MESH"],
             lambda: [o for o in bpy.data.objects if o.type == "MESH" and _stored_armature(o) == active.name],
             lambda: [o for o in bpy.data.objects if o.type == "MESH"
                      and any(m.type == "ARMATURE" and m.object == active for m in o.modifiers)])
    for rule in rules:
        found = rule()
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            names = ", ".join(sorted(o.name for o in found))
            raise ShapeSpaceError(f"armature {active.name!r}: more than one face mesh fits ({names}); select the "
                                  "face mesh too", ErrorCode.AMBIGUOUS_OBJECT)
    raise ShapeSpaceError(f"armature {active.name!r}: no face mesh found; select the face mesh too",
                          ErrorCode.NO_OBJECT)


def armature_for(face, active=None):
    """The armature a face's controls belong to: the active armature, else the stored one, else the one its
    Armature modifiers use, else the one its shape-key drivers read; None for a face with none of these."""
    if active is not None and active.type == "ARMATURE":
        return active
    name = _stored_armature(face)
    if name and bpy.data.objects.get(name) is not None:
        return bpy.data.objects[name]
    found = [m.object for m in face.modifiers if m.type == "ARMATURE" and m.object is not None]
    keys = face.data.shape_keys
    if not found and keys is not None and keys.animation_data is not None:
        found = [t.id for fc in keys.animation_data.drivers for v in fc.driver.variables for t in v.targets
                 if isinstance(t.id, bpy.types.Object) and t.id.type == "ARMATURE"]
    found = list(dict.fromkeys(found))
    return found[0] if len(found) == 1 else None


def path_owner(face, object_name: str = "", active=None):
    """The object an added data path starts from: ``object_name`` when given, else the active armature, else the
    control set's armature, else the face."""
    if object_name:
        return _object(object_name)
    return armature_for(face, active) if active is not None and active.type == "ARMATURE" else \
        (bpy.data.objects.get(_stored_armature(face)) or face)


# -- verbs -----------------------------------------------------------------------------------------------------

def _editable(face, *others) -> None:
    check_editable([face, *[o for o in others if o is not None]])


def add_entries_of(face, armature: str, channels) -> list:
    """Append the entries of ``channels`` not stored yet (each read back from the rig first); returns the added
    entries.  ``armature`` becomes the stored armature when none is stored."""
    stored_arm, entries = read(face)
    new = [entry_of(ch) for ch in channels]
    for e in new:
        to_channel(e)
    merged, added = add_entries(entries, new)
    if added:
        write(face, stored_arm or armature, merged)
    return added


def add_bones(face, arm, bone_names) -> tuple:
    """Add the rotation (in each bone's rotation mode) and location axes of ``bone_names`` of the armature ``arm``
    that can move: locked axes, axes held still by their bounds and the location of connected bones are left out.

    Returns
    -------
    (list of StoredChannel, list of str)
        The entries added and the names of the axes left out.
    """
    _editable(face, arm)
    if arm is None or arm.type != "ARMATURE":
        raise ShapeSpaceError(f"{getattr(arm, 'name', arm)!r} is not an armature", ErrorCode.NOT_ARMATURE)
    stored_arm, _ = read(face)
    if stored_arm and stored_arm != arm.name:
        raise ShapeSpaceError(f"the control set of {face.name!r} belongs to armature {stored_arm!r}, not "
                              f"{arm.name!r}: clear it first", ErrorCode.INVALID)
    names = list(bone_names)
    if not names:
        raise ShapeSpaceError(f"no bones of {arm.name!r} are selected (select bones in Pose Mode)",
                              ErrorCode.MISSING_BONE)
    keep, skipped = [], []
    for name in names:
        connected = arm.data.bones[name].use_connect if name in arm.data.bones else False
        for kind in ("rotation", "location"):
            for axis in range(3):
                ch = bone_channel(arm, name, kind, axis)
                if ch.locked or ch.lo == ch.hi or (kind == "location" and connected):
                    skipped.append(ch.name)
                else:
                    keep.append(ch)
    if not keep:
        raise ShapeSpaceError(f"no axis of {', '.join(names)} can move (locked, held by constraints or connected)",
                              ErrorCode.INVALID)
    return add_entries_of(face, arm.name, keep), skipped


def add_path(face, owner, data_path: str) -> StoredChannel:
    """Add the channel at ``data_path`` of the object ``owner``: a custom property (``["name"]``,
    ``pose.bones["bone"]["name"]``, a float) or a shape-key slider (``data.shape_keys.key_blocks["key"].value``).
    Refuses a path that is none of these, does not resolve, or is stored already."""
    _editable(face, owner)
    path = data_path.strip()
    m = _KEY.match(path)
    ch = shape_key_channel(owner, _unescape(m[1])) if m else _property(owner, path)
    added = add_entries_of(face, owner.name if owner.type == "ARMATURE" else "", [ch])
    if not added:
        raise ShapeSpaceError(f"channel {ch.name!r} is already in the control set of {face.name!r}",
                              ErrorCode.DUPLICATE_NAME)
    return added[0]


def _at(face, index: int) -> tuple:
    armature, entries = read(face)
    if not 0 <= index < len(entries):
        raise ShapeSpaceError(f"{face.name!r} has no stored channel {index} ({len(entries)} stored)", ErrorCode.RANGE)
    return armature, entries


def remove(face, index: int) -> StoredChannel:
    """Remove the stored channel at ``index``; returns it."""
    _editable(face)
    armature, entries = _at(face, index)
    gone = entries.pop(index)
    write(face, armature, entries)
    return gone


def set_enabled(face, index: int, enabled: bool) -> StoredChannel:
    _editable(face)
    armature, entries = _at(face, index)
    entries[index] = replace(entries[index], enabled=bool(enabled))
    write(face, armature, entries)
    return entries[index]


def set_bounds(face, index: int, lo: float | None, hi: float | None) -> StoredChannel:
    """Set (a number) or drop (None) the bounds override of the stored channel at ``index``; the result must be an
    interval together with the rig's own bounds."""
    _editable(face)
    armature, entries = _at(face, index)
    entry = replace(entries[index], lo=None if lo is None else float(lo), hi=None if hi is None else float(hi))
    to_channel(entry)
    entries[index] = entry
    write(face, armature, entries)
    return entry


def mirror(face) -> list:
    """Add the left↔right mirror of every sided stored channel not stored yet (:func:`core.rig.stored.mirror_entry`);
    refuses, naming the channel and its mirror, when the mirror's bone, property or key does not exist."""
    _editable(face)
    armature, entries = read(face)
    if not entries:
        raise ShapeSpaceError(f"{face.name!r} has no stored control channels to mirror", ErrorCode.NO_CHANNELS)
    merged, added = mirror_entries(entries)
    for e in added:
        try:
            to_channel(e)
        except ShapeSpaceError as exc:
            raise ShapeSpaceError(f"channel {mirror_entry(e).label!r} has no mirror {e.label!r}: {exc}",
                                  ErrorCode.NO_MIRROR) from None
    if added:
        write(face, armature, merged)
    return added
