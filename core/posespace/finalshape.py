"""Final-shape examples and masked sculpts (thesis 7.2.1): what a corrective was inverted from, kept compactly.

A pose-space corrective is stored as a rest-space displacement δ with
``deform(rest + δ) = sculpt`` (:mod:`.inversion`).  δ is only right for the
rig it was inverted through: change a skin weight, a bone's rest pose or a
modifier before the armature and the posed result drifts from the sculpt.
An example therefore also keeps its *final shape* — the sculpted posed
positions of the vertices it moves, float32, sparse — and a *fingerprint* of
the inputs δ came from, so stale examples are found by comparing
fingerprints and re-inverted exactly from the stored sculpt.

Masked sculpts: one rest-space corrective δ split into parts by vertex-group
masks ``m_g(v) ∈ [0, 1]``, normalised per vertex where the masks overlap,

    δ_g(v) = δ(v) · m_g(v) / Σ_h m_h(v)      (Σ_h m_h(v) > 0),

so ``Σ_g δ_g = δ`` exactly and, because skinning acts per vertex,
``deform(rest + Σ_g δ_g) = sculpt``.
"""
from __future__ import annotations

import base64
import hashlib
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..skinning import MIN_CONTRIB, SkinningRig, bone_change_matrices

__all__ = ["touched_vertices", "encode_array", "decode_array", "array_digest", "compare_fingerprints",
           "split_by_masks", "uncovered_vertices", "lbs_affine_maps"]

#: Displacements at most this fraction of the mesh size are "untouched" (float32 rounding of a key is ~1e-7).
TOUCH_REL = 1e-6


def touched_vertices(displacement: ArrayLike, size: float, rel: float = TOUCH_REL) -> np.ndarray:
    """Indices of the vertices a corrective moves: ``max_i |δ_vi| > rel · size``.

    Parameters
    ----------
    displacement : array_like, shape (p, 3)
        Rest-space corrective δ (or posed sculpt minus posed mesh).
    size : float
        Mesh size (bounding-box diagonal).
    rel : float
        Threshold as a fraction of ``size``.

    Returns
    -------
    ndarray of int64, shape (t,)
    """
    d = validate.array(displacement, "displacement", shape=(None, 3))
    return np.flatnonzero(np.abs(d).max(axis=1) > rel * (size if size > 0 else 1.0)).astype(np.int64)


def encode_array(values: ArrayLike, dtype: str) -> str:
    """``values`` as base64 text of little-endian ``dtype`` (``"<f4"`` or ``"<i4"``), for a JSON blob."""
    return base64.b64encode(np.ascontiguousarray(values, dtype=np.dtype(dtype)).tobytes()).decode("ascii")


def decode_array(text: str, dtype: str, width: int, what: str) -> np.ndarray:
    """Inverse of :func:`encode_array`: an (n, width) array (n, for width 1); refused when damaged."""
    try:
        raw = base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError):
        raise ShapeSpaceError(f"damaged ShapeSpace data in {what}: not base64 text",
                              ErrorCode.CORRUPT_METADATA) from None
    item = np.dtype(dtype).itemsize * width
    if len(raw) % item:
        raise ShapeSpaceError(f"damaged ShapeSpace data in {what}: {len(raw)} bytes is not a whole number of "
                              f"{width}-value rows", ErrorCode.CORRUPT_METADATA)
    arr = np.frombuffer(raw, dtype=np.dtype(dtype)).copy()
    return arr if width == 1 else arr.reshape(-1, width)


def array_digest(*arrays: ArrayLike, decimals: int = 6) -> str:
    """SHA-1 of arrays rounded to ``decimals`` (float32-stable), for a fingerprint entry.

    Parameters
    ----------
    *arrays : array_like
        Any shapes; floats are rounded, integers hashed as int64.

    Returns
    -------
    str
        40 hex digits.
    """
    h = hashlib.sha1()
    for a in arrays:
        a = np.asarray(a)
        if a.dtype.kind == "f":
            a = np.round(a.astype(np.float64), decimals) + 0.0      # + 0.0: −0 and 0 hash alike
        elif a.dtype.kind in "iub":
            a = a.astype(np.int64)
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def compare_fingerprints(stored: Mapping, current: Mapping, bones_now: Sequence[str], tol: float = 1e-5) -> list:
    """Why a corrective inverted from ``stored`` inputs is stale for ``current`` ones: a list of reasons.

    A fingerprint is ``{"weights": digest, "modifiers": {name: digest}, "basis": digest,
    "bones": {bone: [16 floats rest matrix]}, "relative": [16 floats]}``.  ``current`` need not hold
    ``"bones"`` for bones that no longer exist; ``bones_now`` are the bones the armatures have now.

    Returns
    -------
    list of str
        Empty when nothing changed; else human-readable reasons, deleted bones first.
    """
    reasons = []
    gone = [b for b in stored.get("bones", {}) if b not in set(bones_now)]
    if gone:
        reasons.append(f"bone {gone[0]!r} was deleted" if len(gone) == 1
                       else f"bones {', '.join(map(repr, gone))} were deleted")
    for b, m in stored.get("bones", {}).items():
        if b in gone:
            continue
        now = current.get("bones", {}).get(b)
        if now is None or np.abs(np.asarray(now) - np.asarray(m)).max() > tol:
            reasons.append(f"the rest pose of bone {b!r} changed")
    if stored.get("weights") != current.get("weights"):
        reasons.append("skin weights of its sculpted vertices changed")
    old_m, new_m = stored.get("modifiers", {}), current.get("modifiers", {})
    for name in sorted(set(old_m) | set(new_m)):
        if old_m.get(name) != new_m.get(name):
            what = "was added" if name not in old_m else "was removed" if name not in new_m else "changed"
            reasons.append(f"modifier {name!r} {what}")
    if stored.get("basis") != current.get("basis"):
        reasons.append("the basis shape of its sculpted vertices changed")
    rel_old, rel_new = stored.get("relative"), current.get("relative")
    if rel_old is not None and rel_new is not None and np.abs(np.asarray(rel_old) - np.asarray(rel_new)).max() > tol:
        reasons.append("the mesh moved relative to its armature")
    return reasons


