"""The pose space of a mesh in Blender: its settings, its armature, its readers and the current pose."""
from __future__ import annotations

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
    """The pose space as core readers."""
    return [PoseReader(r.kind.lower(), r.source, r.scale) for r in settings(obj).readers]


def _local_quaternion(pose_bone) -> np.ndarray:
    return np.array(pose_bone.matrix_basis.to_quaternion(), dtype=np.float64)


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
        return np.array(pb.matrix_basis.translation) if r.kind == "location" else _local_quaternion(pb)
    if r.kind == "shape_key":
        blocks = obj.data.shape_keys.key_blocks if obj.data.shape_keys else {}
        if r.source not in blocks:
            raise ShapeSpaceError(f"shape key {r.source!r} no longer exists", ErrorCode.MISSING_KEY)
        return blocks[r.source].value
    owner = arm if arm is not None else obj
    try:
        return float(owner.path_resolve(r.source))
    except (ValueError, TypeError):
        raise ShapeSpaceError(f"property {r.source!r} not found on {owner.name!r}",
                              ErrorCode.MISSING_PROPERTY) from None


def read_pose(obj) -> np.ndarray:
    """The current pose-space location of ``obj``'s rig (feature vector)."""
    arm = armature_of(obj)
    rs = readers(obj)
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
        q = _local_quaternion(pb)
        if pb.bone.use_deform and abs(abs(q[0]) - 1.0) > 1e-6:
            out.append(pb.name)
    return out


def add_default_readers(obj) -> int:
    """Give an empty pose space a rotation reader per posed deforming bone; returns how many were added."""
    st = settings(obj)
    if len(st.readers):
        return 0
    bones = default_readers(obj)
    for bone in bones:
        r = st.readers.add()
        r.kind, r.source, r.scale = "ROTATION", bone, 1.0
    return len(bones)
