"""Read and write ShapeSpace's versioned JSON blobs on Blender data (see :mod:`core.schema`).

Blobs live either as custom properties of an ID (``key["shapespace_mapping"]``)
or as string properties of ShapeSpace PropertyGroups (``example.pose``).
Every read validates against the blob's schema and migrates files saved by
older versions; damage raises ``ShapeSpaceError`` (code ``corrupt_metadata``)
naming the datablock and property.

Which blobs exist, on which owner, with which schema, is declared once in
:mod:`core.blobs`: :func:`upgrade_file` (before each save) and :func:`damaged_blobs`
(Check Rig) walk that registry, so this module imports none of the modules that own
a blob (they import it).
"""
from __future__ import annotations

import json

from ..core import blobs as _blobs
from ..core import schema as _schema
from ..core.result import Issue, ShapeSpaceError
from . import actions


def where(owner, prop: str) -> str:
    """Human description of a blob's location, e.g. ``Key 'Key' ▸ shapespace_mapping``."""
    kind = type(owner).__name__
    name = getattr(owner, "name", "") or getattr(getattr(owner, "id_data", None), "name", "")
    return f"{kind} '{name}' ▸ {prop}"


def read_id_blob(id_block, prop: str, schema: _schema.Schema) -> dict:
    """The blob stored as custom property ``prop`` of ``id_block`` (an empty blob when absent)."""
    if id_block is None:
        return _schema.loads(None, schema, prop)
    return _schema.loads(id_block.get(prop), schema, where(id_block, prop))


def write_id_blob(id_block, prop: str, schema: _schema.Schema, data: dict) -> None:
    id_block[prop] = _schema.dumps(data, schema)


def read_string_blob(owner, attr: str, schema: _schema.Schema) -> dict:
    """The blob stored in the string property ``attr`` of a PropertyGroup ``owner``."""
    return _schema.loads(getattr(owner, attr), schema, where(owner, attr))


def write_string_blob(owner, attr: str, schema: _schema.Schema, data: dict) -> None:
    setattr(owner, attr, _schema.dumps(data, schema))


def _local(owner) -> bool:
    """Whether ``owner`` (an ID, or a PropertyGroup of one) belongs to this file (not linked from a library)."""
    return getattr(owner.id_data, "library", None) is None


#: Every owner of each kind (:data:`core.blobs.OWNERS`) in ``bpy.data``.
_FILE_OWNERS = {
    "Key": lambda data: list(data.shape_keys),
    "Mesh": lambda data: list(data.meshes),
    "Object": lambda data: list(data.objects),
    "Action": lambda data: list(data.actions),
    "Example": lambda data: [ex for ob in data.objects if ob.type == "MESH" for ex in ob.shapespace_psd.examples],
}


def _played(obj) -> list:
    """The actions the mesh object ``obj`` and its shape keys play (each once)."""
    ids = [obj] + ([obj.data.shape_keys] if obj.data.shape_keys is not None else [])
    return list(dict.fromkeys(a for a in map(actions.active_action, ids) if a is not None))


#: The owners of each kind that belong to a mesh object: itself, its mesh, its shape keys, the actions it and its
#: shape keys play, its pose-space examples.
_OBJECT_OWNERS = {
    "Key": lambda obj: [obj.data.shape_keys] if obj.data.shape_keys is not None else [],
    "Mesh": lambda obj: [obj.data],
    "Object": lambda obj: [obj],
    "Action": _played,
    "Example": lambda obj: list(obj.shapespace_psd.examples),
}


def _stored_text(owner, blob: _blobs.Blob):
    """What ``owner`` holds in the blob's property (None when absent)."""
    if blob.on_id:
        return owner.get(blob.prop)
    return getattr(owner, blob.prop)


def _upgraded(text, schema: _schema.Schema, where_: str):
    """The blob re-serialised at the current version, or None when it is current, empty or damaged
    (a damaged blob is left exactly as it is: Check Rig names it)."""
    if not isinstance(text, str) or not text.strip():
        return None
    try:
        parsed = json.loads(text)
        if isinstance(parsed, dict) and parsed.get("schema_version") == schema.version:
            return None
        return _schema.dumps(_schema.loads(text, schema, where_), schema)
    except (ValueError, RecursionError):
        return None


def upgrade_file(data) -> int:
    """Rewrite every readable older-version blob of :data:`core.blobs.BLOBS` in ``data`` (``bpy.data``) at the
    current schema version.

    Runs before each save (after :func:`bridge.posespace.stored.pin_settings`), so files written by this version
    hold only current blobs; linked (library) data and damaged blobs are left untouched.  Returns how many blobs
    were rewritten.
    """
    count = 0
    for blob in _blobs.BLOBS:
        for owner in _FILE_OWNERS[blob.owner](data):
            if not _local(owner):
                continue
            new = _upgraded(_stored_text(owner, blob), blob.schema, where(owner, blob.prop))
            if new is None:
                continue
            if blob.on_id:
                owner[blob.prop] = new
            else:
                setattr(owner, blob.prop, new)
            count += 1
    return count


def _damage(text, blob: _blobs.Blob, place: str) -> str | None:
    """The one-line message when ``text`` does not read as ``blob`` (or one of its sections), else None."""
    try:
        data = _schema.loads(text, blob.schema, place)
        for section, schema in blob.sections.items():
            if section in data:
                _schema.loads(json.dumps(data[section]), schema, f"{place} ▸ {section}")
    except ShapeSpaceError as exc:
        return str(exc)
    return None


def damaged_blobs(obj, which=_blobs.BLOBS) -> list:
    """``core.Issue`` errors (code ``corrupt_metadata``) for every stored blob of ``obj`` that does not read.

    Walks :data:`core.blobs.BLOBS` (``which``: the blobs to check, default all) on the mesh object, its mesh,
    its shape keys, the actions it and its shape keys play and its pose-space examples; used by Check Rig.
    (That a mirror map is also a mirror table of the mesh's vertices is :func:`bridge.symmetry.table_damage`'s
    check.)
    """
    if obj is None or obj.type != "MESH":
        return []
    found = []
    for blob in which:
        for owner in _OBJECT_OWNERS[blob.owner](obj):
            text = _stored_text(owner, blob)
            if text is None or (not blob.on_id and not text):
                continue
            message = _damage(text, blob, where(owner, blob.prop))
            if message is not None:
                found.append(Issue("error", "corrupt_metadata", message))
    return found
