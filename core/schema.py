"""Versioned JSON blobs: what ShapeSpace stores in a .blend as text, checked on every read.

Every JSON blob ShapeSpace writes (custom properties on the shape-key
datablock, strings inside its PropertyGroups) is a JSON object with a
``schema_version``.  A :class:`Schema` names the blob, its current version,
the fields it must have (with their JSON types) and the migrations from older
versions.  Version 0 means "written by ShapeSpace 0.1.0" (no
``schema_version`` field; for list blobs, a bare JSON list).

Reading never trusts the file: invalid JSON, a wrong type, a missing field or
a version from the future raise :class:`~core.result.ShapeSpaceError` with
code ``corrupt_metadata`` and a message naming the blob (and the field).
"""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from .errors import ErrorCode
from .result import ShapeSpaceError

__all__ = ["Schema", "dumps", "loads"]

_JSON_TYPES = {"object": dict, "list": list, "string": str, "number": (int, float), "bool": bool,
               "int": int}


@dataclass(frozen=True)
class Schema:
    """The shape of one stored blob.

    Attributes
    ----------
    name : str
        Shown in messages, e.g. ``"retarget mapping (Key 'Key' ▸ shapespace_mapping)"`` is built by
        the caller from this name and where the blob lives.
    version : int
        Current ``schema_version`` written by this release.
    fields : mapping of str to str
        Required top-level fields and their JSON type: ``"object"``, ``"list"``, ``"string"``,
        ``"number"``, ``"int"`` or ``"bool"``.  A type ending in ``"?"`` may also be ``null``.
    optional : mapping of str to str
        Fields that may be absent, with their type.
    values : str or None
        For map-like blobs (``{name: entry}``), the JSON type every value (other than
        ``schema_version``) must have.
    migrations : mapping of int to callable
        ``migrations[v](data) -> data`` turns a version-``v`` blob into version ``v + 1``.
    list_blob : bool
        Version 0 of this blob was a bare JSON list, migrated to ``{"values": [...]}``.
    """

    name: str
    version: int
    fields: Mapping[str, str] = field(default_factory=dict)
    optional: Mapping[str, str] = field(default_factory=dict)
    values: str | None = None
    migrations: Mapping[int, Callable[[dict], dict]] = field(default_factory=dict)
    list_blob: bool = False


def _type_ok(value, kind: str) -> bool:
    if kind.endswith("?"):
        if value is None:
            return True
        kind = kind[:-1]
    want = _JSON_TYPES[kind]
    if kind in ("number", "int") and isinstance(value, bool):
        return False
    return isinstance(value, want)


def _corrupt(where: str, what: str) -> ShapeSpaceError:
    return ShapeSpaceError(f"damaged ShapeSpace data in {where}: {what}", ErrorCode.CORRUPT_METADATA)


def loads(text: str | bytes | None, schema: Schema, where: str) -> dict:
    """Parse, migrate to the current version and check a stored blob.

    Parameters
    ----------
    text : str, bytes or None
        The stored text; empty or ``None`` reads as an empty blob of the current version.
    schema : Schema
    where : str
        Where the blob lives, for the message (``"Key 'Key' ▸ shapespace_mapping"``).

    Returns
    -------
    dict
        The blob at ``schema.version`` (with its ``schema_version``).
    """
    if text is None or (isinstance(text, (str, bytes)) and not text.strip()):
        return _empty(schema)
    if not isinstance(text, (str, bytes)):
        raise _corrupt(where, f"expected JSON text, found {type(text).__name__}")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise _corrupt(where, f"not valid JSON ({str(exc).splitlines()[0]})") from None
    if schema.list_blob and isinstance(data, list):
        data = {"schema_version": 0, "values": data}
    if not isinstance(data, dict):
        raise _corrupt(where, f"expected a JSON object, found {type(data).__name__}")
    version = data.get("schema_version", 0)
    if not isinstance(version, int) or isinstance(version, bool) or version < 0:
        raise _corrupt(where, f"schema_version must be a whole number, found {version!r}")
    if version > schema.version:
        raise _corrupt(where, f"written by a newer ShapeSpace (schema {version}, this one reads "
                              f"up to {schema.version}): update the add-on")
    while version < schema.version:
        migrate = schema.migrations.get(version, _identity)
        data = migrate(dict(data))
        version += 1
        data["schema_version"] = version
    _check(data, schema, where)
    return data


def _identity(data: dict) -> dict:
    return data


def _empty(schema: Schema) -> dict:
    data = {"schema_version": schema.version}
    if schema.list_blob:
        data["values"] = []
    return data


def _check(data: dict, schema: Schema, where: str) -> None:
    for name, kind in schema.fields.items():
        if name not in data:
            raise _corrupt(where, f"field '{name}' is missing")
        if not _type_ok(data[name], kind):
            raise _corrupt(where, f"field '{name}' must be {kind.rstrip('?')}, found {type(data[name]).__name__}")
    for name, kind in schema.optional.items():
        if name in data and not _type_ok(data[name], kind):
            raise _corrupt(where, f"field '{name}' must be {kind.rstrip('?')}, found {type(data[name]).__name__}")
    if schema.values is not None:
        for name, value in data.items():
            if name == "schema_version":
                continue
            if not _type_ok(value, schema.values):
                raise _corrupt(where, f"entry '{name}' must be {schema.values}, found {type(value).__name__}")


def dumps(data: dict, schema: Schema) -> str:
    """Serialise ``data`` as the current version of ``schema`` (adds ``schema_version``)."""
    out = dict(data)
    out["schema_version"] = schema.version
    _check(out, schema, schema.name)
    return json.dumps(out, sort_keys=True, allow_nan=False)
