"""Examples of a transfer: target shape keys the user sculpted (or imported) as examples of the source's shapes.

Thesis 3.4.1 (Li, Weise & Pauly 2010): every transferred key is refined so the examples are reproduced, with
the plain transfer as the regulariser (:mod:`core.authoring.examples`).  An example is a shape key of the
target; its weights say which source shapes it shows (``jawOpen=1, mouthClose=0.5``), and a key named after a
source shape (in the source's or the chosen naming) with no weights given shows that shape at weight 1.  A key
used as an example is never replaced: the source shape of its name is computed (it explains the example) and
not written.  The panel keeps the list on the target (``Object.shapespace_authoring.examples``); the command
line reads it from there or from a file (:func:`load_example_file`).
"""
from __future__ import annotations

import json
import os

import bpy
import numpy as np

from ...core.authoring.examples import check_weight, parse_weights
from ...core.authoring.job import SourceRig, TargetMesh, TransferExample
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import driven
from ..arrays import read_float
from .reading import finite

__all__ = ["stored_examples", "add_example", "remove_example", "load_example_file", "example_keys", "read_examples"]

#: The file format of ``transfer --examples FILE.json``.
FILE_VERSION = 1
#: An example whose largest coordinate change is at most this × the head's diagonal moves nothing.
STILL = 1e-9
#: An example's largest weight must be at least this: a smaller one would scale the shapes it names up by its
#: inverse (an example of 0.001 jawOpen makes a jawOpen 1000× the sculpt).
MIN_LEAD_WEIGHT = 0.05


def stored_examples(target) -> list:
    """The examples listed in the panel for ``target``: ``[(key, weights or None)]`` (weights parsed; None when
    none were written: the source shape of the key's name at 1)."""
    out = []
    for item in target.shapespace_authoring.examples:
        weights = parse_weights(item.weights, f"example {item.key!r}")
        out.append((item.key, weights or None))
    return out


def add_example(target) -> str:
    """List ``target``'s active shape key as an example (the panel's list); returns its name.  Refused: no
    active key, the basis, a key listed already."""
    key = target.data.shape_keys
    kb = target.active_shape_key if key is not None else None
    if kb is None:
        raise ShapeSpaceError(f"{target.name!r} has no active shape key to add as an example", ErrorCode.MISSING_KEY)
    _usable(target, kb)
    items = target.shapespace_authoring.examples
    if any(item.key == kb.name for item in items):
        raise ShapeSpaceError(f"{kb.name!r} is an example already", ErrorCode.DUPLICATE_NAME)
    item = items.add()
    item.key = kb.name
    target.shapespace_authoring.active_example = len(items) - 1
    return kb.name


def remove_example(target, index: int) -> str:
    """Remove example ``index`` of ``target``'s list (the shape key itself stays); returns its key's name."""
    st = target.shapespace_authoring
    if not 0 <= index < len(st.examples):
        raise ShapeSpaceError(f"no example {index} ({len(st.examples)} listed)", ErrorCode.RANGE)
    name = st.examples[index].key
    st.examples.remove(index)
    st.active_example = max(0, min(st.active_example, len(st.examples) - 1))
    return name


