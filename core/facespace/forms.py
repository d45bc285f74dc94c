"""Whole-face, delta and convex forms of a blendshape rig (thesis 3.7.3).

J.P. Lewis, *Learning from the Artist*, 2016, section 3.7.3: the *delta* form
``f = b0 + B w`` (``B`` holds the target displacements ``d_k = b_k − b0``) and the
*whole-face* form ``f = Σ_{k≥0} c_k b_k`` are the same rig when the whole-face
weights sum to one, ``c = [1 − Σw, w]``; otherwise the neutral itself is scaled.
The *convex* slider mode keeps the whole-face weights a convex combination
(every slider in [0, 1] and ``Σw ≤ 1``), so the face stays inside the hull of the
targets and the neutral.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..result import Result, ShapeSpaceError, Status
from ._common import EPS, check_model, shaped

__all__ = ["to_whole_face", "from_whole_face", "whole_face_weights", "delta_weights", "project_convex",
           "convex_slider_values", "neutral_key_count"]


def to_whole_face(model: BlendshapeModel) -> tuple[np.ndarray, np.ndarray]:
    """Whole-face targets ``b_k = b0 + d_k`` and the neutral ``b0`` (thesis 3.7.3).

    Primary targets only: in-betweens and combinations are correctives, not faces.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` targets over ``p`` vertices.

    Returns
    -------
    targets : ndarray, shape (n, p, 3)
    neutral : ndarray, shape (p, 3)
        A copy of ``model.neutral``.
    """
    check_model(model, need_targets=False)
    return model.neutral + model.deltas, model.neutral.copy()


def neutral_key_count(slider_min: ArrayLike, slider_max: ArrayLike, limit: float = 10.0) -> int:
    """How many Neutral keys share the neutral's whole-face weight ``c0 = 1 − Σw`` (thesis 3.7.3).

    A host application may bound every key weight to ``[−limit, limit]`` (Blender: ±10).  Splitting
    ``b0`` over ``K`` identical keys, each weighted ``c0 / K``, keeps ``Σ_k c_k b_k`` exact for every
    slider vector of the box ``slider_min ≤ w ≤ slider_max`` when ``|c0| / K ≤ limit``:
    ``K = ⌈max(|1 − Σ slider_max|, |1 − Σ slider_min|) / limit⌉`` (at least 1).

    Parameters
    ----------
    slider_min, slider_max : array_like, shape (n,)
        Finite slider ranges, ``slider_min ≤ slider_max``.
    limit : float
        Largest weight magnitude one key may take, > 0.

    Returns
    -------
    int
    """
    lo = validate.array(slider_min, "slider_min", ndim=1)
    hi = validate.array(slider_max, "slider_max", shape=lo.shape)
    limit = validate.positive(limit, "limit")
    if np.any(lo > hi):
        raise ShapeSpaceError("slider_min must not exceed slider_max", ErrorCode.RANGE)
    worst = max(abs(1.0 - hi.sum()), abs(1.0 - lo.sum()))
    return max(1, int(np.ceil(worst / limit - 1e-9)))


def from_whole_face(neutral: ArrayLike, targets: ArrayLike, names: list[str], slider_min: ArrayLike | None = None,
                    slider_max: ArrayLike | None = None, reference_name: str = "Basis") -> BlendshapeModel:
    """Delta-form rig ``d_k = b_k − b0`` from whole-face targets (thesis 3.7.3).

    Parameters
    ----------
    neutral : array_like, shape (p, 3)
        ``b0``.
    targets : array_like, shape (n, p, 3)
        Whole faces ``b_k``.
    names : list of str, length n
    slider_min, slider_max : array_like, shape (n,), optional
    reference_name : str
        Name of the reference (basis) key.

    Returns
    -------
    BlendshapeModel
        ``neutral = b0``, ``deltas = b_k − b0`` (n, p, 3).
    """
    b0 = shaped(neutral, "neutral", "(p, 3)", ndims=(2,), last=3)
    bk = shaped(targets, "targets", f"(n, {b0.shape[0]}, 3)", ndims=(3,))
    if bk.shape[1:] != b0.shape:
        raise ShapeSpaceError(f"targets must have shape (n, {b0.shape[0]}, 3), got {bk.shape}", ErrorCode.SHAPE)
    return BlendshapeModel(b0, bk - b0, names, slider_min=slider_min, slider_max=slider_max,
                           reference_name=reference_name)


def whole_face_weights(w: ArrayLike) -> np.ndarray:
    """Sum-to-one whole-face weights ``c = [1 − Σw, w]`` of delta weights (thesis 3.7.3).

    ``b0 + B w = (1 − Σw) b0 + Σ_k w_k b_k``.

    Parameters
    ----------
    w : array_like, shape (n,) or (f, n)
        Delta (slider) weights.

    Returns
    -------
    ndarray, shape (n + 1,) or (f, n + 1)
        Entry 0 weights the neutral ``b0``.
    """
    arr = shaped(w, "w", "(n,) or (f, n)", ndims=(1, 2))
    return np.concatenate([1.0 - arr.sum(axis=-1, keepdims=True), arr], axis=-1)


def delta_weights(c: ArrayLike) -> tuple[np.ndarray, float | np.ndarray]:
    """Delta weights and neutral scale of any whole-face weights (inverse of :func:`whole_face_weights`).

    ``Σ_{k≥0} c_k b_k = (Σc) b0 + Σ_{k≥1} c_k d_k`` (thesis 3.7.3): unless ``Σc = 1`` the
    combination scales the neutral itself (the head grows or shrinks about the origin),
    which is why whole-face rigs need sum-to-one weights.

    Parameters
    ----------
    c : array_like, shape (n + 1,) or (f, n + 1)
        Entry 0 weights the neutral ``b0``; convex or not.

    Returns
    -------
    w : ndarray, shape (n,) or (f, n)
        ``c_1 … c_n``.
    scale : float or ndarray, shape (f,)
        ``Σc``: the face is ``scale · b0 + B w``.
    """
    arr = shaped(c, "c", "(n + 1,) or (f, n + 1)", ndims=(1, 2))
    if arr.shape[-1] == 0:
        raise ShapeSpaceError(f"c must have shape (n + 1,) or (f, n + 1) with n ≥ 0, got {arr.shape}",
                              ErrorCode.SHAPE)
    scale = arr.sum(axis=-1)
    return arr[..., 1:].copy(), (float(scale) if arr.ndim == 1 else scale)


def _bounds(lo: ArrayLike, hi: ArrayLike, n: int) -> tuple[np.ndarray, np.ndarray]:
    lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (n,))
    hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (n,))
    if not np.all(np.isfinite(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
        raise ShapeSpaceError("lo must be finite and lo ≤ hi for every slider", ErrorCode.RANGE)
    if lo.sum() > 1.0 + 1e-12 * max(1.0, np.abs(lo).sum()):
        raise ShapeSpaceError(f"lo sums to {lo.sum():g} > 1: the convex slider set is empty", ErrorCode.INFEASIBLE)
    return lo, hi


def _project_rows(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Projection of rows ``v`` (r, n) with ``Σ clip(v, lo, hi) > 1`` onto ``Σx = 1`` (λ > 0)."""
    a, b = np.zeros(v.shape[0]), (v - lo).max(axis=1)        # Σ clip(v − a) > 1 ≥ Σ clip(v − b)
    for _ in range(200):
        mid = 0.5 * (a + b)
        over = np.clip(v - mid[:, None], lo, hi).sum(axis=1) > 1.0
        a, b = np.where(over, mid, a), np.where(over, b, mid)
        if np.all(b - a <= 4 * EPS * b):
            break
    y = v - b[:, None]
    free = (y > lo) & (y < hi)
    fixed = np.where(free, 0.0, np.where(y >= hi, hi, lo)).sum(axis=1)
    nf = free.sum(axis=1)
    lam = np.where(nf > 0, ((v * free).sum(axis=1) + fixed - 1.0) / np.maximum(nf, 1), b)
    exact, rough = np.clip(v - np.maximum(lam, 0.0)[:, None], lo, hi), np.clip(y, lo, hi)
    better = np.abs(exact.sum(axis=1) - 1.0) <= np.abs(rough.sum(axis=1) - 1.0)
    return np.where(better[:, None], exact, rough)


def project_convex(w: ArrayLike, lo: float | ArrayLike = 0.0, hi: float | ArrayLike = 1.0) -> np.ndarray:
    """Euclidean projection of slider vectors onto ``{lo ≤ x ≤ hi, Σx ≤ 1}`` (thesis 3.7.3).

    The convex slider mode: the neutral's whole-face weight ``1 − Σx`` stays ≥ 0.
    KKT: ``x = clip(w − λ, lo, hi)``, ``λ ≥ 0``, ``λ (Σx − 1) = 0``.  ``Σ clip(w − λ)``
    is continuous and non-increasing, so ``λ`` is bracketed by bisection (all frames at
    once) and then made exact by solving ``Σx = 1`` on the free set the bracket identifies.

    Parameters
    ----------
    w : array_like, shape (n,) or (f, n)
    lo, hi : float or array_like, shape (n,)
        Finite lower bounds with ``Σ lo ≤ 1``; upper bounds may be ``inf``.

    Returns
    -------
    ndarray, shape of ``w``
    """
    arr = shaped(w, "w", "(n,) or (f, n)", ndims=(1, 2))
    lo, hi = _bounds(lo, hi, arr.shape[-1])
    x = np.atleast_2d(arr)
    out = np.clip(x, lo, hi)
    rows = np.flatnonzero(out.sum(axis=1) > 1.0)
    if rows.size:
        out[rows] = _project_rows(x[rows], lo, hi)
    return out.reshape(arr.shape)


def convex_slider_values(w: ArrayLike, slider_min: ArrayLike, slider_max: ArrayLike) -> Result:
    """The nearest convex slider values to ``w`` within the sliders' ranges (thesis 3.7.3).

    Each slider is kept in its range intersected with [0, 1] and ``Σx ≤ 1``, so the
    neutral's whole-face weight ``1 − Σx`` stays ≥ 0 (:func:`project_convex`).

    Parameters
    ----------
    w : array_like, shape (n,)
        Current slider values.
    slider_min, slider_max : array_like, shape (n,)
        The sliders' ranges.

    Returns
    -------
    Result
        ``value``: the projected values, shape (n,).  ``diagnostics``: ``sum_before``,
        ``sum_after`` and ``moved`` (Euclidean distance the sliders moved).
    """
    w = shaped(w, "w", "(n,)", ndims=(1,))
    lo = np.clip(np.asarray(slider_min, dtype=np.float64), 0.0, 1.0)
    hi = np.clip(np.asarray(slider_max, dtype=np.float64), 0.0, 1.0)
    x = project_convex(w, lo, np.maximum(hi, lo))
    diag = {"sum_before": float(w.sum()), "sum_after": float(x.sum()), "moved": float(np.linalg.norm(x - w))}
    return Result(x, status=Status.OK, message=f"slider sum {diag['sum_before']:.3f} → {diag['sum_after']:.3f}",
                  diagnostics=diag)
