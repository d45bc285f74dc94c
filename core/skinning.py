"""Skeletal skinning exactly as Blender's Armature modifier evaluates it.

Linear blend skinning (thesis Eq. 7.1): ``v' = v + Σ_i w_i (M_i v − v) / Σ_i w_i``
over the vertex's deforming bones, where ``M_i = P⁻¹ · C_i · P`` maps the
mesh's object space through the armature space (``P`` = armature-from-mesh)
and ``C_i = pose_i · rest_i⁻¹`` is the bone's change of frame.  Vertices whose
total weight is at most 1e-4 do not move.  Dual-quaternion skinning
("Preserve Volume") blends per-bone dual quaternions with hemisphere
alignment against the running sum and a separately blended scale matrix,
mirroring Blender's ``mat4_to_dquat`` / ``add_weighted_dq_dq`` /
``normalize_dq`` / ``mul_v3m3_dq``.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .result import Issue, Result, ShapeSpaceError

__all__ = [
    "SkinWeights", "ArmatureDeform", "SkinningRig", "bone_change_matrices",
    "linear_blend_skinning", "normalised_weights", "dual_quaternion_skinning", "deform", "diagnose_weights",
    "matrix_to_quaternion", "matrix_to_dual_quaternion",
]

#: Blender ignores vertices whose total deforming weight is at most this.
MIN_CONTRIB = 1e-4


@dataclass
class SkinWeights:
    """Per-vertex bone influences in the order Blender stores them.

    Parameters
    ----------
    bone_index : ndarray of int, shape (p, k)
        Index into the armature's bone list for each influence, ``-1`` for
        padding or for groups that name no deforming bone.
    weight : ndarray of float, shape (p, k)
        Influence weights (raw, un-normalised, as in the vertex groups).
    """

    bone_index: np.ndarray
    weight: np.ndarray

    def __post_init__(self):
        self.bone_index = np.asarray(self.bone_index, dtype=np.int64)
        self.weight = np.asarray(self.weight, dtype=np.float64)
        if self.bone_index.ndim != 2 or self.bone_index.shape != self.weight.shape:
            raise ShapeSpaceError(
                f"bone_index and weight must both have shape (p, k); got {self.bone_index.shape} "
                f"and {self.weight.shape}", "shape")

    @property
    def n_vertices(self) -> int:
        return self.bone_index.shape[0]

    def effective(self) -> np.ndarray:
        """Weights with padding and non-deforming influences zeroed, shape (p, k)."""
        return np.where(self.bone_index >= 0, self.weight, 0.0)

    def dense(self, n_bones: int) -> np.ndarray:
        """Dense (p, n_bones) weight matrix (duplicates summed)."""
        out = np.zeros((self.n_vertices, n_bones))
        rows = np.repeat(np.arange(self.n_vertices), self.bone_index.shape[1])
        cols = self.bone_index.ravel()
        ok = cols >= 0
        np.add.at(out, (rows[ok], cols[ok]), self.weight.ravel()[ok])
        return out


@dataclass
class ArmatureDeform:
    """One Armature modifier: its skin weights, its settings and its bones.

    Parameters
    ----------
    weights : SkinWeights
        Influences restricted to bones that deform (``use_deform``).
    bone_names : list of str
        Bones of the armature, indexed by ``weights.bone_index``.
    rest : ndarray, shape (b, 4, 4)
        Bone rest matrices in armature space (``Bone.matrix_local``).
    armature_world : ndarray, shape (4, 4)
        Armature object's world matrix.
    preserve_volume : bool
        Dual-quaternion skinning (``use_deform_preserve_volume``).
    vertex_mask : ndarray, shape (p,), optional
        The modifier's own vertex-group mask (``vertex_group`` /
        ``invert_vertex_group``), 1 where absent.
    name : str
        Modifier name, for messages.
    """

    weights: SkinWeights
    bone_names: list
    rest: np.ndarray
    armature_world: np.ndarray
    preserve_volume: bool = False
    vertex_mask: np.ndarray = None
    name: str = "Armature"

    def __post_init__(self):
        self.rest = np.asarray(self.rest, dtype=np.float64).reshape(-1, 4, 4)
        self.armature_world = np.asarray(self.armature_world, dtype=np.float64).reshape(4, 4)
        if self.rest.shape[0] != len(self.bone_names):
            raise ShapeSpaceError(
                f"rest has {self.rest.shape[0]} matrices for {len(self.bone_names)} bones", "shape")


@dataclass
class SkinningRig:
    """A mesh deformed by a stack of Armature modifiers, in stack order."""

    mesh_world: np.ndarray
    deformers: list = field(default_factory=list)


def _as_mats(m, name):
    m = np.asarray(m, dtype=np.float64)
    if m.shape[-2:] != (4, 4):
        raise ShapeSpaceError(f"{name} must have shape (..., 4, 4), got {m.shape}", "shape")
    return m


def bone_change_matrices(deformer: ArmatureDeform, pose: ArrayLike, mesh_world: ArrayLike) -> np.ndarray:
    """Per-bone deformation matrices in the mesh's object space.

    Parameters
    ----------
    deformer : ArmatureDeform
    pose : ndarray, shape (b, 4, 4)
        Posed bone matrices in armature space (``PoseBone.matrix``).
    mesh_world : ndarray, shape (4, 4)

    Returns
    -------
    ndarray, shape (b, 4, 4)
        ``P⁻¹ · pose_i · rest_i⁻¹ · P`` with ``P = arm_world⁻¹ · mesh_world``.
    """
    pose = _as_mats(pose, "pose")
    chan = pose @ np.linalg.inv(deformer.rest)
    to_arm = np.linalg.inv(deformer.armature_world) @ _as_mats(mesh_world, "mesh_world")
    return np.linalg.inv(to_arm) @ chan @ to_arm


def normalised_weights(weights: SkinWeights, vertex_mask: ArrayLike | None = None) -> tuple:
    """Each vertex's bone weights divided by their total, as Blender's linear blend skinning weighs them.

    Parameters
    ----------
    weights : SkinWeights
    vertex_mask : ndarray, shape (p,), optional
        Modifier vertex-group mask.

    Returns
    -------
    weights : ndarray, shape (p, k)
        Normalised, times the mask; zero rows where the total is under :data:`MIN_CONTRIB` (Blender leaves those
        vertices where they are).
    bone_index : ndarray of int, shape (p, k)
        The bone of each weight (empty slots point at bone 0 with weight 0).
    """
    w = weights.effective()
    idx = np.where(weights.bone_index >= 0, weights.bone_index, 0)
    contrib = w.sum(axis=1)
    scale = np.where(contrib > MIN_CONTRIB, 1.0 / np.where(contrib > MIN_CONTRIB, contrib, 1.0), 0.0)
    if vertex_mask is not None:
        scale = scale * np.asarray(vertex_mask, dtype=np.float64)
    return w * scale[:, None], idx


def linear_blend_skinning(coords: ArrayLike, weights: SkinWeights, mats: ArrayLike,
                          armature_weight: ArrayLike | None = None) -> np.ndarray:
    """Linear blend skinning with Blender's weight normalisation.

    Parameters
    ----------
    coords : ndarray, shape (p, 3)
        Input positions (after shape keys and earlier modifiers).
    weights : SkinWeights
    mats : ndarray, shape (b, 4, 4)
        Deformation matrices in the same space as ``coords``.
    armature_weight : ndarray, shape (p,), optional
        Modifier vertex-group mask.

    Returns
    -------
    ndarray, shape (p, 3)
    """
    co = np.asarray(coords, dtype=np.float64)
    w = weights.effective()
    idx = np.where(weights.bone_index >= 0, weights.bone_index, 0)
    contrib = w.sum(axis=1)
    # M_i v - v for each influence: (p, k, 3)
    m = mats[idx]
    moved = np.einsum("pkij,pj->pki", m[..., :3, :3], co) + m[..., :3, 3]
    vec = np.einsum("pk,pki->pi", w, moved - co[:, None, :])
    ok = contrib > MIN_CONTRIB
    scale = np.zeros_like(contrib)
    scale[ok] = 1.0 / contrib[ok]
    if armature_weight is not None:
        scale = scale * np.asarray(armature_weight, dtype=np.float64)
    return co + vec * scale[:, None]


def matrix_to_quaternion(r: ArrayLike) -> np.ndarray:
    """Unit quaternions (w, x, y, z) of rotation matrices, shape (..., 3, 3) → (..., 4)."""
    r = np.asarray(r, dtype=np.float64)
    t = np.trace(r, axis1=-2, axis2=-1)
    cand = np.stack([
        1.0 + t,
        1.0 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2],
        1.0 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2],
        1.0 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2],
    ], axis=-1)
    which = np.argmax(cand, axis=-1)
    q = np.empty(r.shape[:-2] + (4,))
    s = np.sqrt(np.maximum(np.take_along_axis(cand, which[..., None], -1)[..., 0], 1e-300)) * 2.0
    r01, r02 = r[..., 0, 1], r[..., 0, 2]
    r10, r12 = r[..., 1, 0], r[..., 1, 2]
    r20, r21 = r[..., 2, 0], r[..., 2, 1]
    opts = [
        np.stack([0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s], -1),
        np.stack([(r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s], -1),
        np.stack([(r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s], -1),
        np.stack([(r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s], -1),
    ]
    for k in range(4):
        sel = which == k
        q[sel] = opts[k][sel]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _orthonormalize_keep_y(m3):
    """Gram–Schmidt that keeps the Y axis direction (Blender's ``orthogonalize_m4(.., 1)``)."""
    y = m3[..., :, 1] / np.linalg.norm(m3[..., :, 1], axis=-1, keepdims=True)
    x = m3[..., :, 0] - np.sum(m3[..., :, 0] * y, -1, keepdims=True) * y
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    z = np.cross(x, y)
    z *= np.sign(np.sum(z * m3[..., :, 2], -1, keepdims=True) + 1e-300)
    return np.stack([x, y, z], axis=-1)


def matrix_to_dual_quaternion(basemat: ArrayLike, mat: ArrayLike) -> tuple:
    """Dual quaternions of bone change matrices, with Blender's scale split.

    Parameters
    ----------
    basemat : ndarray, shape (b, 4, 4)
        Bone rest matrices (armature space).
    mat : ndarray, shape (b, 4, 4)
        Change matrices ``pose · rest⁻¹`` (armature space).

    Returns
    -------
    quat, trans : ndarray, shape (b, 4)
        Real and dual parts.
    scale : ndarray, shape (b, 4, 4)
        Scale matrix applied before the rigid part (identity when absent).
    has_scale : ndarray of bool, shape (b,)
    """
    basemat = _as_mats(basemat, "basemat")
    mat = _as_mats(mat, "mat")
    base_rs = mat @ basemat
    size = np.linalg.norm(base_rs[..., :3, :3], axis=-2)
    m3 = mat[..., :3, :3]
    gram = np.swapaxes(m3, -1, -2) @ m3
    orthonormal = np.all(np.abs(gram - np.eye(3)) <= 1e-6, axis=(-2, -1))
    has_scale = (~orthonormal | (np.linalg.det(m3) < 0)
                 | (np.sum((size - 1.0) ** 2, -1) > 1e-8))
    rigid = mat.copy()
    scale = np.broadcast_to(np.eye(4), mat.shape).copy()
    if has_scale.any():
        brs = base_rs[has_scale]
        base_r = np.broadcast_to(np.eye(4), brs.shape).copy()
        base_r[..., :3, :3] = _orthonormalize_keep_y(brs[..., :3, :3])
        base_r[..., :3, 3] = brs[..., :3, 3]
        base_inv = np.linalg.inv(basemat[has_scale])
        rigid[has_scale] = base_r @ base_inv
        s = np.linalg.inv(base_r) @ brs
        scale[has_scale] = basemat[has_scale] @ s @ base_inv
    q = matrix_to_quaternion(rigid[..., :3, :3])
    t = rigid[..., :3, 3]
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    trans = np.stack([
        -0.5 * (t[..., 0] * x + t[..., 1] * y + t[..., 2] * z),
        0.5 * (t[..., 0] * w + t[..., 1] * z - t[..., 2] * y),
        0.5 * (-t[..., 0] * z + t[..., 1] * w + t[..., 2] * x),
        0.5 * (t[..., 0] * y - t[..., 1] * x + t[..., 2] * w),
    ], -1)
    return q, trans, scale, has_scale


def dual_quaternion_skinning(coords: ArrayLike, weights: SkinWeights, basemat: ArrayLike, chan: ArrayLike,
                             to_arm: ArrayLike, armature_weight: ArrayLike | None = None) -> np.ndarray:
    """Dual-quaternion ("Preserve Volume") skinning as in Blender.

    Parameters
    ----------
    coords : ndarray, shape (p, 3)
        Mesh object-space positions.
    weights : SkinWeights
    basemat : ndarray, shape (b, 4, 4)
        Bone rest matrices (armature space).
    chan : ndarray, shape (b, 4, 4)
        ``pose · rest⁻¹`` per bone (armature space).
    to_arm : ndarray, shape (4, 4)
        Mesh object space → armature space.
    armature_weight : ndarray, shape (p,), optional

    Returns
    -------
    ndarray, shape (p, 3)
    """
    co = np.asarray(coords, dtype=np.float64)
    arm_co = co @ to_arm[:3, :3].T + to_arm[:3, 3]
    q, tr, sc, has_sc = matrix_to_dual_quaternion(basemat, chan)
    w = weights.effective()
    idx = np.where(weights.bone_index >= 0, weights.bone_index, 0)
    p, k = w.shape
    qsum = np.zeros((p, 4))
    tsum = np.zeros((p, 4))
    contrib = np.zeros(p)
    for j in range(k):  # influences in stored order (k is small); vectorised over vertices
        wj = w[:, j]
        bj = idx[:, j]
        qj = q[bj]
        tj = tr[bj]
        hs = has_sc[bj] & (wj != 0.0)
        if hs.any():
            # Blender's add_weighted_dq_dq_pivot: fold the bone's scale, as seen at this
            # vertex (the pivot), into the translation and drop the scale matrix.
            d = np.einsum("pij,pj->pi", sc[bj[hs], :3, :3], arm_co[hs]) + sc[bj[hs], :3, 3] - arm_co[hs]
            qs = qj[hs]
            tj = tj.copy()
            tj[hs, 0] -= 0.5 * (qs[:, 1] * d[:, 0] + qs[:, 2] * d[:, 1] + qs[:, 3] * d[:, 2])
            tj[hs, 1] += 0.5 * (qs[:, 0] * d[:, 0] + qs[:, 2] * d[:, 2] - qs[:, 3] * d[:, 1])
            tj[hs, 2] += 0.5 * (qs[:, 0] * d[:, 1] + qs[:, 3] * d[:, 0] - qs[:, 1] * d[:, 2])
            tj[hs, 3] += 0.5 * (qs[:, 0] * d[:, 2] + qs[:, 1] * d[:, 1] - qs[:, 2] * d[:, 0])
        flip = np.sum(qj * qsum, axis=1) < 0.0
        sw = np.where(flip, -wj, wj)
        qsum += sw[:, None] * qj
        tsum += sw[:, None] * tj
        contrib += wj
    ok = contrib > MIN_CONTRIB
    out = arm_co.copy()
    if ok.any():
        inv = 1.0 / contrib[ok]
        qn = qsum[ok] * inv[:, None]
        tn = tsum[ok] * inv[:, None]
        r = arm_co[ok].copy()
        wq, xq, yq, zq = qn.T
        m = np.empty((qn.shape[0], 3, 3))
        m[:, 0, 0] = wq * wq + xq * xq - yq * yq - zq * zq
        m[:, 0, 1] = 2 * (xq * yq - wq * zq)
        m[:, 0, 2] = 2 * (xq * zq + wq * yq)
        m[:, 1, 0] = 2 * (xq * yq + wq * zq)
        m[:, 1, 1] = wq * wq + yq * yq - xq * xq - zq * zq
        m[:, 1, 2] = 2 * (yq * zq - wq * xq)
        m[:, 2, 0] = 2 * (xq * zq - wq * yq)
        m[:, 2, 1] = 2 * (yq * zq + wq * xq)
        m[:, 2, 2] = wq * wq + zq * zq - xq * xq - yq * yq
        t0, t1, t2, t3 = tn.T
        t = np.stack([
            2.0 * (-t0 * xq + wq * t1 - t2 * zq + yq * t3),
            2.0 * (-t0 * yq + t1 * zq - xq * t3 + wq * t2),
            2.0 * (-t0 * zq + xq * t2 + wq * t3 - t1 * yq),
        ], -1)
        len2 = np.sum(qn * qn, axis=1)
        len2 = np.where(len2 > 0, 1.0 / len2, 0.0)
        res = (np.einsum("pij,pj->pi", m, r) + t) * len2[:, None]
        if armature_weight is not None:
            aw = np.asarray(armature_weight, dtype=np.float64)[ok]
            res = arm_co[ok] + (res - arm_co[ok]) * aw[:, None]
        out[ok] = res
    from_arm = np.linalg.inv(to_arm)
    return out @ from_arm[:3, :3].T + from_arm[:3, 3]


def deform(coords: ArrayLike, rig: SkinningRig, poses: Sequence) -> np.ndarray:
    """Apply a stack of Armature modifiers to ``coords``.

    Parameters
    ----------
    coords : ndarray, shape (p, 3)
        Mesh positions before the first Armature modifier (object space).
    rig : SkinningRig
    poses : list of ndarray, each shape (b_i, 4, 4)
        ``PoseBone.matrix`` of each deformer's armature, in stack order.

    Returns
    -------
    ndarray, shape (p, 3)
    """
    if len(poses) != len(rig.deformers):
        raise ShapeSpaceError(f"poses has {len(poses)} entries for {len(rig.deformers)} armature modifiers",
                              "shape")
    co = np.asarray(coords, dtype=np.float64)
    mesh_world = _as_mats(rig.mesh_world, "mesh_world")
    for d, pose in zip(rig.deformers, poses):
        if d.weights.n_vertices != co.shape[0]:
            raise ShapeSpaceError(
                f"modifier {d.name!r} has weights for {d.weights.n_vertices} vertices, mesh has {co.shape[0]}",
                "vertex_count")
        pose = _as_mats(pose, "pose")
        if d.preserve_volume:
            to_arm = np.linalg.inv(d.armature_world) @ mesh_world
            chan = pose @ np.linalg.inv(d.rest)
            co = dual_quaternion_skinning(co, d.weights, d.rest, chan, to_arm, d.vertex_mask)
        else:
            mats = bone_change_matrices(d, pose, mesh_world)
            co = linear_blend_skinning(co, d.weights, mats, d.vertex_mask)
    return co


def diagnose_weights(weights: SkinWeights, vertex_names: Sequence[str] | None = None, tol: float = 1e-3) -> Result:
    """Report vertices that the skin leaves still or does not normalise.

    Blender divides by the weight sum, so unnormalised weights still deform
    sensibly; all-zero vertices do not move at all.  Both are reported (as
    warnings) so the rigger knows.

    Returns
    -------
    Result
        ``diagnostics`` holds ``unweighted`` and ``unnormalised`` vertex counts.
    """
    w = weights.effective()
    total = w.sum(axis=1)
    zero = np.flatnonzero(total <= MIN_CONTRIB)
    unnorm = np.flatnonzero((total > MIN_CONTRIB) & (np.abs(total - 1.0) > tol))
    issues = []
    if zero.size:
        issues.append(Issue("warning", "unweighted_vertices",
                            f"{zero.size} vertices have no weight on a deforming bone and will not move "
                            f"(first: vertex {int(zero[0])})"))
    if unnorm.size:
        issues.append(Issue("warning", "unnormalised_weights",
                            f"{unnorm.size} vertices have weights that do not sum to 1 "
                            f"(Blender normalises them; first: vertex {int(unnorm[0])}, sum {total[unnorm[0]]:.4g})"))
    return Result(value=total, status=1 if issues else 0, message=issues[0].message if issues else "weights ok",
                  diagnostics={"unweighted": int(zero.size), "unnormalised": int(unnorm.size)}, issues=issues)


def forward_kinematics(rest: ArrayLike, parents: Sequence[int], basis: ArrayLike) -> np.ndarray:
    """Posed bone matrices (armature space) from local pose transforms, as Blender computes them.

    Parameters
    ----------
    rest : ndarray (b, 4, 4)
        ``Bone.matrix_local``.
    parents : sequence of int, length b
        Parent index per bone (−1 for roots); parents must come before children.
    basis : ndarray (b, 4, 4)
        ``PoseBone.matrix_basis`` (the local pose transform).

    Returns
    -------
    ndarray (b, 4, 4)
        ``PoseBone.matrix``: ``pose_parent · rest_parent⁻¹ · rest · basis``.
    """
    rest = np.asarray(rest, dtype=np.float64)
    basis = np.asarray(basis, dtype=np.float64)
    out = np.empty_like(rest)
    for b, par in enumerate(parents):
        local = rest[b] if par < 0 else np.linalg.inv(rest[par]) @ rest[b]
        out[b] = (local if par < 0 else out[par] @ local) @ basis[b]
    return out