def load_example_file(path: str) -> list:
    """``[(key, weights or None)]`` from ``{"version": 1, "examples": [{"key": K, "weights": {name: w}}]}``
    (``weights`` may be left out), refused naming the entry at fault."""
    if not os.path.isfile(path):
        raise ShapeSpaceError(f"--examples {path}: file not found", ErrorCode.MISSING_FILE)
    where = os.path.basename(path)
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh, object_pairs_hook=_unique_names(where))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ShapeSpaceError(f"{where}: not a JSON file ({exc})", ErrorCode.CORRUPT_FILE) from None
    if not isinstance(data, dict) or type(data.get("version")) is not int or data["version"] != FILE_VERSION \
            or not isinstance(data.get("examples"), list) or set(data) - {"version", "examples"}:
        raise ShapeSpaceError(f'{where}: expected {{"version": {FILE_VERSION}, "examples": [{{"key": ..., '
                              f'"weights": {{...}}}}, ...]}}', ErrorCode.CORRUPT_FILE)
    out = []
    for i, entry in enumerate(data["examples"]):
        at = f"{where}.examples[{i}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("key"), str) or not entry["key"]:
            raise ShapeSpaceError(f"{at}: give the example's shape key as \"key\"", ErrorCode.CORRUPT_FILE)
        unknown = sorted(set(entry) - {"key", "weights"})
        if unknown:
            raise ShapeSpaceError(f"{at}: unknown field {unknown[0]!r} (an example has \"key\" and \"weights\")",
                                  ErrorCode.CORRUPT_FILE)
        weights = entry.get("weights")
        if weights is not None:
            if not isinstance(weights, dict):
                raise ShapeSpaceError(f"{at}.weights: a {{shape name: weight}} object", ErrorCode.CORRUPT_FILE)
            for name, w in weights.items():
                if isinstance(w, bool) or not isinstance(w, (int, float)):
                    raise ShapeSpaceError(f"{at}.weights.{name}: not a number", ErrorCode.NOT_NUMBER)
                try:
                    check_weight(float(w), f"{at}.weights.{name}")
                except OverflowError:
                    raise ShapeSpaceError(f"{at}.weights.{name} is too large", ErrorCode.RANGE) from None
            weights = {str(n): float(w) for n, w in weights.items()} or None
        out.append((entry["key"], weights))
    return out


def _unique_names(where: str):
    """A ``json`` object hook refusing a name given twice in one object (``json`` keeps the last silently)."""
    def pairs(items):
        out = {}
        for name, value in items:
            if name in out:
                raise ShapeSpaceError(f"{where}: {name!r} is given twice in one object", ErrorCode.DUPLICATE_NAME)
            out[name] = value
        return out
    return pairs


def _source_of(rig: SourceRig, names: dict) -> dict:
    """Every name a source shape answers to (its own, its new name) → the source key."""
    out = {new: old for old, new in names.items()}
    out.update({n: n for n in rig.names})
    return out


def example_keys(specs: list, rig: SourceRig, names: dict) -> list:
    """The source keys whose source or new name is an example key (computed, never written beside or over the
    example)."""
    keys = {key for key, _ in specs}
    return [n for n in rig.names if names[n] in keys or n in keys]


def _weights(key: str, given, rig: SourceRig, names: dict) -> dict:
    """An example's weights by source key (validated: every name a source shape, not all zero)."""
    source = _source_of(rig, names)
    if given is None:
        if key not in source:
            raise ShapeSpaceError(f"example {key!r} is not named after a shape of the source rig: give its weights "
                                  f"(for instance jawOpen=1, mouthClose=0.5)", ErrorCode.MISSING_KEY)
        return {source[key]: 1.0}
    out = {}
    for name, w in given.items():
        if name not in source:
            raise ShapeSpaceError(f"example {key!r}: the source rig has no shape {name!r}", ErrorCode.MISSING_KEY)
        if source[name] in out:
            raise ShapeSpaceError(f"example {key!r}: {name!r} names a shape given already", ErrorCode.DUPLICATE_NAME)
        out[source[name]] = check_weight(w, f"example {key!r}: the weight of {name!r}")
    if not any(out.values()):
        raise ShapeSpaceError(f"example {key!r}: every weight is zero", ErrorCode.INVALID)
    lead = max(out, key=lambda n: abs(out[n]))
    if abs(out[lead]) < MIN_LEAD_WEIGHT:
        raise ShapeSpaceError(f"example {key!r}: its largest weight ({names[lead]!r} = {out[lead]:g}) is below "
                              f"{MIN_LEAD_WEIGHT:g}: an example shows its shapes at a visible weight",
                              ErrorCode.RANGE)
    for n in out:
        if n in rig.inbetweens or n in rig.combinations:
            raise ShapeSpaceError(f"example {key!r}: {names[n]!r} is driven by other shapes (an in-between or a "
                                  f"combination): weight the shapes that drive it", ErrorCode.DRIVEN_PRIMARY)
    return out


