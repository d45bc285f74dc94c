"""In-between and combination shapes as driven shape keys (thesis 3.3.2, 3.3.3).

Blender has neither natively.  ShapeSpace builds them from plain relative
keys and *simple-expression* drivers, which Blender evaluates without
Python, so files play back anywhere:

- an in-between of primary ``P`` at weight ``t`` is a key holding the
  correction ``S_t − t·S_P``, driven by ``hat(P; left, t, right)``;
- a combination of ``A``, ``B`` (, ``C``) is a key holding the correction,
  driven by ``A·B(·C)``.

What was built is recorded as JSON in the ``Key`` datablock's custom property
``shapespace_driven`` so the reader can rebuild the exact nonlinear model.
"""
from __future__ import annotations

import re

import bpy
import numpy as np

from ..core import blobs
from ..core.result import ShapeSpaceError
from ..core.validate import coordinates
from . import storage
from .arrays import read_float, write_float

#: ``{"inbetweens": {key: {"primary": str, "at": float}}, "combinations": {key: {"inputs": [str]}}}``
PROP = blobs.DRIVEN.prop
SCHEMA = blobs.DRIVEN.schema


def metadata(key) -> dict:
    """``{"inbetweens": {key: {"primary", "at"}}, "combinations": {key: {"inputs"}}}`` (checked on read)."""
    data = storage.read_id_blob(key, PROP, SCHEMA)
    data.setdefault("inbetweens", {})
    data.setdefault("combinations", {})
    _check_entries(data, storage.where(key, PROP) if key is not None else PROP)
    return data


def _check_entries(data: dict, where: str) -> None:
    for name, entry in data["inbetweens"].items():
        ok = isinstance(entry, dict) and isinstance(entry.get("primary"), str) \
            and isinstance(entry.get("at"), (int, float)) and not isinstance(entry.get("at"), bool)
        if not ok:
            raise ShapeSpaceError(f"damaged ShapeSpace data in {where}: in-between '{name}' needs a primary "
                                  f"key name and a weight", "corrupt_metadata")
    for name, entry in data["combinations"].items():
        inputs = entry.get("inputs") if isinstance(entry, dict) else None
        if not (isinstance(inputs, list) and all(isinstance(i, str) for i in inputs)):
            raise ShapeSpaceError(f"damaged ShapeSpace data in {where}: combination '{name}' needs a list of "
                                  f"input key names", "corrupt_metadata")


def _store(key, data) -> None:
    storage.write_id_blob(key, PROP, SCHEMA, data)


def knots_for(data: dict, primary: str) -> dict:
    """``{inbetween key: (left, peak, right)}`` for every in-between of ``primary``."""
    items = sorted((v["at"], k) for k, v in data["inbetweens"].items() if v["primary"] == primary)
    ts = [0.0] + [t for t, _ in items] + [1.0]
    return {name: (ts[i], ts[i + 1], ts[i + 2]) for i, (_, name) in enumerate(items)}


def _value_path(name: str) -> str:
    return f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'


def _set_driver(key, target_name: str, expression: str, inputs) -> None:
    kb = key.key_blocks[target_name]
    kb.driver_remove("value")
    fc = kb.driver_add("value")
    drv = fc.driver
    drv.type = "SCRIPTED"
    for var_name, source in inputs:
        var = drv.variables.new()
        var.name = var_name
        var.type = "SINGLE_PROP"
        var.targets[0].id_type = "KEY"
        var.targets[0].id = key
        var.targets[0].data_path = _value_path(source)
    drv.expression = expression
    for mod in list(fc.modifiers):  # Blender adds a Generator modifier to new drivers
        fc.modifiers.remove(mod)


def hat_expression(left: float, peak: float, right: float) -> str:
    return (f"max(0.0, min((w - {left!r}) / {peak - left!r}, ({right!r} - w) / {right - peak!r}))")


def _refresh_inbetween_drivers(key, data, primary: str) -> None:
    for name, (a, t, b) in knots_for(data, primary).items():
        _set_driver(key, name, hat_expression(a, t, b), [("w", primary)])


def _shape(obj, name) -> np.ndarray:
    """Shape key ``name``'s coordinates, refused (naming the key and the vertex) when one is NaN or infinite."""
    co = read_float(obj.data.shape_keys.key_blocks[name].data, "co", 3).astype(np.float64)
    return coordinates(co, f"shape key {name!r} of {obj.name!r}")


def _rig_key(obj):
    """The object's Key, refusing meshes ShapeSpace cannot build driven keys on."""
    key = obj.data.shape_keys
    if key is None:
        raise ShapeSpaceError(f"mesh {obj.name!r} has no shape keys", "no_shape_keys")
    if len(obj.data.vertices) == 0:
        raise ShapeSpaceError(f"mesh {obj.name!r} has no vertices", "empty")
    return key


