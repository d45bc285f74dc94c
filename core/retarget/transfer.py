"""Dense performances onto a target mesh: head-motion removal and motion transfer (thesis 3.5.4).

A source performance given as vertex positions over time (a mesh sequence,
any deformation) becomes the target's geometry before it is fitted:

- :func:`stabilise` removes rigid head motion frame by frame (rigid
  Procrustes of a stable vertex set onto the rest pose);
- :func:`transfer_motion` carries the source's motion onto the target's
  vertices — vertex to vertex for the same topology, else through landmarks
  (similarity + thin-plate warp of the source rest onto the target neutral,
  then closest points) — rotated and scaled by the similarity between the two
  rests.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..validate import array
from .landmarks import check_landmarks, closest_points, landmark_warp, procrustes

__all__ = ["stabilise", "transfer_motion", "moving_vertices"]


def stabilise(sequence: np.ndarray, rest: ArrayLike, stable: ArrayLike) -> np.ndarray:
    """Remove rigid head motion: align each frame's ``stable`` vertices onto the rest pose (in place).

    Frame ``i ≥ 1`` becomes ``x R_iᵀ + t_i`` with ``(R_i, t_i)`` the rigid
    Procrustes fit of ``sequence[i][stable]`` onto ``rest[stable]``; with fewer
    than 3 stable vertices nothing changes.

    Parameters
    ----------
    sequence : ndarray (f, p, 3)
        Modified in place.
    rest : ndarray (p, 3)
    stable : ndarray of int (k,)

    Returns
    -------
    ndarray (f, p, 3)
        ``sequence``.
    """
    rest = np.asarray(rest, dtype=np.float64)
    stable = np.asarray(stable, dtype=int)
    if stable.size >= 3:
        for i in range(1, sequence.shape[0]):
            _, R, t = procrustes(sequence[i][stable], rest[stable], scaling=False)
            sequence[i] = sequence[i] @ R.T + t
    return sequence


def moving_vertices(deltas: ArrayLike, size: float, rel_tol: float = 1e-6) -> np.ndarray:
    """Vertices some shape moves by more than ``rel_tol · size``: bool (p,) for deltas (n, p, 3)."""
    return np.linalg.norm(np.asarray(deltas, dtype=np.float64), axis=2).max(axis=0) > rel_tol * (size or 1.0)


def transfer_motion(sequence: ArrayLike, rest: ArrayLike, neutral: ArrayLike, deltas: ArrayLike, size: float,
                    src_landmarks: ArrayLike, dst_landmarks: ArrayLike) -> np.ndarray:
    """The source performance on the target's vertices: ``neutral + s (x_f − rest)[corr] Rᵀ``.

    Same topology without landmarks: vertex to vertex, ``(s, R)`` the
    similarity taking the source rest onto the target neutral (the source may
    live in another space, e.g. a world-space cache).  Otherwise landmarks
    (≥ 3 pairs, not collinear, some on vertices a target shape moves): the
    source rest is warped onto the target neutral (:func:`~.landmarks.landmark_warp`),
    every target vertex takes its closest warped source vertex, and ``(s, R)``
    is the landmarks' similarity.

    Parameters
    ----------
    sequence : ndarray (f, p_s, 3)
        Source positions per frame (stabilised).
    rest : ndarray (p_s, 3)
        The source's neutral.
    neutral : ndarray (p_t, 3)
        The target's neutral.
    deltas : ndarray (n, p_t, 3)
        The target's shape deltas (to refuse landmarks only on static vertices).
    size : float
        The target's size (bounding-box diagonal).
    src_landmarks, dst_landmarks : ndarray of int (m,)
        Landmark vertex pairs (may be empty for the same topology).

    Returns
    -------
    ndarray (f, 3 p_t)
        Target-vertex positions per frame (x0, y0, z0, x1, …).
    """
    seq = array(sequence, "sequence", ndim=3)
    rest = array(rest, "rest", shape=(seq.shape[1], 3))
    neutral_t = array(neutral, "neutral", shape=(None, 3))
    src_lm = np.asarray(src_landmarks, dtype=int).ravel()
    dst_lm = np.asarray(dst_landmarks, dtype=int).ravel()
    motion = seq - rest
    if seq.shape[1] == neutral_t.shape[0] and not src_lm.size:
        corr = np.arange(neutral_t.shape[0])
        scale, R, _ = procrustes(rest, neutral_t)
    else:
        if src_lm.size < 3 or src_lm.size != dst_lm.size:
            found = min(src_lm.size, dst_lm.size)
            raise ShapeSpaceError(f"different meshes need at least 3 landmark pairs; found {found}",
                                  ErrorCode.TOO_FEW_LANDMARKS)
        if not moving_vertices(deltas, size)[dst_lm].any():
            raise ShapeSpaceError(f"all {dst_lm.size} landmarks lie on target vertices no shape key moves: place "
                                  "some on the moving face (mouth corners, lids, chin)", ErrorCode.STATIC_LANDMARKS)
        check_landmarks(rest[src_lm], neutral_t[dst_lm])
        scale, R, _ = procrustes(rest[src_lm], neutral_t[dst_lm])
        warped = landmark_warp(rest[src_lm], neutral_t[dst_lm], rest)
        corr, _ = closest_points(neutral_t, warped)
    carried = scale * motion[:, corr, :] @ R.T
    return (neutral_t[None] + carried).reshape(seq.shape[0], -1)
