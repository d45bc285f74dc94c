"""Read and write ShapeSpace's versioned JSON blobs on Blender data (see :mod:`core.schema`).

Blobs live either as custom properties of an ID (``key["shapespace_mapping"]``)
or as string properties of ShapeSpace PropertyGroups (``example.pose``).
Every read validates against the blob's schema and migrates files saved by
older versions; damage raises ``ShapeSpaceError`` (code ``corrupt_metadata``)
naming the datablock and property.
"""
from __future__ import annotations

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
