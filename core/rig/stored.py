"""A control set as it is stored on a face (issue #25 item 5): the entries, their check on read, their mirror.

The blob (:data:`core.blobs.CONTROL_SET`, ``Object['shapespace_controls']`` on the face mesh object) is ::

    {"schema_version": 1, "armature": str,            # the armature the bone channels belong to ('' for none)
     "channels": [{"kind": str, "object": str, "owner": str, "path": str, "index": int,
                   "lo": float | null, "hi": float | null, "enabled": bool}, …]}

``kind`` is a :class:`~core.rig.controls.ChannelKind` value; ``object`` the object the data ``path`` starts from
(the armature, the mesh, a control object); ``owner`` the named thing the channel moves (the bone for bone
channels and pose-bone properties, the property, the shape key); ``index`` the axis (``-1`` for a scalar);
``lo``/``hi`` a bounds override (``null``: the rig's own bound); ``enabled`` whether a solve uses the channel.
A bone channel's ``path`` is the one its bone had when stored; reading it again follows the bone's current
rotation mode (its identity is the bone, kind and axis).

Pure: :mod:`bridge.rig.stored` reads and writes the blob on Blender data.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..symmetry import counterpart_name
from .controls import ChannelKind

__all__ = ["BONE_KINDS", "StoredChannel", "add_entries", "entries_from_blob", "blob_from_entries", "mirror_entry",
           "mirror_entries"]

#: Kinds whose channels are one axis of a pose bone's transform.
BONE_KINDS = (ChannelKind.ROTATION, ChannelKind.LOCATION, ChannelKind.SCALE)
_AXES = "XYZ"


@dataclass(frozen=True)
class StoredChannel:
    """One stored channel of a control set (module doc).

    Attributes
    ----------
    kind : ChannelKind
    object : str
    owner : str
    path : str
    index : int
    lo, hi : float or None
        Bounds override; None keeps the rig's bound.
    enabled : bool
    """

    kind: ChannelKind
    object: str
    owner: str
    path: str
    index: int = -1
    lo: float | None = None
    hi: float | None = None
    enabled: bool = True

    @property
    def identity(self) -> tuple:
        """What makes two entries the same channel: the bone, kind and axis for bone channels, else the path."""
        if self.kind in BONE_KINDS:
            return (self.object, self.kind.value, self.owner, self.index)
        return (self.object, self.path, self.index)

    @property
    def label(self) -> str:
        """The name messages and the panel use (as :mod:`bridge.rig.channels` names the channel)."""
        if self.kind in BONE_KINDS:
            return f"{self.owner} {self.kind.value} {_AXES[self.index]}"
        if self.kind == ChannelKind.SHAPE_KEY:
            return f"key {self.owner}"
        prop = self.path.rpartition('["')[2][:-2]
        return f"{self.owner}[{prop}]" if self.owner != prop else f"{self.object}[{prop}]"


def _bad(where: str, i: int, what: str) -> ShapeSpaceError:
    return ShapeSpaceError(f"damaged ShapeSpace data in {where}: channel {i} {what}", ErrorCode.CORRUPT_METADATA)


def _bound(entry: dict, name: str, where: str, i: int):
    v = entry.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _bad(where, i, f"'{name}' must be a finite number or null, found {v!r}")
    return float(v)


def _entry(entry, where: str, i: int) -> StoredChannel:
    if not isinstance(entry, dict):
        raise _bad(where, i, f"is not an object ({type(entry).__name__})")
    for name, kind in (("kind", str), ("object", str), ("owner", str), ("path", str), ("index", int),
                       ("enabled", bool)):
        v = entry.get(name)
        if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
            raise _bad(where, i, f"field '{name}' must be {kind.__name__}, found {v!r}")
        if kind is str and name != "path" and not v:
            raise _bad(where, i, f"field '{name}' is empty")
    try:
        kind = ChannelKind(entry["kind"])
    except ValueError:
        raise _bad(where, i, f"has an unknown kind {entry['kind']!r}") from None
    index = entry["index"]
    if (kind in BONE_KINDS and index not in (0, 1, 2)) or (kind not in BONE_KINDS and index != -1):
        raise _bad(where, i, f"({kind.value}) has no axis {index}")
    lo, hi = _bound(entry, "lo", where, i), _bound(entry, "hi", where, i)
    if lo is not None and hi is not None and lo > hi:
        raise _bad(where, i, f"bounds [{lo:g}, {hi:g}] are not an interval")
    return StoredChannel(kind, entry["object"], entry["owner"], entry["path"], index, lo, hi, entry["enabled"])


def entries_from_blob(data: dict, where: str) -> tuple:
    """The armature name and the entries of a read blob (its schema already checked), each entry checked.

    Parameters
    ----------
    data : dict
        The blob as :func:`core.schema.loads` returns it (an empty blob has no ``channels``).
    where : str
        Where the blob lives, for the message.

    Returns
    -------
    (str, list of StoredChannel)

    Raises
    ------
    ShapeSpaceError
        ``corrupt_metadata``, one line naming the blob and the channel, on a bad entry or a channel listed twice.
    """
    entries, seen = [], {}
    for i, raw in enumerate(data.get("channels", [])):
        e = _entry(raw, where, i)
        if e.identity in seen:
            raise _bad(where, i, f"({e.label}) repeats channel {seen[e.identity]}")
        seen[e.identity] = i
        entries.append(e)
    return data.get("armature", ""), entries


def blob_from_entries(armature: str, entries: Sequence[StoredChannel]) -> dict:
    """The blob's fields (without ``schema_version``) for an armature name and entries."""
    return {"armature": armature or "",
            "channels": [{"kind": e.kind.value, "object": e.object, "owner": e.owner, "path": e.path,
                          "index": e.index, "lo": e.lo, "hi": e.hi, "enabled": bool(e.enabled)} for e in entries]}


