"""Correspondence between meshes of different topology (thesis 3.5.4).

- :func:`procrustes` — the best similarity ``target ≈ s R source + t`` (Umeyama);
- :func:`landmark_layout`, :func:`check_landmarks` — whether landmark pairs
  determine a warp (≥ 3, not collinear);
- :func:`landmark_warp` — similarity plus a radial-basis residual warp that
  carries every source landmark exactly onto its target;
- :func:`peak_landmarks` — landmark pairs from the shapes two rigs share (the
  vertex each shape moves most);
- :func:`closest_points` — dense correspondence by nearest neighbours.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..rbf import fit_rbf
from ..result import ShapeSpaceError

__all__ = ["procrustes", "landmark_layout", "check_landmarks", "landmark_warp", "peak_landmarks",
           "closest_points"]


def procrustes(source: ArrayLike, target: ArrayLike, scaling: bool = True) -> tuple:
    """Best similarity transform ``target ≈ s·R·source + t`` (Umeyama).

    With centred sets ``X``, ``Y`` and ``U Σ Vᵀ = Yᵀ X``: ``R = U diag(1, 1, d) Vᵀ``
    (``d = sign det(U Vᵀ)``, a proper rotation), ``s = tr(Σ diag(1, 1, d)) / ‖X‖²``.

    Parameters
    ----------
    source, target : ndarray (m, 3)
        Corresponding points, m ≥ 3, not collinear.
    scaling : bool
        Fit the scale (else ``s = 1``: a rigid transform).

    Returns
    -------
    s : float
    R : ndarray (3, 3)
    t : ndarray (3,)
    """
    X = np.asarray(source, dtype=np.float64)
    Y = np.asarray(target, dtype=np.float64)
    if X.shape != Y.shape or X.ndim != 2 or X.shape[1] != 3:
        raise ShapeSpaceError(f"point sets must both be (m, 3); got {X.shape}, {Y.shape}", "shape")
    if X.shape[0] < 3:
        raise ShapeSpaceError("at least 3 points are needed for a rigid alignment", "too_few")
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mx, Y - my
    if np.linalg.matrix_rank(Xc, tol=1e-9 * (np.abs(Xc).max() + 1e-300)) < 2:
        raise ShapeSpaceError("the points are collinear: a rotation is not determined", "collinear")
    U, sv, Vt = np.linalg.svd(Yc.T @ Xc)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(sv) @ D) / np.sum(Xc ** 2)) if scaling else 1.0
    return s, R, my - s * R @ mx


def landmark_layout(landmarks: ArrayLike, rel_tol: float = 1e-3) -> str:
    """``"collinear"``, ``"coplanar"`` or ``"spatial"``: the spread of landmark points (m, 3).

    Judged by the singular values of the centred points relative to the largest.
    """
    X = np.asarray(landmarks, dtype=np.float64)
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv.size < 2 or sv[1] <= rel_tol * sv[0]:
        return "collinear"
    if sv.size < 3 or sv[2] <= rel_tol * sv[0]:
        return "coplanar"
    return "spatial"


def check_landmarks(source_landmarks: ArrayLike, target_landmarks: ArrayLike) -> tuple:
    """Validate landmark pairs: equal (m, 3) shapes, m ≥ 3, not collinear on either side.

    Returns
    -------
    src, dst : ndarray (m, 3)
        The two sets as float64.
    layouts : tuple of str
        Their layouts (:func:`landmark_layout`).
    """
    src = np.asarray(source_landmarks, dtype=np.float64)
    dst = np.asarray(target_landmarks, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ShapeSpaceError(f"source_landmarks and target_landmarks must both have shape (m, 3), got "
                              f"{src.shape} and {dst.shape}", "shape")
    if src.shape[0] < 3:
        raise ShapeSpaceError(f"a landmark warp needs at least 3 landmark pairs, got {src.shape[0]}", "too_few")
    layouts = (landmark_layout(src), landmark_layout(dst))
    if "collinear" in layouts:
        raise ShapeSpaceError("the landmarks lie on a line: add landmarks off that line (e.g. eye corners and "
                              "the chin, not only the mouth)", "collinear")
    return src, dst, layouts


def landmark_warp(source_landmarks: ArrayLike, target_landmarks: ArrayLike, points: ArrayLike) -> np.ndarray:
    """Warp ``points`` so the source landmarks land on the target ones (3.5.4).

    A similarity (Procrustes) aligns the landmark sets, then a thin-plate RBF
    carries the residual so every landmark lands exactly.  Needs at least 3
    landmark pairs, not collinear on either mesh; with coplanar landmarks
    (all on the face's front, or only 3) the residual warp uses the 3-D
    biharmonic kernel ``r`` with a constant, which they determine, instead of
    thin plates with an affine part, which they do not.

    Parameters
    ----------
    source_landmarks, target_landmarks : ndarray (m, 3)
    points : ndarray (p, 3)

    Returns
    -------
    ndarray (p, 3)
    """
    src, dst, layouts = check_landmarks(source_landmarks, target_landmarks)
    s, R, t = procrustes(src, dst)
    aligned = s * src @ R.T + t
    if layouts == ("spatial", "spatial") and src.shape[0] >= 5:
        warp = fit_rbf(aligned, dst - aligned, "thin_plate_spline", 1.0, 1)
    else:   # the 3-D biharmonic kernel r only needs a constant, which any ≥ 1 landmarks determine
        warp = fit_rbf(aligned, dst - aligned, "linear", 1.0, 0)
    moved = s * np.asarray(points, dtype=np.float64) @ R.T + t
    return moved + warp(moved)


def peak_landmarks(source_deltas: ArrayLike, target_deltas: ArrayLike, pairs: Sequence,
                   rel_tol: float = 0.05) -> tuple:
    """Landmark pairs from matching shapes.

    For each mapped pair (i, j), the vertex that shape i moves most on the
    source and shape j on the target (e.g. jawOpen → chin, eyeBlink → lid,
    mouthSmile → corner).

    Parameters
    ----------
    source_deltas : ndarray (n_s, p_s, 3)
    target_deltas : ndarray (n_t, p_t, 3)
    pairs : sequence of (source index, target index)
    rel_tol : float
        Shapes whose peak displacement is below ``rel_tol`` × the rig's largest are skipped (empty or
        faint shapes have no meaningful peak).

    Returns
    -------
    src, dst : ndarray of int (m,)
        Vertex indices, one pair per usable shape pair, each source and target vertex used once.
    used : list of (source index, target index)
        The shape pairs the landmarks come from.
    """
    ds = np.linalg.norm(np.asarray(source_deltas, dtype=np.float64), axis=2)     # (n_s, p_s)
    dt = np.linalg.norm(np.asarray(target_deltas, dtype=np.float64), axis=2)
    src, dst, used = [], [], []
    top_s, top_t = ds.max(initial=0.0), dt.max(initial=0.0)
    for i, j in pairs:
        a, b = int(np.argmax(ds[i])), int(np.argmax(dt[j]))
        if ds[i, a] < rel_tol * top_s or dt[j, b] < rel_tol * top_t or a in src or b in dst:
            continue
        src.append(a)
        dst.append(b)
        used.append((i, j))
    return np.array(src, dtype=int), np.array(dst, dtype=int), used


def closest_points(points: ArrayLike, surface_points: ArrayLike) -> tuple:
    """Nearest ``surface_points`` row for each of ``points`` (dense correspondence).

    Parameters
    ----------
    points : ndarray (p, 3)
    surface_points : ndarray (q, 3)

    Returns
    -------
    index : ndarray of int (p,)
    distance : ndarray (p,)
    """
    from scipy.spatial import cKDTree
    dist, idx = cKDTree(np.asarray(surface_points, dtype=np.float64)).query(np.asarray(points, dtype=np.float64))
    return idx, dist
