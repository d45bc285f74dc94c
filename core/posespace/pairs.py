"""Bone-pair pose features for weighted PSD: how a vertex's bones turn *relative to each other*.

Linear blend skinning moves a vertex by the blend ``Σ_b w_vb C_b`` of its bones' channel transforms
``C_b = pose_b · rest_b⁻¹``.  Where the blended transforms agree the vertex moves rigidly and needs no
corrective; the artefacts a corrective repairs (collapsing joints, candy wrappers, lost volume) grow with
how far the blended rotations *differ*: the relative rotations ``C_aᵀ C_b`` between the vertex's bones
(thesis 8.1: skinning weights tell which part of the pose matters to a vertex).  A joint that turns all
of a vertex's bones together (a parent of all of them) changes none of those relative rotations.

:class:`BonePairs` turns a pose-space location (the readers' features, :mod:`.readers`) into one
relative rotation per pair of pose-space bones that share a vertex, ``(C_aᵀ C_b − I)/√2`` (9 numbers, the
rotation reader's own scaling, so its distance is ``2|sin(θ/2)|`` for a relative turn by θ).  The
channels come from forward kinematics of the readers' local rotations alone (bones that are not in the
pose space stay at rest, as the pose space assumes): for a bone with pose-space ancestor ``p``,
``C_b = C_p · Q_b R_b Q_bᵀ`` with ``Q_b`` the rotation of the bone's rest matrix and ``R_b`` its local
rotation.  Weighted PSD's bone-pair distance (:func:`core.posespace.psd.train_psd`, ``blend="pairs"``)
weighs these per vertex:

``d_v(x, x_k)² = Σ_{a<b} w_va w_vb ‖r_ab(x) − r_ab(x_k)‖² + s Σ_a w_va² ‖x_a − x_ka‖²``

with ``s`` = :data:`SINGLE_WEIGHT` keeping each bone's own rotation in view (a bulge on a vertex skinned to
one bone).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .readers import PoseReader, feature_groups

__all__ = ["SINGLE_WEIGHT", "BonePairs", "bone_pairs", "pair_metric"]

#: Weight of each bone's own (local) rotation in the bone-pair distance, times the squared skin weight:
#: measured on RobotExpressive's and the RPM hand (a quarter beats a half and one at 8 examples).
SINGLE_WEIGHT = 0.25


@dataclass(frozen=True)
class BonePairs:
    """Relative rotations between pose-space bones, from pose features.

    Attributes
    ----------
    groups : ndarray of int, shape (R,)
        The weighted-PSD group (pose source) of each rotation-read bone.
    columns : ndarray of int, shape (R, 9)
        Each bone's rotation-reader feature columns.
    scales : ndarray, shape (R,)
        Each rotation reader's scale.
    rest : ndarray, shape (R, 3, 3)
        Rotation of each bone's rest matrix (armature space).
    parent : ndarray of int, shape (R,)
        Nearest ancestor among the R bones, −1 for none; parents come first.
    pairs : ndarray of int, shape (P, 2)
        Bone pairs (indices into the R bones) that share a vertex.
    """

    groups: np.ndarray
    columns: np.ndarray
    scales: np.ndarray
    rest: np.ndarray
    parent: np.ndarray
    pairs: np.ndarray

    @property
    def n_pairs(self) -> int:
        """Number of bone pairs P."""
        return int(self.pairs.shape[0])

    def channels(self, X: ArrayLike) -> np.ndarray:
        """Channel rotations ``C_b`` of the R bones at each pose, shape (K, R, 3, 3), from features (K, d)."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        local = X[:, self.columns].reshape(X.shape[0], -1, 3, 3) * (np.sqrt(2.0) / self.scales[None, :, None, None])
        local += np.eye(3)
        step = self.rest[None] @ local @ np.swapaxes(self.rest, -1, -2)[None]      # Q R Qᵀ
        C = np.empty_like(step)
        for b, p in enumerate(self.parent):
            C[:, b] = step[:, b] if p < 0 else C[:, p] @ step[:, b]
        return C

    def features(self, X: ArrayLike) -> np.ndarray:
        """Relative-rotation features ``(C_aᵀ C_b − I)/√2`` of every pair, shape (K, 9P), from (K, d)."""
        C = self.channels(X)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        rel = np.swapaxes(C[:, a], -1, -2) @ C[:, b] - np.eye(3)
        return rel.reshape(C.shape[0], -1) / np.sqrt(2.0)


def _rotation(m: np.ndarray) -> np.ndarray:
    """The rotation of a 3 × 3 matrix (polar factor: scale and shear in a rest matrix dropped)."""
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


