"""Driven targets (thesis 7.3.3): values a pose space drives besides correctives — bone channels, custom
properties, shape-key values — recorded at each example and interpolated between them."""
from __future__ import annotations

import math
import re

import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.drivers import train_target_driver
from ...core.result import ShapeSpaceError
from .pose import armature_of, settings
from .stored import check_examples, find_example, interpolation_pose, set_target_values, target_values


def _resolve(owner, data_path: str):
    if owner is None:
        raise ShapeSpaceError(f"driven target {data_path!r} has no owner", ErrorCode.MISSING_TARGET)
    try:
        return owner.path_resolve(data_path)
    except ValueError:
        raise ShapeSpaceError(f"{owner.name!r} has no property {data_path!r}", ErrorCode.MISSING_TARGET) from None


def _value(owner, data_path: str, index: int) -> float:
    value = _resolve(owner, data_path)
    return float(value[index] if index >= 0 else value)


def _target_value(t) -> float:
    """A driven target's current value; refused when it cannot be read or is not finite, naming it."""
    try:
        value = _value(t.owner, t.data_path, t.index)
    except ShapeSpaceError:
        raise
    except (IndexError, TypeError, ValueError):
        raise ShapeSpaceError(f"driven target {t.data_path!r} index {t.index} is not a number on "
                              f"{t.owner.name!r}", ErrorCode.NOT_NUMBER) from None
    if not math.isfinite(value):
        raise ShapeSpaceError(f"driven target {t.data_path!r} of {t.owner.name!r} is {value}: give it a finite "
                              "value first", ErrorCode.NON_FINITE)
    return value


def read_targets(obj) -> list:
    """Current values of the driven targets (one float each)."""
    return [_target_value(t) for t in settings(obj).targets]


def _setter(t):
    """A function setting driven target ``t`` to a float; refused (naming it) when its path does not resolve."""
    if t.index >= 0:
        arr = _resolve(t.owner, t.data_path)
        if not hasattr(arr, "__setitem__") or not 0 <= t.index < len(arr):
            raise ShapeSpaceError(f"driven target {t.data_path!r} has no index {t.index} on {t.owner.name!r}",
                                  ErrorCode.MISSING_TARGET)
        return lambda v: arr.__setitem__(t.index, v)
    custom = re.match(r'^(.*)\[(["\'])([^"\']*)\2\]$', t.data_path)
    if custom:                  # a custom property: owner["name"] or owner.path["name"]
        path, name = custom.group(1), custom.group(3)
        holder = _resolve(t.owner, path) if path else t.owner
        return lambda v: holder.__setitem__(name, v)
    path, _, prop = t.data_path.rpartition(".")
    holder = _resolve(t.owner, path) if path else t.owner
    if not hasattr(holder, prop):
        raise ShapeSpaceError(f"{t.owner.name!r} has no property {t.data_path!r}", ErrorCode.MISSING_TARGET)
    return lambda v: setattr(holder, prop, v)


def write_targets(obj, values) -> None:
    """Set the driven targets to ``values`` (one float each, in order); every path is resolved first."""
    setters = [_setter(t) for t in settings(obj).targets]
    for set_value, v in zip(setters, values):
        set_value(float(v))


def add_target(obj, data_path: str, index: int = -1, on_armature: bool = True) -> tuple:
    """Drive ``data_path`` (``[index]``) of the armature (or of the mesh) from pose space.

    Returns ``(owner name, current value)``; nothing is added when the path does not name a number.
    """
    owner = armature_of(obj) if on_armature else obj
    if owner is None:
        raise ShapeSpaceError("the mesh has no armature", ErrorCode.NO_ARMATURE)
    try:
        value = _value(owner, data_path, index)
    except ShapeSpaceError:
        raise
    except (IndexError, TypeError, ValueError):
        raise ShapeSpaceError(f"{data_path!r} index {index} is not a number on {owner.name!r}",
                              ErrorCode.NOT_NUMBER) from None
    st = settings(obj)
    t = st.targets.add()
    t.owner, t.data_path, t.index = owner, data_path, index
    st.revision += 1
    return owner.name, value


def record_targets(obj, example_name: str) -> list:
    """Store the driven targets' current values as the example's (after the rigger set them at its pose)."""
    st = settings(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    values = read_targets(obj)
    set_target_values(ex, values)
    st.revision += 1
    return values


def target_driver(obj):
    """The pose-space interpolant of the driven targets (a core ``ScalarDriver``), or None when there are none."""
    st = settings(obj)
    if not len(st.targets):
        return None
    active = [ex for ex in st.examples if not ex.mute]
    rows = [target_values(ex) for ex in active]
    if not active or any(len(r) != len(st.targets) for r in rows):
        raise ShapeSpaceError("some examples have no recorded values for the driven targets: pose each and use "
                              "Record Targets", ErrorCode.STALE_TARGETS)
    poses = np.array([interpolation_pose(ex) for ex in active])
    names = [f"{t.data_path}[{t.index}]" for t in st.targets]
    return train_target_driver(poses, np.array(rows), names)
