"""Driven targets (thesis 7.3.3): values a pose space drives besides correctives — bone channels, custom
properties, shape-key values — recorded at each example and interpolated between them."""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.drivers import train_target_driver
from ...core.result import ShapeSpaceError
from .pose import armature_of, settings
from .stored import find_example, interpolation_pose, set_target_values, target_values


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


def read_targets(obj) -> list:
    """Current values of the driven targets (one float each)."""
    return [_value(t.owner, t.data_path, t.index) for t in settings(obj).targets]


def write_targets(obj, values) -> None:
    """Set the driven targets to ``values`` (one float each, in order)."""
    for t, v in zip(settings(obj).targets, values):
        if t.index >= 0:
            arr = _resolve(t.owner, t.data_path)
            arr[t.index] = float(v)
        else:
            path, _, prop = t.data_path.rpartition(".")
            holder = t.owner.path_resolve(path) if path else t.owner
            if prop.startswith("["):   # custom property: owner["name"]
                holder[prop[2:-2]] = float(v)
            else:
                setattr(holder, prop, float(v))


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
