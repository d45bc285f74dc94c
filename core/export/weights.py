"""Shape-key weights an importer will not clamp: split a key whose weights leave [0, 1] and rescale its parts.

A blendshape contributes ``w(t) d`` (thesis Eq. 3.1: ``f = b + Σ_k w_k d_k``).  Pose-space correctives and
in-range sliders with wide ranges give weights outside [0, 1] (PSD weights of CesiumMan run −1.36…1.72),
and importers that clamp weights to [0, 1] (Unity by default, many glTF viewers) change the mesh.  Any
weight curve is exactly a sum of two curves in [0, 1] on rescaled copies of the key:

    w d = (max(w, 0) / s₊) (s₊ d) + (min(w, 0) / s₋) (s₋ d),   s₊ = max(1, max w),  s₋ = min w  (< 0)

Each part's weight lies in [0, 1]; the identity holds sample by sample, and — because both parts are
piecewise linear in the same keys and ``max(w, 0) + min(w, 0) = w`` — also between linearly interpolated
samples.  Only keys that need it are changed: weights already in [0, 1] (within ``tolerance``) keep one
part with scale 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..validate import array, non_negative

__all__ = ["NEGATIVE_SUFFIX", "WeightPart", "split_weights", "recombine", "weight_range"]

#: Name suffix of the key that carries the negative part of a split key.
NEGATIVE_SUFFIX = "__neg"

#: Weights this far outside [0, 1] are float noise (an importer clamping them moves a vertex by < 1e-6 d).
DEFAULT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class WeightPart:
    """One exported key of a split shape key.

    Attributes
    ----------
    suffix : str
        ``""`` for the key itself, :data:`NEGATIVE_SUFFIX` for its negative part.
    scale : float
        The exported key's displacement is ``scale · d`` (``d``: the source key's displacement).
    weights : ndarray, shape (f,)
        Its weight at every sample, in [0, 1].
    """

    suffix: str
    scale: float
    weights: np.ndarray


def weight_range(weights: ArrayLike) -> tuple[float, float]:
    """(min, max) of a weight curve (f,); (0, 0) for an empty one."""
    w = array(weights, "weights", ndim=1)
    return (float(w.min()), float(w.max())) if w.size else (0.0, 0.0)


def split_weights(weights: ArrayLike, tolerance: float = DEFAULT_TOLERANCE) -> list[WeightPart]:
    """Parts of a key whose weight curve leaves [0, 1], each with weights in [0, 1] (module docstring).

    Parameters
    ----------
    weights : array_like, shape (f,)
        The key's effective weight at every sample (finite).
    tolerance : float
        Weights within ``[-tolerance, 1 + tolerance]`` count as in range (no split, no rescale).

    Returns
    -------
    list of WeightPart
        The positive part first (suffix ``""``, always present so the key keeps its name), then the
        negative part when the curve goes below ``-tolerance``.  ``Σ part.scale · part.weights == weights``
        to float precision (see :func:`recombine`).
    """
    w = array(weights, "weights", ndim=1)
    tol = non_negative(tolerance, "tolerance")
    lo, hi = weight_range(w)
    if lo >= -tol and hi <= 1.0 + tol:
        return [WeightPart("", 1.0, np.clip(w, 0.0, 1.0) if w.size else w.copy())]
    s_pos = hi if hi > 1.0 + tol else 1.0
    parts = [WeightPart("", float(s_pos), np.clip(np.maximum(w, 0.0) / s_pos, 0.0, 1.0))]
    if lo < -tol:
        parts.append(WeightPart(NEGATIVE_SUFFIX, float(lo), np.clip(np.minimum(w, 0.0) / lo, 0.0, 1.0)))
    return parts


def recombine(parts: list[WeightPart]) -> np.ndarray:
    """``Σ part.scale · part.weights`` (f,): the source weight curve the parts stand for."""
    if not parts:
        return np.zeros(0)
    return np.sum([p.scale * np.asarray(p.weights, dtype=np.float64) for p in parts], axis=0)
