"""Head and eye rotations of a face capture onto bones: one definition for live capture and recorded takes.

Rotations arrive as ``(yaw, pitch, roll)`` in the face frame (x: the face's
left, y: up, z: out of the face), ``R = R_y(yaw) R_x(pitch) R_z(roll)``.

- Units: Face Cap and iFacialMocap send Euler degrees ``(x pitch, y yaw, z roll)``
  (:func:`ypr_from_degrees`; Face Cap's eyes only ``(x, y)``: :func:`eye_ypr_from_degrees`).
- Bones: the face frame maps onto Blender's armature axes (X the character's
  left, Z up, −Y forward: ``C`` below); a bone whose rest orientation in
  armature space is ``B`` takes the local rotation ``L = Bᵀ (C R Cᵀ) B``.
  The head / neck split gives the neck ``R^s`` and the head ``R^(1−s)`` (powers
  of one rotation commute, so the chain composes to exactly ``R``).
- :func:`bone_values` turns one frame's rotations into every chosen bone's
  rotation in its own rotation mode (the live session per packet, the offline
  retarget per scene frame: :func:`bone_curves`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .validate import in_range

__all__ = ["FACE_TO_ARMATURE", "BONE_PARTS", "BoneSpec", "euler_matrix", "matrix_euler", "matrix_quaternion",
           "rotation_power", "face_to_armature", "bone_local", "matrix_to_euler", "rotation_channel",
           "bone_values", "bone_curves", "ypr_from_degrees", "eye_ypr_from_degrees", "unused_rotation_channels",
           "ROTATION_CHANNELS"]

#: The head and eye rotation channels, in a frame's rotation order (the Live Link Face CSV's column names).
ROTATION_CHANNELS = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                     "RightEyeYaw", "RightEyePitch", "RightEyeRoll")

#: Face frame (x left, y up, z out of the face) → Blender armature axes (X left, Z up, −Y forward).
FACE_TO_ARMATURE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: The parts a bone can take: head and neck share the head rotation, the eyes take theirs.
BONE_PARTS = ("head", "neck", "eye_left", "eye_right")
_ROTATION_PATHS = {"QUATERNION": ("rotation_quaternion", 4), "AXIS_ANGLE": ("rotation_axis_angle", 4)}
_AXIS = {"X": 0, "Y": 1, "Z": 2}


def euler_matrix(yaw_pitch_roll: ArrayLike) -> np.ndarray:
    """``(yaw, pitch, roll)`` radians → ``R = R_y(yaw) R_x(pitch) R_z(roll)``, shape (3, 3)."""
    a, b, c = (float(v) for v in yaw_pitch_roll)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.array([[ca * cc + sa * sb * sc, -ca * sc + sa * sb * cc, sa * cb],
                     [cb * sc, cb * cc, -sb],
                     [-sa * cc + ca * sb * sc, sa * sc + ca * sb * cc, ca * cb]])


def matrix_euler(R: ArrayLike) -> np.ndarray:
    """Inverse of :func:`euler_matrix`: (3, 3) rotation → ``(yaw, pitch, roll)`` radians (pitch in ±π/2)."""
    R = np.asarray(R, dtype=np.float64)
    pitch = np.arcsin(np.clip(-R[1, 2], -1.0, 1.0))
    return np.array([np.arctan2(R[0, 2], R[2, 2]), pitch, np.arctan2(R[1, 0], R[1, 1])])


def matrix_quaternion(R: ArrayLike) -> np.ndarray:
    """(3, 3) rotation → unit quaternion ``(w, x, y, z)`` with ``w ≥ 0`` (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rotation_power(R: ArrayLike, share: float) -> np.ndarray:
    """``R^share``: the same axis, ``share`` × the angle (0 → identity, 1 → ``R``), shape (3, 3)."""
    share = in_range(share, "share", 0.0, 1.0)
    q = matrix_quaternion(R)
    angle = 2.0 * np.arctan2(np.linalg.norm(q[1:]), q[0])
    if angle < 1e-12:
        return np.eye(3)
    axis = q[1:] / np.linalg.norm(q[1:])
    theta = share * angle
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def face_to_armature(R: ArrayLike, mirror: bool = False) -> np.ndarray:
    """A face-frame rotation in Blender armature axes, ``C R Cᵀ``; ``mirror`` swaps left and right
    (a selfie-mirrored capture: yaw and roll change sign)."""
    R = np.asarray(R, dtype=np.float64)
    if mirror:
        M = np.diag([-1.0, 1.0, 1.0])
        R = M @ R @ M
    return FACE_TO_ARMATURE @ R @ FACE_TO_ARMATURE.T


def bone_local(R_armature: ArrayLike, rest: ArrayLike) -> np.ndarray:
    """The pose-bone rotation ``Bᵀ R B`` (3, 3) that turns a bone with rest orientation ``B`` (its
    ``matrix_local`` rotation, armature space) by ``R`` about its head, in armature axes."""
    B = np.asarray(rest, dtype=np.float64)
    return B.T @ np.asarray(R_armature, dtype=np.float64) @ B


def ypr_from_degrees(rx_ry_rz: ArrayLike) -> np.ndarray:
    """iFacialMocap / Face Cap Euler degrees ``(x: pitch, y: yaw, z: roll)`` (..., 3) → ``(yaw, pitch, roll)``
    radians (..., 3): the live decoders' convention, and the recorded files' (:mod:`core.retarget.formats`)."""
    return np.radians(np.asarray(rx_ry_rz, dtype=np.float64)[..., [1, 0, 2]])


def eye_ypr_from_degrees(rx_ry: ArrayLike) -> np.ndarray:
    """Face Cap eye Euler degrees ``(x: pitch, y: yaw)`` (..., 2) → ``(yaw, pitch, 0)`` radians (..., 3)."""
    xy = np.asarray(rx_ry, dtype=np.float64)
    return np.radians(np.stack([xy[..., 1], xy[..., 0], np.zeros(xy.shape[:-1])], axis=-1))




def matrix_to_euler(R: ArrayLike, order: str = "XYZ") -> np.ndarray:
    """A rotation (3, 3) as Blender Euler angles ``(x, y, z)`` radians for the rotation mode ``order``
    (``'XYZ'`` applies X first: ``R = R_z R_y R_x``), the solution with the middle angle in ±π/2."""
    R = np.asarray(R, dtype=np.float64)
    i, j, k = (_AXIS[c] for c in order)
    odd = (j - i) % 3 != 1                       # XZY, YXZ, ZYX: the axes run backwards
    cy = np.hypot(R[i, i], R[j, i])
    a = np.arctan2(R[k, j], R[k, k])
    b = np.arctan2(-R[k, i], cy)
    c = np.arctan2(R[j, i], R[i, i])
    if cy < 1e-12:                               # gimbal lock: put the whole turn on the first axis
        a, c = np.arctan2(-R[j, k], R[j, j]), 0.0
    if odd:
        a, b, c = -a, -b, -c
    out = np.empty(3)
    out[i], out[j], out[k] = a, b, c
    return out


def rotation_channel(mode: str) -> tuple:
    """``(property name, number of values)`` a pose bone in rotation ``mode`` is keyed on."""
    return _ROTATION_PATHS.get(mode, ("rotation_euler", 3))


@dataclass
class BoneSpec:
    """A pose bone the head or an eye drives.

    Attributes
    ----------
    name : str
    part : str
        ``head``, ``neck``, ``eye_left`` or ``eye_right``.
    share : float
        The power of the head rotation this bone takes (head / neck split; 1 for eyes).
    rest : ndarray (3, 3)
        The bone's rest orientation in armature space.
    mode : str
        Its rotation mode (the channel written and keyed).
    """

    name: str
    part: str
    share: float
    rest: np.ndarray
    mode: str

    @property
    def channel(self) -> tuple:
        """``(property name, number of values)`` of the rotation this bone's mode uses."""
        return rotation_channel(self.mode)

    def values(self, local: np.ndarray) -> tuple:
        """The local rotation (3, 3) in this bone's rotation mode."""
        if self.mode == "QUATERNION":
            return tuple(float(v) for v in matrix_quaternion(local))
        if self.mode == "AXIS_ANGLE":
            q = matrix_quaternion(local)
            angle = 2.0 * np.arctan2(np.linalg.norm(q[1:]), q[0])
            axis = q[1:] / np.linalg.norm(q[1:]) if angle > 1e-12 else np.array([0.0, 1.0, 0.0])
            return (float(angle), *(float(v) for v in axis))
        return tuple(float(v) for v in matrix_to_euler(local, self.mode))


def bone_values(rotations: ArrayLike, bones: list, mirror: bool = False) -> dict:
    """Every bone's rotation for one frame: ``{bone name: values in its rotation mode}``.

    Parameters
    ----------
    rotations : ndarray (9,)
        Head, left-eye and right-eye ``(yaw, pitch, roll)`` radians (calibrated, smoothed as the caller wants).
    bones : list of BoneSpec
    mirror : bool
        A selfie-mirrored capture: yaw and roll change sign, the actor's left eye drives the character's right.
    """
    v = np.asarray(rotations, dtype=np.float64)
    if not bones:
        return {}
    head = face_to_armature(euler_matrix(v[0:3]), mirror)
    eyes = {"eye_left": v[3:6], "eye_right": v[6:9]}
    if mirror:
        eyes = {"eye_left": eyes["eye_right"], "eye_right": eyes["eye_left"]}
    out = {}
    for b in bones:
        R = rotation_power(head, b.share) if b.part in ("head", "neck") else \
            face_to_armature(euler_matrix(eyes[b.part]), mirror)
        out[b.name] = b.values(bone_local(R, b.rest))
    return out


def bone_curves(rotations: ArrayLike, bones: list, mirror: bool = False) -> dict:
    """:func:`bone_values` of every frame: ``{bone name: (f, k) values}`` for rotations (f, 9)."""
    rot = np.asarray(rotations, dtype=np.float64)
    out = {b.name: np.empty((rot.shape[0], b.channel[1])) for b in bones}
    for f in range(rot.shape[0]):
        for name, values in bone_values(rot[f], bones, mirror).items():
            out[name][f] = values
    return out


def unused_rotation_channels(bones: list, mirror: bool = False) -> list:
    """The rotation channels (:data:`ROTATION_CHANNELS`) no bone of ``bones`` takes: the head's without a head
    or neck bone, an eye's without its bone (``mirror``: the actor's left eye drives the character's right)."""
    parts = {b.part for b in bones}
    used = set()
    if parts & {"head", "neck"}:
        used |= {0, 1, 2}
    left, right = ("eye_right", "eye_left") if mirror else ("eye_left", "eye_right")
    if left in parts:
        used |= {3, 4, 5}
    if right in parts:
        used |= {6, 7, 8}
    return [c for k, c in enumerate(ROTATION_CHANNELS) if k not in used]
