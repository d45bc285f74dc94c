"""The channel mapping of a retarget: overrides stored on the target's Key, then name matching.

The overrides ``{source channel: {target, gain, offset}}`` live in the Key's :data:`MAPPING_PROP` custom property
(versioned JSON, :data:`MAPPING_SCHEMA`); every source channel without one is matched by name
(:func:`core.names.match_channels`).
"""
from __future__ import annotations

import math

from ...core import blobs
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.retarget import MAX_MAPPING_VALUE, resolve_channel_mapping
from .. import storage

__all__ = ["MAPPING_PROP", "MAPPING_SCHEMA", "MAX_MAPPING_VALUE", "channel_mapping", "resolve_mapping",
           "stored_mapping", "set_mapping", "remove_mapping"]

#: Key custom property: the channel-mapping overrides ``{source channel: {target, gain, offset}}``.
MAPPING_PROP = "shapespace_mapping"
MAPPING_SCHEMA = blobs.RETARGET_MAPPING.schema



def channel_mapping(obj, source_names, target_names) -> list:
    """``[(source index, target index, gain, offset)]``: stored overrides first, then name matching
    (:func:`resolve_mapping` without its warnings)."""
    return resolve_mapping(obj, source_names, target_names)[0]


def resolve_mapping(obj, source_names, target_names) -> tuple:
    """The channel mapping and its warnings: ``([(source index, target index, gain, offset)], [str])`` — the
    overrides stored on ``obj``'s Key, then name matching (:func:`core.retarget.resolve_channel_mapping`).

    Stored overrides win over name matching.  An override whose target key no longer exists (stale) is
    reported by name, and its channel is matched by name when that is possible; an override with a NaN or
    infinite gain or offset is refused naming the channel.
    """
    return resolve_channel_mapping(stored_mapping(obj), source_names, target_names, obj.name)


def stored_mapping(obj) -> dict:
    """The channel-mapping overrides stored on ``obj``'s shape keys: ``{source: {target, gain, offset}}``."""
    key = obj.data.shape_keys
    data = storage.read_id_blob(key, MAPPING_PROP, MAPPING_SCHEMA)
    data.pop("schema_version", None)
    for source, entry in data.items():
        bad = (not isinstance(entry.get("target"), str)
               or any(not isinstance(entry.get(k, 0.0), (int, float)) or isinstance(entry.get(k), bool)
                      for k in ("gain", "offset")))
        if bad:
            raise ShapeSpaceError(f"damaged ShapeSpace data in {storage.where(key, MAPPING_PROP)}: entry "
                                  f"'{source}' needs a target name and numeric gain and offset",
                                  ErrorCode.CORRUPT_METADATA)
    return data


def _mapping_number(source: str, label: str, value) -> float:
    """A gain or offset: finite and within ±:data:`MAX_MAPPING_VALUE` (slider ranges lie within ±10)."""
    value = float(value)
    if not math.isfinite(value):
        raise ShapeSpaceError(f"the {label} of {source!r} must be a finite number, got {value:g}",
                              ErrorCode.NON_FINITE)
    if abs(value) > MAX_MAPPING_VALUE:
        raise ShapeSpaceError(f"the {label} of {source!r} must lie within ±{MAX_MAPPING_VALUE:g}, got {value:g}",
                              ErrorCode.RANGE)
    return value


def remove_mapping(obj, source: str) -> None:
    """Drop the override of ``source`` (name matching applies again)."""
    data = stored_mapping(obj)
    if source not in data:
        raise ShapeSpaceError(f"{obj.name!r} has no mapping override for {source!r}", "missing_channel")
    del data[source]
    storage.write_id_blob(obj.data.shape_keys, MAPPING_PROP, MAPPING_SCHEMA, data)


def set_mapping(obj, source: str, target: str, gain: float = 1.0, offset: float = 0.0) -> None:
    """Store a channel mapping override (kept in the .blend on the shape-key datablock)."""
    key = obj.data.shape_keys
    if not source:
        raise ShapeSpaceError("name the source channel", "missing_channel")
    gain, offset = _mapping_number(source, "gain", gain), _mapping_number(source, "offset", offset)
    if key is None or target not in key.key_blocks or target == key.reference_key.name:
        raise ShapeSpaceError(f"{obj.name!r} has no shape key {target!r} to map to", "missing_key")
    data = stored_mapping(obj)
    data[source] = {"target": target, "gain": float(gain), "offset": float(offset)}
    storage.write_id_blob(key, MAPPING_PROP, MAPPING_SCHEMA, data)