def bone_pairs(readers: Sequence[PoseReader], bone_names: Sequence[str], rest: ArrayLike, parents: Sequence[int],
               vertex_groups: ArrayLike, vertex_weights: ArrayLike) -> BonePairs | None:
    """The bone pairs of a skinned mesh's pose space, or None when no vertex has two rotation-read bones.

    Parameters
    ----------
    readers : sequence of PoseReader
        The pose space; its ``rotation`` readers of bones take part.
    bone_names : sequence of str, length B
        The armature's bones.
    rest : array_like, shape (B, 4, 4)
        Rest matrices (armature space, ``Bone.matrix_local``).
    parents : sequence of int, length B
        Parent index per bone (−1 for roots).
    vertex_groups, vertex_weights : array_like, shape (p, m)
        Weighted-PSD influences (group index into the pose sources, −1 padding) as from
        :func:`core.posespace.psd.skin_group_inputs`.

    Returns
    -------
    BonePairs or None
    """
    rest = np.asarray(rest, dtype=np.float64)
    if rest.shape != (len(bone_names), 4, 4) or len(parents) != len(bone_names):
        raise ShapeSpaceError(f"bone_pairs needs one rest matrix and parent per bone: {len(bone_names)} bones, "
                              f"rest {rest.shape}, {len(parents)} parents", ErrorCode.SHAPE)
    sources = list(feature_groups(readers))
    bone_of = {n: i for i, n in enumerate(bone_names)}
    start, rotation_cols = 0, {}
    for r in readers:
        if r.kind == "rotation" and r.source in bone_of and r.source not in rotation_cols:
            rotation_cols[r.source] = (np.arange(start, start + 9), r.scale)
        start += r.dims
    # parents first: order the read bones by depth in the armature
    depth = {}

    def depth_of(b):
        if b not in depth:
            depth[b] = 0 if parents[b] < 0 else depth_of(parents[b]) + 1
        return depth[b]
    read = sorted(rotation_cols, key=lambda n: (depth_of(bone_of[n]), bone_of[n]))
    index = {bone_of[n]: i for i, n in enumerate(read)}
    pairs = _shared_pairs(read, sources, vertex_groups, vertex_weights)
    if len(pairs) == 0:
        return None
    parent = []
    for n in read:
        p = parents[bone_of[n]]
        while p >= 0 and p not in index:
            p = parents[p]
        parent.append(index.get(p, -1))
    return BonePairs(groups=np.array([sources.index(n) for n in read]),
                     columns=np.stack([rotation_cols[n][0] for n in read]),
                     scales=np.array([rotation_cols[n][1] for n in read], dtype=np.float64),
                     rest=np.stack([_rotation(rest[bone_of[n], :3, :3]) for n in read]),
                     parent=np.array(parent, dtype=np.int64), pairs=pairs)


def _shared_pairs(read: Sequence[str], sources: Sequence[str], vertex_groups, vertex_weights) -> np.ndarray:
    """(P, 2) pairs of read bones (indices into ``read``, a < b) that some vertex is skinned to both of."""
    gi = np.asarray(vertex_groups, dtype=np.int64)
    gw = np.asarray(vertex_weights, dtype=np.float64)
    to_read = np.full(len(sources) + 1, -1)
    for i, n in enumerate(read):
        to_read[sources.index(n)] = i
    r = np.where((gi >= 0) & (gw > 0), to_read[np.where(gi >= 0, gi, len(sources))], -1)
    found = set()
    m = r.shape[1]
    for i in range(m):
        for j in range(i + 1, m):
            a, b = r[:, i], r[:, j]
            ok = (a >= 0) & (b >= 0) & (a != b)
            for x, y in np.unique(np.sort(np.stack([a[ok], b[ok]], axis=1), axis=1), axis=0):
                found.add((int(x), int(y)))
    return np.array(sorted(found), dtype=np.int64).reshape(-1, 2)


def pair_metric(pairs: BonePairs, vertex_groups: np.ndarray, vertex_weights: np.ndarray,
                n_groups: int) -> Any:
    """Per-vertex weights of the bone-pair distance: sparse (p × (G + P)), columns the G pose sources' own
    distances (weight :data:`SINGLE_WEIGHT` · w²) then the P pairs' (weight ``w_a w_b``).

    ``vertex_groups``/``vertex_weights`` (p, m) are normalised influences (each vertex's weights sum to 1).
    """
    import scipy.sparse as sp
    p, m = vertex_groups.shape
    to_read = np.full(n_groups + 1, -1)
    to_read[pairs.groups] = np.arange(pairs.groups.size)
    R = pairs.groups.size
    pair_col = np.full((R, R), -1, dtype=np.int64)
    pair_col[pairs.pairs[:, 0], pairs.pairs[:, 1]] = n_groups + np.arange(pairs.n_pairs)
    ok = vertex_groups >= 0
    rows = [np.repeat(np.arange(p), m)[ok.ravel()]]
    cols = [vertex_groups[ok]]
    vals = [SINGLE_WEIGHT * vertex_weights[ok] ** 2]
    rd = to_read[np.where(ok, vertex_groups, n_groups)]
    for i in range(m):
        for j in range(i + 1, m):
            a, b = rd[:, i], rd[:, j]
            live = (a >= 0) & (b >= 0) & (a != b)
            col = pair_col[np.minimum(a, b)[live], np.maximum(a, b)[live]]
            keep = col >= 0                     # every shared pair is a column (bone_pairs found them all)
            rows.append(np.flatnonzero(live)[keep])
            cols.append(col[keep])
            vals.append((vertex_weights[live, i] * vertex_weights[live, j])[keep])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(p, n_groups + pairs.n_pairs))