def _usable(obj, kb) -> None:
    """Refuse a shape key that does not hold the whole shape it shows: the basis, a key relative to another key
    (its shape is a sum), an in-between or combination ShapeSpace drives (its key holds a correction)."""
    shape_keys = obj.data.shape_keys
    if kb == shape_keys.reference_key:
        raise ShapeSpaceError(f"example {kb.name!r} is the basis of {obj.name!r}: choose a shape key",
                              ErrorCode.RESERVED_NAME)
    if kb.relative_key != shape_keys.reference_key:
        raise ShapeSpaceError(f"example {kb.name!r} of {obj.name!r} is relative to {kb.relative_key.name!r}, not "
                              f"to the basis: make it relative to the basis (or a plain key of the whole shape)",
                              ErrorCode.KEY_SHAPE)
    meta = driven.prune(shape_keys)
    for kind, what in (("inbetweens", "an in-between"), ("combinations", "a combination")):
        if kb.name in meta[kind]:
            raise ShapeSpaceError(f"example {kb.name!r} of {obj.name!r} is {what} (its key holds a correction, not "
                                  f"the shape): give a plain key of the whole shape", ErrorCode.DRIVEN_PRIMARY)


def _deltas(obj, key: str, diagonal: float):
    """(n, 3) shape key ``key`` of ``obj`` minus the basis, or None without that key (refused: see
    :func:`_usable`; non-finite or absurd coordinates; a key that moves nothing)."""
    shape_keys = obj.data.shape_keys
    kb = shape_keys.key_blocks.get(key) if shape_keys is not None else None
    if kb is None:
        return None
    _usable(obj, kb)
    co = read_float(kb.points, "co", 3).astype(np.float64)
    finite(obj, "example", repr(key), co)
    delta = co - read_float(shape_keys.reference_key.points, "co", 3).astype(np.float64)
    if np.abs(delta).max(initial=0.0) <= STILL * diagonal:
        raise ShapeSpaceError(f"example {key!r} of {obj.name!r} moves nothing (it equals the basis): sculpt the "
                              f"expression first", ErrorCode.EMPTY)
    return delta


def _part_deltas(obj, key: str, diagonal: float):
    """A part object's rows of an example: its key of that name (a part the example leaves still is still:
    zeros), None without one."""
    try:
        return _deltas(obj, key, diagonal)
    except ShapeSpaceError as exc:
        if exc.code != ErrorCode.EMPTY:
            raise
        return np.zeros((len(obj.data.vertices), 3))


def read_examples(target, specs: list, rig: SourceRig, tgt: TargetMesh, names: dict) -> list:
    """:class:`TransferExample` per ``(key, weights or None)`` of ``specs``, read from ``target`` (its rows) and
    the part objects (their key of the same name, in the target's space; NaN rows where they have none).

    Refused, naming the example: a key the target does not have, its basis, a duplicate, non-finite or absurd
    coordinates, weights naming no source shape, all zero, not finite or too large."""
    out, seen = [], set()
    own = tgt.own if tgt.own >= 0 else len(tgt.neutral)
    diagonal = float(np.linalg.norm(np.ptp(tgt.neutral, axis=0)))
    for key, given in specs:
        if key in seen:
            raise ShapeSpaceError(f"example {key!r} is listed twice", ErrorCode.DUPLICATE_NAME)
        seen.add(key)
        head = _deltas(target, key, diagonal)
        if head is None:
            have = tgt.keys[1:9]
            raise ShapeSpaceError(f"example {key!r}: {target.name!r} has no shape key of that name"
                                  + (f" (it has {', '.join(have)}…)" if have else " (it has no shape keys)"),
                                  ErrorCode.MISSING_KEY)
        deltas = np.full(tgt.neutral.shape, np.nan)
        deltas[:own] = head
        for p in tgt.objects:
            part = _part_deltas(bpy.data.objects[p.name], key, diagonal)
            if part is not None:
                deltas[p.start:p.start + p.count] = part @ p.linear.T
        out.append(TransferExample(key=key, deltas=deltas, weights=_weights(key, given, rig, names)))
    return out