def add_entries(entries: Sequence[StoredChannel], new: Sequence[StoredChannel]) -> tuple:
    """``entries`` followed by those of ``new`` not already in them (by identity).

    Returns
    -------
    (list of StoredChannel, list of StoredChannel)
        The merged list and the entries actually added.
    """
    out = list(entries)
    have = {e.identity for e in out}
    added = []
    for e in new:
        if e.identity not in have:
            have.add(e.identity)
            out.append(e)
            added.append(e)
    return out, added


def _mirror_names(text: str) -> str:
    """Every quoted name in a data path replaced by its left↔right counterpart (unsided names kept)."""
    parts = text.split('"')
    for j in range(1, len(parts), 2):
        parts[j] = counterpart_name(parts[j]) or parts[j]
    return '"'.join(parts)


def _flips(e: StoredChannel) -> bool:
    """Whether the mirrored channel's value is the negated value (Blender's flipped pose: rotation Y and Z,
    location X; scale, properties and sliders keep their sign)."""
    return (e.kind == ChannelKind.ROTATION and e.index in (1, 2)) or (e.kind == ChannelKind.LOCATION and e.index == 0)


def mirror_entry(e: StoredChannel) -> StoredChannel | None:
    """The left↔right mirror of an entry, or None when nothing it names has a side (``jaw``, ``jawOpen``).

    The owner and every quoted name in the path go to their counterpart (:func:`core.symmetry.counterpart_name`:
    ``lid.T.L.002`` ↔ ``lid.T.R.002``, ``eyeBlink_L`` ↔ ``eyeBlink_R``, ``eyeBlinkLeft`` ↔ ``eyeBlinkRight``,
    ``_l`` ↔ ``_r``); a bounds override is reflected as Blender's flipped pose reflects the value
    (``[lo, hi]`` → ``[−hi, −lo]`` on rotation Y/Z and location X).
    """
    owner = counterpart_name(e.owner) or e.owner
    path = _mirror_names(e.path)
    if owner == e.owner and path == e.path:
        return None
    lo, hi = e.lo, e.hi
    if _flips(e):
        lo, hi = (None if e.hi is None else -e.hi), (None if e.lo is None else -e.lo)
    return replace(e, owner=owner, path=path, lo=lo, hi=hi)


def mirror_entries(entries: Sequence[StoredChannel]) -> tuple:
    """``entries`` completed with the mirror of every sided entry whose mirror is not in them yet.

    Returns
    -------
    (list of StoredChannel, list of StoredChannel)
        The completed list (originals first, in order, then the new mirrors) and the mirrors added.
    """
    mirrors = [m for m in map(mirror_entry, entries) if m is not None]
    return add_entries(entries, mirrors)