def add_inbetween(obj, primary: str, source: str, at: float, name: str = None, keep_source: bool = False) -> str:
    """Turn shape key ``source`` (a full sculpt) into an in-between of ``primary`` at weight ``at``."""
    key = _rig_key(obj)
    blocks = key.key_blocks
    for n in (primary, source):
        if n not in blocks:
            raise ShapeSpaceError(f"mesh {obj.name!r} has no shape key named {n!r}", "missing_key")
    if primary == source:
        raise ShapeSpaceError("the in-between shape must be a different key than its primary", "same_key")
    if not 0.0 < at < 1.0:
        raise ShapeSpaceError(f"an in-between weight must lie strictly between 0 and 1, got {at}", "range")
    data = prune(key)
    if primary in data["inbetweens"] or primary in data["combinations"]:
        raise ShapeSpaceError(f"{primary!r} is itself a driven key", "driven_primary")
    if any(v["primary"] == primary and abs(v["at"] - at) < 1e-6 for v in data["inbetweens"].values()):
        raise ShapeSpaceError(f"{primary!r} already has an in-between at {at:g}", "duplicate_inbetween")
    basis = _shape(obj, key.reference_key.name)
    prim_rel = blocks[primary].relative_key.name
    s_primary = _shape(obj, primary) - _shape(obj, prim_rel)
    s_at = _shape(obj, source) - _shape(obj, blocks[source].relative_key.name)
    name = name or f"{primary}@{at:g}"
    kb = obj.shape_key_add(name=name, from_mix=False)
    write_float(kb.data, "co", basis + (s_at - at * s_primary))
    kb.slider_min, kb.slider_max = 0.0, 1.0
    data["inbetweens"][kb.name] = {"primary": primary, "at": float(at)}
    _store(key, data)
    _refresh_inbetween_drivers(key, data, primary)
    if not keep_source:
        obj.shape_key_remove(blocks[source])
    obj.data.update()
    return kb.name


def add_combination(obj, inputs, source: str, name: str = None, keep_source: bool = False) -> str:
    """Turn shape key ``source`` (the full sculpt at all ``inputs`` = 1) into a combination shape."""
    key = _rig_key(obj)
    inputs = list(inputs)
    if not 2 <= len(inputs) <= 3 or len(set(inputs)) != len(inputs):
        raise ShapeSpaceError("a combination needs 2 or 3 different primary keys", "combination_inputs")
    blocks = key.key_blocks
    for n in inputs + [source]:
        if n not in blocks:
            raise ShapeSpaceError(f"mesh {obj.name!r} has no shape key named {n!r}", "missing_key")
    if source in inputs:
        raise ShapeSpaceError("the combination shape must be a different key than its inputs", "same_key")
    data = prune(key)
    driven = set(data["inbetweens"]) | set(data["combinations"])
    if driven & set(inputs):
        raise ShapeSpaceError("combination inputs must be primary (undriven) keys", "driven_primary")
    basis = _shape(obj, key.reference_key.name)
    total = sum(_shape(obj, n) - _shape(obj, blocks[n].relative_key.name) for n in inputs)
    sculpt = _shape(obj, source) - _shape(obj, blocks[source].relative_key.name)
    name = name or "+".join(inputs)
    kb = obj.shape_key_add(name=name, from_mix=False)
    write_float(kb.data, "co", basis + (sculpt - total))
    kb.slider_min, kb.slider_max = -10.0, 10.0  # products of extended ranges must not clamp
    data["combinations"][kb.name] = {"inputs": inputs}
    _store(key, data)
    letters = "abc"[:len(inputs)]
    _set_driver(key, kb.name, "*".join(letters), list(zip(letters, inputs)))
    if not keep_source:
        obj.shape_key_remove(blocks[source])
    obj.data.update()
    return kb.name


def prune(key) -> dict:
    """The driven keys as they are now, re-derived from the drivers ShapeSpace built.

    Blender renames driver paths when a shape key is renamed, so the drivers are the source of truth: a
    renamed primary, in-between or combination key is followed, and a key whose ShapeSpace driver was
    removed is a plain slider again.  The stored metadata only supplies the exact in-between weights
    (the driver expression holds them to the last bit as well).
    """
    try:
        stored = metadata(key)
    except ShapeSpaceError:          # damaged metadata: the drivers alone say it all (Check Rig names the damage)
        stored = {"inbetweens": {}, "combinations": {}}
    data = {"inbetweens": {}, "combinations": {}}
    if key is None or key.animation_data is None:
        return data
    for fc in key.animation_data.drivers:
        found = _parse_driver(key, fc)
        if found is None:
            continue
        kind, name, entry = found
        if kind == "inbetweens":
            old = next((v for v in stored["inbetweens"].values()
                        if v.get("primary") == entry["primary"] and abs(v.get("at", -1.0) - entry["at"]) < 1e-9),
                       None)
            if old is not None:
                entry["at"] = float(old["at"])
        data[kind][name] = entry
    return data


_HAT = re.compile(r"^max\(0\.0, min\(\(w - (?P<left>[-+0-9.e]+)\) / (?P<rise>[-+0-9.e]+), "
                  r"\((?P<right>[-+0-9.e]+) - w\) / (?P<fall>[-+0-9.e]+)\)\)$")
_KEY_VALUE = re.compile(r'^key_blocks\["(?P<name>(?:[^"\\]|\\.)*)"\]\.value$')


def _key_name(path: str, blocks):
    m = _KEY_VALUE.match(path or "")
    if m is None:
        return None
    name = m.group("name").replace('\\"', '"').replace("\\\\", "\\")
    return name if name in blocks else None


def _parse_driver(key, fc):
    """``(kind, driven key, entry)`` for a driver ShapeSpace built on ``key``, else None."""
    blocks = key.key_blocks
    name = _key_name(fc.data_path, blocks)
    drv = fc.driver
    if name is None or drv.type != "SCRIPTED" or fc.modifiers:
        return None
    sources = []
    for var in drv.variables:
        tgt = var.targets[0]
        if var.type != "SINGLE_PROP" or tgt.id != key:
            return None
        src = _key_name(tgt.data_path, blocks)
        if src is None:
            return None
        sources.append((var.name, src))
    expr = drv.expression.strip()
    m = _HAT.match(expr)
    if m is not None and [v for v, _ in sources] == ["w"]:
        left, rise = float(m.group("left")), float(m.group("rise"))
        return "inbetweens", name, {"primary": sources[0][1], "at": left + rise}
    letters = [v for v, _ in sources]
    if letters in (["a", "b"], ["a", "b", "c"]) and expr == "*".join(letters):
        return "combinations", name, {"inputs": [src for _, src in sources]}
    return None
