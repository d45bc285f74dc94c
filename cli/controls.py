"""``retarget --controls SPEC …``: the rig channels a capture is retargeted onto (issue #25).

A SPEC is one of::

    ARMATURE:BONE:rotation[:AXES]    a pose bone's rotation axes (in its rotation mode)
    ARMATURE:BONE:location[:AXES]    … its location axes
    ARMATURE:BONE:scale[:AXES]       … its scale axes
    OBJECT:["prop"]                  a float custom property of an object
    ARMATURE:BONE:["prop"]           … of a pose bone
    key:NAME                         a shape-key slider of the --object mesh
    stored                           the control set stored on the --object mesh (Rig ▸ Controls), alone

AXES is a subset of ``xyz`` (default: every unlocked axis).  An object or bone name may itself contain ``:``
(``mixamorig:Head``): the split that names an existing object is taken.  :func:`parse_specs` checks the
syntax before any work (a malformed SPEC is a usage error, exit 2); :func:`control_set_of` resolves them on
the opened file (a missing object, bone, property or key, or a locked axis named in AXES, is refused naming the
SPEC and it, exit 1).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import bpy

from ..bridge import rig as brig
from ..bridge.rig import stored as stored_controls
from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError

__all__ = ["Spec", "parse_specs", "control_set_of"]

KINDS = ("rotation", "location", "scale")
FORMS = 'ARMATURE:BONE:rotation|location|scale[:AXES], OBJECT:["prop"], ARMATURE:BONE:["prop"] or key:NAME'
_PROPERTY = re.compile(r'(?P<owner>.+):\[(?P<q>["\'])(?P<prop>.+)(?P=q)\]')


@dataclass(frozen=True)
class Spec:
    """One parsed SPEC: ``form`` ``'key'`` / ``'property'`` / ``'bone'``, the owner text (``'ARM:BONE'``,
    ``'OBJECT'`` or the key's name), the property name or bone channel kind, and the axes (``None``: unlocked)."""

    text: str
    form: str
    owner: str
    what: str = ""
    axes: tuple | None = None


def _usage(text: str, why: str) -> ShapeSpaceError:
    return ShapeSpaceError(f"--controls {text!r}: {why}; expected {FORMS}", ErrorCode.USAGE)


def _parse(text: str) -> Spec:
    if text.startswith("key:"):
        if not text[4:]:
            raise _usage(text, "no shape key named")
        return Spec(text, "key", text[4:])
    m = _PROPERTY.fullmatch(text)
    if m is not None:
        return Spec(text, "property", m["owner"], m["prop"])
    parts = text.split(":")
    axes = None
    if len(parts) >= 3 and parts[-2].lower() in KINDS:
        letters = parts.pop().lower()
        if not letters or set(letters) - set("xyz") or len(set(letters)) != len(letters):
            raise _usage(text, f"axes {letters!r} must be distinct letters of xyz")
        axes = tuple("xyz".index(a) for a in letters)
    if len(parts) < 3 or parts[-1].lower() not in KINDS:
        raise _usage(text, "not a bone channel, custom property or shape key")
    owner = ":".join(parts[:-1])
    if not all(parts[:-1]):
        raise _usage(text, "an armature and a bone name are needed")
    return Spec(text, "bone", owner, parts[-1].lower(), axes)


def parse_specs(texts) -> list:
    """Every SPEC parsed (syntax only, no Blender data read); the first malformed one is a usage error.
    ``stored`` (the face's stored control set) stands alone."""
    texts = list(texts)
    if "stored" in texts:
        if len(texts) > 1:
            raise _usage("stored", "the stored control set stands alone: give it or channel SPECs, not both")
        return [Spec("stored", "stored", "")]
    return [_parse(t) for t in texts]


def _armature_and_bone(spec: Spec) -> tuple:
    """The (armature object, bone name) of ``'ARM:BONE'`` — the split whose left side names an object."""
    parts = spec.owner.split(":")
    for k in range(1, len(parts)):
        ob = bpy.data.objects.get(":".join(parts[:k]))
        if ob is not None:
            return ob, ":".join(parts[k:])
    raise ShapeSpaceError(f"--controls {spec.text!r}: no object {parts[0]!r} in the file", ErrorCode.MISSING_OBJECT)


def _channels(spec: Spec, mesh_obj) -> list:
    if spec.form == "key":
        return [brig.shape_key_channel(mesh_obj, spec.owner)]
    if spec.form == "property":
        ob = bpy.data.objects.get(spec.owner)
        if ob is not None:
            return [brig.property_channel(ob, spec.what)]
        arm, bone = _armature_and_bone(spec)
        return [brig.property_channel(arm, spec.what, bone)]
    arm, bone = _armature_and_bone(spec)
    if spec.axes is not None:
        chans = [brig.bone_channel(arm, bone, spec.what, a) for a in spec.axes]
        locked = [c.name for c in chans if c.locked]
        if locked:
            raise ShapeSpaceError(f"{locked[0]!r} is locked on its bone (unlock it or leave the axis out)",
                                  ErrorCode.INVALID)
        return chans
    chans = brig.bone_channels(arm, [bone], (spec.what,))
    if not chans:
        raise ShapeSpaceError(f"bone {bone!r}: every {spec.what} axis is locked", ErrorCode.INVALID)
    return chans


def control_set_of(specs, mesh_obj):
    """The :class:`core.rig.ControlSet` of parsed ``specs`` on the open file (sliders on ``mesh_obj``); a SPEC
    naming what the file lacks is refused with the SPEC and the missing name in the message; ``stored``: the
    enabled channels of the control set stored on ``mesh_obj`` (refused by name when it has none)."""
    if specs and specs[0].form == "stored":
        return stored_controls.control_set(mesh_obj)
    chans = []
    for spec in specs:
        try:
            chans += _channels(spec, mesh_obj)
        except ShapeSpaceError as exc:
            if str(exc).startswith("--controls"):
                raise
            raise ShapeSpaceError(f"--controls {spec.text!r}: {exc}", exc.code) from None
    return brig.control_set(chans)
