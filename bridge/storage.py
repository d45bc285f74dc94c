"""Read and write ShapeSpace's versioned JSON blobs on Blender data (see :mod:`core.schema`).

Blobs live either as custom properties of an ID (``key["shapespace_mapping"]``)
or as string properties of ShapeSpace PropertyGroups (``example.pose``).
Every read validates against the blob's schema and migrates files saved by
older versions; damage raises ``ShapeSpaceError`` (code ``corrupt_metadata``)
naming the datablock and property.
"""
from __future__ import annotations

import json

from ..core import schema as _schema


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


def _key_blob_schemas() -> dict:
    """Every JSON blob ShapeSpace keeps on a shape-key datablock: property name → schema."""
    from . import authoring, driven, facespace, retarget
    return {driven.PROP: driven.SCHEMA, retarget.MAPPING_PROP: retarget.MAPPING_SCHEMA,
            retarget.LAST_PROP: retarget.LAST_SCHEMA, authoring.LAST_PROP: authoring.LAST_SCHEMA,
            **facespace.blob_schemas()}


def _example_blob_schemas() -> dict:
    """Every JSON string of a pose-space example: attribute name → schema."""
    from .posespace import stored
    return {"pose": stored.POSE_SCHEMA, "pseudo_pose": stored.PSEUDO_POSE_SCHEMA,
            "target_values": stored.TARGET_VALUES_SCHEMA}


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


def pin_settings(data) -> int:
    """Store explicitly every ShapeSpace setting whose default changed since the file was made, at the value
    the file meant: a pose space with examples and no stored distance was made before 0.2.0 and keeps Skin
    Weighted.  Runs after each load and before each save; linked (library) data is left untouched (it reads
    the same through ``bridge.posespace.stored.wpsd_distance``).  Returns how many settings it wrote."""
    from .posespace import stored
    return sum(stored.pin_wpsd_distance(ob.shapespace_psd) for ob in data.objects
               if ob.library is None and ob.type == "MESH" and len(ob.shapespace_psd.examples))


def upgrade_file(data) -> int:
    """Rewrite every readable older-version blob in ``data`` (``bpy.data``) at the current schema version,
    and pin the settings whose default changed (:func:`pin_settings`).

    Runs before each save, so files written by this version hold only current blobs; linked (library)
    data and damaged blobs are left untouched.  Returns how many blobs and settings were rewritten.
    """
    count = pin_settings(data)
    key_schemas = _key_blob_schemas()
    for key in data.shape_keys:
        if key.library is not None:
            continue
        for prop, schema in key_schemas.items():
            new = _upgraded(key.get(prop), schema, where(key, prop))
            if new is not None:
                key[prop] = new
                count += 1
    example_schemas = _example_blob_schemas()
    for ob in data.objects:
        if ob.library is not None or ob.type != "MESH":
            continue
        for ex in ob.shapespace_psd.examples:
            for attr, schema in example_schemas.items():
                new = _upgraded(getattr(ex, attr), schema, where(ex, attr))
                if new is not None:
                    setattr(ex, attr, new)
                    count += 1
    return count


def damaged_blobs(obj) -> list:
    """``core.Issue`` errors (code ``corrupt_metadata``) for every stored blob of ``obj`` that does not read.

    Covers the blobs on the object's shape keys, its pose-space examples' strings and its mesh's mirror map
    (which must also be a mirror table of the mesh's vertices; a stale map is not damage); used by Check Rig.
    """
    from ..core.result import Issue, ShapeSpaceError
    found = []
    key = getattr(obj.data, "shape_keys", None) if obj is not None and obj.type == "MESH" else None
    checks = []
    if key is not None:
        checks += [(key.get(prop), schema, where(key, prop)) for prop, schema in _key_blob_schemas().items()
                   if prop in key]
    if obj is not None and obj.type == "MESH":
        for ex in obj.shapespace_psd.examples:
            checks += [(getattr(ex, attr), schema, where(ex, attr))
                       for attr, schema in _example_blob_schemas().items() if getattr(ex, attr)]
    for text, schema, place in checks:
        try:
            _schema.loads(text, schema, place)
        except ShapeSpaceError as exc:
            found.append(Issue("error", "corrupt_metadata", str(exc)))
    if obj is not None and obj.type == "MESH":
        from . import symmetry
        if symmetry.PROP in obj.data:
            try:
                symmetry.load_map(obj)
            except ShapeSpaceError as exc:
                if exc.code == "corrupt_metadata":
                    found.append(Issue("error", "corrupt_metadata", str(exc)))
                elif exc.code == "no_mirror_map":          # the blob reads but holds no table
                    found.append(Issue("error", "corrupt_metadata", f"damaged ShapeSpace data in "
                                       f"{where(obj.data, symmetry.PROP)}: {exc}"))
    return found
