"""Named landmarks stored per head (issue #22 §3): guided placement, mirrored completion, and the transfer's
landmark pairs from the named landmarks of the source and the target.

The landmarks of a head are a versioned blob on its mesh, ``Mesh['shapespace_named_landmarks']``:
``{"landmarks": {name: vertex index}, "vertices": vertex count when placed}`` (names:
:data:`core.authoring.named.NAMES`).
A change of the mesh's vertex count makes them stale (refused with a message, never silently used).
"""
from __future__ import annotations

from ..core import blobs
from ..core.authoring import named as core_named
from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError
from . import storage
from . import symmetry as bsym

__all__ = ["PROP", "SCHEMA", "named_landmarks", "next_name", "place", "remove", "clear_named", "mirror_complete",
           "named_status"]

PROP = blobs.NAMED_LANDMARKS.prop
SCHEMA = blobs.NAMED_LANDMARKS.schema


def _read(obj) -> dict:
    data = storage.read_id_blob(obj.data, PROP, SCHEMA)
    where = storage.where(obj.data, PROP)
    if PROP not in obj.data:
        return {}
    marks = core_named.check_named(data.get("landmarks", {}), where)
    placed_on = int(data.get("vertices", 0))
    if marks and placed_on != len(obj.data.vertices):
        raise ShapeSpaceError(f"the named landmarks of {obj.name!r} were placed when it had {placed_on} vertices, "
                              f"now {len(obj.data.vertices)}: clear and place them again", ErrorCode.STALE_LANDMARKS)
    return marks


def _write(obj, marks: dict) -> None:
    marks = core_named.check_named(marks, storage.where(obj.data, PROP), len(obj.data.vertices))
    storage.write_id_blob(obj.data, PROP, SCHEMA, {"landmarks": marks, "vertices": len(obj.data.vertices)})


def named_landmarks(obj) -> dict:
    """``{name: vertex index}`` placed on the mesh object (in placement order); {} when none.  Damaged or stale
    data raises, naming the mesh."""
    return _read(obj)


def named_status(obj) -> tuple:
    """``(landmarks, problem)`` for panels: never raises (``problem`` is '' or one line)."""
    try:
        return _read(obj), ""
    except ShapeSpaceError as exc:
        return {}, str(exc)


def next_name(obj) -> str | None:
    """The first name of :data:`~core.authoring.named.NAMES` not yet placed, or None when all are."""
    marks = _read(obj)
    return next((n for n in core_named.NAMES if n not in marks), None)


def place(obj, name: str, vertex: int) -> dict:
    """Place landmark ``name`` at ``vertex`` (replacing that name, and any other name on that vertex)."""
    core_named.mirror_name(name)                      # refuses an unknown name
    marks = _read(obj)
    if not 0 <= int(vertex) < len(obj.data.vertices):
        raise ShapeSpaceError(f"{obj.name!r} has no vertex {vertex}", ErrorCode.RANGE)
    marks = {n: v for n, v in marks.items() if v != int(vertex) and n != name}
    marks[name] = int(vertex)
    _write(obj, marks)
    return _read(obj)


def remove(obj, name: str) -> dict:
    marks = _read(obj)
    if name not in marks:
        raise ShapeSpaceError(f"{obj.name!r} has no named landmark {name!r}", ErrorCode.MISSING_KEY)
    del marks[name]
    _write(obj, marks)
    return marks


def clear_named(obj) -> None:
    if PROP in obj.data:
        del obj.data[PROP]


def mirror_complete(obj) -> list:
    """Fill every unplaced partner of a placed landmark (``eye_inner_R`` from ``eye_inner_L`` …) with the mirror
    vertex from the mesh's symmetry map (the stored one, else an automatic map across local X = 0).  Returns
    the names filled; a placed landmark whose vertex has no mirror is skipped (said in the error when none
    could be filled).  Midline landmarks are not changed."""
    marks = _read(obj)
    mmap, _ = bsym.map_for(obj)
    mirror = mmap.mirror
    filled, missing = {}, []
    used = set(marks.values())
    for name, v in marks.items():
        partner = core_named.mirror_name(name)
        if partner == name or partner in marks:
            continue
        w = int(mirror[v]) if v < len(mirror) else -1
        if w < 0 or w in used:
            missing.append(name)
            continue
        filled[partner] = w
        used.add(w)
    if not filled and missing:
        raise ShapeSpaceError(f"the symmetry map of {obj.name!r} has no mirror vertex for {', '.join(missing)}: "
                              f"place the partners by hand", ErrorCode.NO_MIRROR_MAP)
    if filled:
        _write(obj, {**marks, **filled})
    return [n for n in core_named.NAMES if n in filled]
