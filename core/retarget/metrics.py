"""How well a retargeted performance follows its source (the numbers of the retarget report).

One definition of each, used by every retarget path (weights or dense meshes):

- :func:`position_error_rms` — RMS over frames of the whole-mesh distance
  between the result's geometry and the ideal (unlimited) source motion on
  the target, relative to the target's size;
- :func:`velocity_error_rms` — the same on frame-to-frame differences (the
  quantity space-time cloning matches, thesis ch. 5);
- :func:`weight_errors` — both, for a weight difference on a rig, without forming the dense residual;
- :func:`per_vertex_mm` — either one as the RMS per vertex in mm with the head scaled to a 30 cm
  bounding-box diagonal (the unit of every other ShapeSpace distance; what the report shows);
- :func:`clipped_mask` — frames whose ideal weights leave the slider ranges;
- :func:`slider_scales` — the per-slider scales σ of the space-time regulariser.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["position_error_rms", "velocity_error_rms", "weight_errors", "per_vertex_mm", "clipped_mask",
           "slider_scales", "HEAD_MM"]

#: Floor of the slider scales σ_k, as a fraction of the slider's range.
SIGMA_FLOOR = 0.05

#: Frames whose dense residual :func:`weight_errors` forms at a time (memory stays O(rows · 3p)).
CHUNK_ROWS = 1024


def position_error_rms(residual: ArrayLike, size: float) -> float:
    """``√(mean_f ‖x_f − s_f‖²) / size``: the RMS over frames of the per-frame whole-mesh residual norm.

    Parameters
    ----------
    residual : ndarray (f, 3p) or (f, p, 3)
        Result geometry minus the ideal source geometry on the target's vertices, per frame.
    size : float
        The target's size (bounding-box diagonal), so the error is unit-free.

    Returns
    -------
    float
    """
    R = np.asarray(residual, dtype=np.float64).reshape(len(residual), -1)
    return float(np.sqrt(np.mean(np.sum(R ** 2, axis=1))) / size)


#: The head size every ShapeSpace distance in mm refers to: a 30 cm bounding-box diagonal.
HEAD_MM = 300.0


def per_vertex_mm(error_rms: float, vertices: int) -> float:
    """An error of :func:`position_error_rms` or :func:`velocity_error_rms` (a whole-mesh frame norm over the
    size) as the RMS over frames and vertices of one vertex's distance, in mm at a 30 cm head:
    ``HEAD_MM · error_rms / √p`` (``‖x_f − s_f‖² = Σ_v |x_fv − s_fv|²``).

    Parameters
    ----------
    error_rms : float
    vertices : int
        ``p``, the vertices the residual covers.

    Returns
    -------
    float
    """
    return HEAD_MM * float(error_rms) / float(np.sqrt(vertices)) if vertices > 0 else 0.0


def velocity_error_rms(residual: ArrayLike, size: float) -> float:
    """``√(mean_f ‖Δx_f − Δs_f‖²) / size``: :func:`position_error_rms` of the frame-to-frame differences.

    Parameters
    ----------
    residual : ndarray (f, 3p) or (f, p, 3)
        Result geometry minus the ideal source geometry, per frame (f ≥ 2).
    size : float

    Returns
    -------
    float
    """
    R = np.asarray(residual, dtype=np.float64).reshape(len(residual), -1)
    return position_error_rms(np.diff(R, axis=0), size)


def weight_errors(dW: ArrayLike, delta_matrix: ArrayLike, size: float) -> tuple:
    """Position and velocity error RMS of the residual ``dW Dᵀ``, a few frames at a time.

    The same numbers as :func:`position_error_rms` and :func:`velocity_error_rms` of
    ``dW @ delta_matrix.T`` (the residual is linear in the weights, so its frame
    differences are ``diff(dW) Dᵀ``), without the (f, 3p) array: a long take on a
    dense rig needs O(f·n) memory.

    Parameters
    ----------
    dW : ndarray (f, n)
        Result weights minus ideal weights.
    delta_matrix : ndarray (3p, n)
        ``D``, the rig's shape-key offsets.
    size : float

    Returns
    -------
    (float, float)
        Position and velocity error RMS (``nan`` for velocity with fewer than 2 frames).
    """
    dW = np.asarray(dW, dtype=np.float64)
    D = np.asarray(delta_matrix, dtype=np.float64)
    if dW.shape[0] > 2 * D.shape[1] and D.shape[0] > D.shape[1]:
        # a long take: ‖dW_t Dᵀ‖ = ‖dW_t Rᵀ‖ with D = Q R (Q orthonormal columns), so the frames are multiplied
        # by the n × n factor, not the 3p × n rig: O(p n²) once, then O(f n²) (a 27k-vertex rig, 1,640 frames:
        # 0.1 s instead of 2.6 s, and the worker reaches its next progress call — a cancel — that much sooner)
        D = np.linalg.qr(D, mode="r")

    def rms(X: np.ndarray) -> float:
        if X.shape[0] == 0:
            return float("nan")
        total = 0.0
        for a in range(0, X.shape[0], CHUNK_ROWS):
            R = X[a:a + CHUNK_ROWS] @ D.T
            total += float(np.sum(R ** 2))
        return float(np.sqrt(total / X.shape[0]) / size)

    return rms(dW), rms(np.diff(dW, axis=0))


def clipped_mask(ideal: ArrayLike, lo: ArrayLike, hi: ArrayLike, tol: float = 1e-9) -> np.ndarray:
    """Frames whose ideal (unbounded) weights leave the slider ranges: bool (f,) — the one clipping count
    (the report's ``clipping_frames`` is its sum, ``clipped_frames`` its runs).

    Frame f clips when ``∃k: w_fk < lo_k − tol  or  w_fk > hi_k + tol``.

    Parameters
    ----------
    ideal : ndarray (f, n)
    lo, hi : ndarray (n,)
    tol : float
        Slack for weights that are themselves the result of a numerical fit.

    Returns
    -------
    ndarray of bool (f,)
    """
    W = np.asarray(ideal, dtype=np.float64)
    if W.ndim != 2:
        raise ValueError(f"ideal weights must be (frames, sliders), got shape {W.shape}")
    return np.any((W < np.asarray(lo) - tol) | (W > np.asarray(hi) + tol), axis=1)


def slider_scales(ideal: ArrayLike, lo: ArrayLike, hi: ArrayLike, floor: float = SIGMA_FLOOR) -> np.ndarray:
    """σ_k = max(std_f w_fk, floor · (hi_k − lo_k)): the spread of each ideal slider, floored (thesis 5.5).

    Parameters
    ----------
    ideal : ndarray (f, n)
    lo, hi : ndarray (n,)
    floor : float

    Returns
    -------
    ndarray (n,)
    """
    return np.maximum(np.asarray(ideal, dtype=np.float64).std(axis=0), floor * (np.asarray(hi) - np.asarray(lo)))
