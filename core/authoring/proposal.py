"""Automatic landmark proposal for a target head that has no shapes (issue #13 §1).

The source rig's shapes tell where its landmarks are (the vertex each shape moves most: eyelid, mouth
corner, chin, brow …).  The target has no shapes, so its landmarks are found geometrically:

1. each head gets a frame from its mirror plane (:func:`~core.authoring.mesh.symmetry_plane`: the normal is
   the left–right axis) and the two principal axes of its vertices within that plane;
2. the frames are matched under the 8 proper rotations that keep the left–right axis an axis (in-plane
   quarter turns, and the half turn that swaps left and right) and three starting scales, each refined by
   similarity ICP (Umeyama on closest points, the worst 30 % of pairs trimmed); the hypothesis with the
   smallest trimmed residual measured both ways (source → target and target → source) wins;
3. each source landmark, moved by that similarity, is snapped to the nearest target vertex.

Limits: this is a rigid + uniform-scale fit, and the best fit is not always the right one: a face-only mask
can fit the smooth back of a whole head (facecap ↔ ICT FaceKit: landmarks ~60 mm off, on the wrong side —
the status can still be OK when the residual is small; a curvature-agreement score was tried and was not
reliable across the shared heads).  The proposal is only as good as the two heads are alike after scaling
(a long-nosed cartoon on a realistic head misplaces mouth and eye corners by the difference);
a head that is far from mirror-symmetric (sculpted asymmetric, posed, with a body attached) can get a wrong
frame (the residual in ``diagnostics`` says how well it fits).  The artist corrects the pairs before
registering; :func:`~core.authoring.registration.register` then refines the whole surface.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from .. import validate
from ..result import Result, Status
from .landmarks import MIN_LANDMARKS, LandmarkPairs
from .mesh import bbox_diagonal, check_mesh, symmetry_plane, triangle_parts
from .registration import similarity

__all__ = ["propose_landmark_pairs", "head_frame"]


def head_frame(verts: ArrayLike) -> tuple:
    """A head's frame: centroid (3,) and rotation (3, 3) whose first row is the mirror-plane normal.

    Returns
    -------
    origin : ndarray (3,)
    axes : ndarray (3, 3)
        Rows: mirror normal, first and second in-plane principal axis (right-handed).
    plane_error : float
        Relative mirror residual of :func:`symmetry_plane`.
    """
    V = np.asarray(verts, dtype=np.float64)
    n, _, err = symmetry_plane(V)
    c = V.mean(axis=0)
    X = V - c
    X = X - np.outer(X @ n, n)
    _, _, vt = np.linalg.svd(X, full_matrices=False)
    a = vt[0] - (vt[0] @ n) * n
    a /= np.linalg.norm(a)
    return c, np.stack([n, a, np.cross(n, a)]), err


def _hypotheses():
    out = []
    for flip in (1.0, -1.0):
        for k in range(4):
            ang = k * np.pi / 2
            c, s = np.cos(ang), np.sin(ang)
            rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
            if flip < 0:
                rot = np.diag([-1.0, 1.0, -1.0]) @ rot
            out.append(rot)
    return out


def _trimmed_rms(d, trim):
    keep = d <= np.quantile(d, 1.0 - trim)
    return float(np.sqrt(np.mean(d[keep] ** 2)))


def _similarity_icp(S, T, tree, s, R, t, iterations, trim):
    """Similarity ICP of S onto T; the score is the trimmed RMS in BOTH directions (a source shrunk onto a
    patch of the target fits one way only)."""
    for _ in range(iterations):
        moved = s * S @ R.T + t
        d, idx = tree.query(moved)
        keep = d <= np.quantile(d, 1.0 - trim)
        s, R, t = similarity(S[keep], T[idx[keep]])
    moved = s * S @ R.T + t
    there = _trimmed_rms(tree.query(moved)[0], trim)
    back = _trimmed_rms(cKDTree(moved).query(T)[0], trim)
    return s, R, t, max(there, back)


def propose_landmark_pairs(src_verts: ArrayLike, src_tris: ArrayLike, src_deltas: ArrayLike,
                           src_names: Sequence[str], dst_verts: ArrayLike, dst_tris: ArrayLike, *,
                           iterations: int = 25, trim: float = 0.3, sample: int = 2500) -> Result:
    """Landmark pairs for a target head without shapes, proposed from the source rig's shapes and geometry.

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    src_tris : array_like of int (f_s, 3)
    src_deltas : array_like (k, n_s, 3)
    src_names : sequence of str (k,)
    dst_verts : array_like (n_t, 3)
    dst_tris : array_like of int (f_t, 3)
    iterations : int
        Similarity-ICP iterations per hypothesis.
    trim : float
        Fraction of the worst closest-point pairs ignored (parts one head has and the other has not).
    sample : int
        Vertices used per head for the fit.

    Returns
    -------
    Result
        ``value``: :class:`LandmarkPairs` named after the source shapes; ``diagnostics``: ``fit_residual``
        (trimmed RMS / target diagonal), ``similarity`` ``(s, R, t)``, ``plane_error`` (source, target).
        WARNING when the fit residual exceeds 2 % of the diagonal or a head has no clear mirror plane;
        FAILED when fewer than 5 source shapes move the skin.
    """
    S, ST = check_mesh(src_verts, src_tris, "source")
    T, TT = check_mesh(dst_verts, dst_tris, "target")
    D = validate.array(src_deltas, "source deltas", shape=(None, S.shape[0], 3))
    s_part, _ = triangle_parts(S.shape[0], ST)
    t_part, _ = triangle_parts(T.shape[0], TT)
    skin_s, skin_t = np.flatnonzero(s_part == 0), np.flatnonzero(t_part == 0)
    mag = np.linalg.norm(D[:, skin_s], axis=2) if D.shape[0] else np.zeros((0, skin_s.size))
    peak = mag.max(axis=1) if mag.size else np.zeros(0)
    idx, names = [], []
    for k in np.argsort(-peak):
        if peak[k] <= 0.05 * peak.max():
            continue
        v = int(skin_s[np.argmax(mag[k])])
        if v not in idx:
            idx.append(v)
            names.append(str(src_names[k]))
    if len(idx) < MIN_LANDMARKS:
        return Result(None, status=Status.FAILED,
                      message=f"only {len(idx)} source shapes move the skin: place landmarks by hand")
    rng = np.random.default_rng(0)
    Ss = S[skin_s] if skin_s.size <= sample else S[rng.choice(skin_s, sample, replace=False)]
    Ts = T[skin_t] if skin_t.size <= sample else T[rng.choice(skin_t, sample, replace=False)]
    cs, As, es = head_frame(S[skin_s])
    ct, At, et = head_frame(T[skin_t])
    scale = bbox_diagonal(T[skin_t]) / max(bbox_diagonal(S[skin_s]), 1e-300)
    tree = cKDTree(Ts)
    best = None
    for H in _hypotheses():
        for f in (0.75, 1.0, 1.33):
            R0 = At.T @ H @ As
            t0 = ct - f * scale * R0 @ cs
            fit = _similarity_icp(Ss, Ts, tree, f * scale, R0, t0, iterations, trim)
            if best is None or fit[3] < best[3]:
                best = fit
    s, R, t, resid = best
    moved = s * S[idx] @ R.T + t
    _, j = cKDTree(T[skin_t]).query(moved)
    dst_idx = skin_t[j]
    keep = np.unique(dst_idx, return_index=True)[1]
    keep.sort()
    pairs = LandmarkPairs(S[np.array(idx)[keep]].copy(), T[dst_idx[keep]].copy(), np.array(idx)[keep],
                          dst_idx[keep], tuple(np.array(names)[keep]))
    rel = resid / max(bbox_diagonal(T[skin_t]), 1e-300)
    diag = {"fit_residual": rel, "similarity": (s, R, t), "plane_error": (es, et)}
    warn = rel > 0.02 or es > 0.02 or et > 0.02
    msg = (f"{len(pairs)} landmarks proposed (fit residual {100 * rel:.1f}% of the head size)"
           + ("; check them: the heads do not align well" if warn else ""))
    return Result(pairs, status=Status.WARNING if warn else Status.OK, message=msg, diagnostics=diag)
