"""The pose space of a mesh in Blender: its settings, its armature, its readers and the current pose."""
from __future__ import annotations

import math

import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.readers import PoseReader, pose_features
from ...core.result import ShapeSpaceError
from .. import skin


def settings(obj):
    """The mesh's pose-space settings (``Object.shapespace_psd``)."""
    return obj.shapespace_psd


def armature_of(obj):
    """The armature whose pose drives the correctives: the chosen one, else the first Armature modifier's."""
    st = settings(obj)
    if st.armature is not None:
        if st.armature.type != "ARMATURE":
            raise ShapeSpaceError(f"{st.armature.name!r}, chosen as the pose-space armature, is not an armature",
                                  ErrorCode.NOT_ARMATURE)
        return st.armature
    mods = skin.armature_modifiers(obj)
    return mods[0].object if mods else None


def readers(obj) -> list:
    """The pose space as core readers (a reader with a non-finite or non-positive scale is refused, named)."""
    out = []
    for i, r in enumerate(settings(obj).readers):
        if not (math.isfinite(r.scale) and r.scale > 0):
            raise ShapeSpaceError(f"pose-space reader {i + 1} ({r.kind.lower()} {r.source!r}) of {obj.name!r} has "
                                  f"scale {r.scale}: it must be a positive number",
                                  ErrorCode.RANGE if math.isfinite(r.scale) else ErrorCode.NON_FINITE)
        out.append(PoseReader(r.kind.lower(), r.source, r.scale))
    return out


def _local_quaternion(pose_bone) -> np.ndarray:
    return np.array(pose_bone.matrix_basis.to_quaternion(), dtype=np.float64)


def _finite(value, what: str):
    """``value`` (a number or array) when finite, else refused naming ``what`` (code ``non_finite``)."""
    if not np.isfinite(np.asarray(value, dtype=np.float64)).all():
        shown = f" ({value})" if np.ndim(value) == 0 else ""
        raise ShapeSpaceError(f"{what} is not finite{shown}: fix it before using pose-space correctives",
                              ErrorCode.NON_FINITE)
    return value


def _bone_value(arm, pb, kind: str):
    """A pose bone's location or local rotation (quaternion); refused when its transform is not finite."""
    basis = np.array(pb.matrix_basis, dtype=np.float64)
    _finite(basis, f"the pose of bone {pb.name!r} of {arm.name!r} (location, rotation or scale)")
    return basis[:3, 3].copy() if kind == "location" else _local_quaternion(pb)


def _reader_value(obj, arm, r):
    """The raw value of one reader (quaternion, location or scalar) from Blender."""
    if r.is_bone:
        if arm is None:
            raise ShapeSpaceError(f"{obj.name!r} has no armature to read bone {r.source!r} from",
                                  ErrorCode.NO_ARMATURE)
        pb = arm.pose.bones.get(r.source)
        if pb is None:
            raise ShapeSpaceError(f"bone {r.source!r} no longer exists in {arm.name!r}: was it renamed "
                                  "or deleted? Fix the pose-space reader", ErrorCode.MISSING_BONE)
        return _bone_value(arm, pb, r.kind)
    if r.kind == "shape_key":
        blocks = obj.data.shape_keys.key_blocks if obj.data.shape_keys else {}
        if r.source not in blocks:
            raise ShapeSpaceError(f"shape key {r.source!r} no longer exists", ErrorCode.MISSING_KEY)
        return _finite(blocks[r.source].value, f"the value of shape key {r.source!r}")
    owner = arm if arm is not None else obj
    try:
        value = float(owner.path_resolve(r.source))
    except (ValueError, TypeError):
        raise ShapeSpaceError(f"property {r.source!r} not found on {owner.name!r}",
                              ErrorCode.MISSING_PROPERTY) from None
    return _finite(value, f"property {r.source!r} of {owner.name!r}")


def read_pose(obj, rs: list = None) -> np.ndarray:
    """The current pose-space location of ``obj``'s rig (feature vector); ``rs``: the readers (default: the
    mesh's own, :func:`readers`)."""
    arm = armature_of(obj)
    rs = readers(obj) if rs is None else rs
    if not rs:
        raise ShapeSpaceError("the pose space has no readers: add the bones that drive the correctives",
                              ErrorCode.NO_READERS)
    return pose_features(rs, [_reader_value(obj, arm, r) for r in rs])


def default_readers(obj) -> list:
    """Rotation readers for every deforming bone posed away from rest (a sensible first pose space)."""
    arm = armature_of(obj)
    if arm is None:
        raise ShapeSpaceError(f"{obj.name!r} has no Armature modifier", ErrorCode.NO_ARMATURE)
    out = []
    for pb in arm.pose.bones:
        if not pb.bone.use_deform:
            continue
        q = _bone_value(arm, pb, "rotation")
        if abs(abs(q[0]) - 1.0) > 1e-6:
            out.append(pb.name)
    return out


def add_readers(obj, bones) -> None:
    """Add a rotation reader for each of ``bones`` to the pose space."""
    st = settings(obj)
    for bone in bones:
        r = st.readers.add()
        r.kind, r.source, r.scale = "ROTATION", bone, 1.0


def add_default_readers(obj) -> int:
    """Give an empty pose space a rotation reader per posed deforming bone; returns how many were added."""
    if len(settings(obj).readers):
        return 0
    bones = default_readers(obj)
    add_readers(obj, bones)
    return len(bones)