def split_by_masks(delta: ArrayLike, masks: ArrayLike) -> tuple:
    """Split a corrective into parts by masks normalised where they overlap (parts add up to ``delta``).

    ``δ_g(v) = δ(v) m_g(v) / Σ_h m_h(v)`` where ``Σ_h m_h(v) > 0``; vertices where every mask is 0 go
    to the remainder.

    Parameters
    ----------
    delta : array_like, shape (p, 3)
        The corrective to split.
    masks : array_like, shape (G, p)
        Mask weights in [0, 1] (vertex-group weights, smooth where painted so).

    Returns
    -------
    parts : ndarray, shape (G, p, 3)
    remainder : ndarray, shape (p, 3)
        ``delta`` where no mask covers the vertex, else 0; ``parts.sum(0) + remainder == delta`` up to
        rounding (the shares sum to 1 in floating point).
    """
    d = validate.array(delta, "delta", shape=(None, 3))
    m = validate.array(masks, "masks", ndim=2)
    if m.shape[1] != d.shape[0]:
        raise ShapeSpaceError(f"masks have {m.shape[1]} vertices, the corrective has {d.shape[0]}", ErrorCode.SHAPE)
    if (m < 0).any():
        raise ShapeSpaceError("mask weights must not be negative", ErrorCode.RANGE)
    total = m.sum(axis=0)
    covered = total > 0
    share = np.zeros_like(m)
    share[:, covered] = m[:, covered] / total[covered]
    parts = share[:, :, None] * d[None]
    remainder = np.where(covered[:, None], 0.0, d)
    return parts, remainder


def uncovered_vertices(delta: ArrayLike, masks: ArrayLike, size: float, rel: float = TOUCH_REL) -> np.ndarray:
    """Vertices the corrective moves (:func:`touched_vertices`) that no mask covers, int64 (u,).

    Parameters
    ----------
    delta : array_like, shape (p, 3)
    masks : array_like, shape (G, p)
    size : float
        Mesh size for the "moved" threshold.
    """
    moved = touched_vertices(delta, size, rel)
    m = validate.array(masks, "masks", ndim=2)
    return moved[m[:, moved].sum(axis=0) <= 0] if m.shape[0] else moved


def lbs_affine_maps(rig: SkinningRig, poses: Sequence) -> np.ndarray | None:
    """Per-vertex affine maps of linear blend skinning, ``deform(x)_v = A_v x + b_v`` (thesis 7.2.1).

    With Blender's normalisation ``s_v = m_v / Σ_k w_vk`` (0 when ``Σ_k w_vk ≤`` MIN_CONTRIB; ``m_v`` the
    modifier's mask) and bone matrices ``M_k`` in object space,
    ``A_v = (1 − s_v Σ_k w_vk) I + s_v Σ_k w_vk M_k[:3, :3]`` and ``b_v = s_v Σ_k w_vk M_k[:3, 3]``
    (:func:`core.skinning.linear_blend_skinning` written as one matrix per vertex).

    Parameters
    ----------
    rig : SkinningRig
    poses : sequence of ndarray, each shape (b, 4, 4)
        ``PoseBone.matrix`` per deformer.

    Returns
    -------
    ndarray, shape (p, 3, 4) or None
        ``[A_v | b_v]``; None unless the rig is exactly one linear-blend (not dual-quaternion) deformer.
    """
    if len(rig.deformers) != 1 or rig.deformers[0].preserve_volume or len(poses) != 1:
        return None
    d = rig.deformers[0]
    mats = bone_change_matrices(d, poses[0], rig.mesh_world)
    w = d.weights.effective()
    idx = np.where(d.weights.bone_index >= 0, d.weights.bone_index, 0)
    contrib = w.sum(axis=1)
    scale = np.zeros_like(contrib)
    ok = contrib > MIN_CONTRIB
    scale[ok] = 1.0 / contrib[ok]
    if d.vertex_mask is not None:
        scale = scale * np.asarray(d.vertex_mask, dtype=np.float64)
    ws = w * scale[:, None]
    maps = np.einsum("pk,pkij->pij", ws, mats[idx][:, :, :3, :])
    maps[:, :, :3] += (1.0 - ws.sum(axis=1))[:, None, None] * np.eye(3)
    return maps
