"""A whole performance onto a target rig: the fit each retarget method makes, and its report numbers.

Two entry points, one per kind of source:

- :func:`retarget_weights` — a weight performance already on the target's
  sliders but unlimited (copied channels, or a learned map): ``copy`` and
  ``learned`` clip it to the slider ranges; ``perframe`` and ``spacetime``
  fit the sliders, within their ranges, to its geometry;
- :func:`retarget_positions` — a dense performance already on the target's
  vertices (:mod:`.transfer`): ``perframe`` or ``spacetime`` fit.

Both work in size-normalised units (the model's bounding-box diagonal
measures :data:`~core.blendshape.NORMALISED_DIAGONAL`), so λ means the same
for any rig, and report the errors of :mod:`.metrics` against the ideal
(unlimited) performance.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..blendshape import BlendshapeModel, normalised_unit
from ..validate import array, choice
from .metrics import clipping_frames, position_error_rms, slider_scales, velocity_error_rms
from .perframe import fit_frames
from .spacetime_solver import SpacetimeResult, spacetime

__all__ = ["METHODS", "GEOMETRIC_METHODS", "PerformanceFit", "normalised_basis", "retarget_weights",
           "retarget_positions"]

METHODS = ("copy", "learned", "perframe", "spacetime")
GEOMETRIC_METHODS = ("perframe", "spacetime")

#: Bounds of the unbounded ("ideal") per-frame fit of a dense performance.
IDEAL_BOUND = 10.0


@dataclass
class PerformanceFit:
    """The retargeted weights of one performance and how well they follow it.

    Attributes
    ----------
    weights : ndarray (f, n)
        Within the slider ranges.
    ideal : ndarray (f, n)
        The unlimited performance the errors are measured against.
    position_error_rms, velocity_error_rms : float
        :mod:`.metrics`.
    clipping_frames : int
    solver : SpacetimeResult or None
        The space-time solve, for the ``spacetime`` method.
    """

    weights: np.ndarray
    ideal: np.ndarray
    position_error_rms: float
    velocity_error_rms: float
    clipping_frames: int
    solver: SpacetimeResult | None = None


def normalised_basis(model: BlendshapeModel) -> tuple:
    """The rig in size-normalised units: ``B`` (3p, n), ``b0`` (3p,) and the unit.

    The unit is :func:`~core.blendshape.normalised_unit` (model units per normalised unit).
    """
    unit = normalised_unit(model)
    return model.delta_matrix / unit, model.neutral.ravel() / unit, unit


def _fit(B: np.ndarray, b0: np.ndarray, S: np.ndarray, lo: np.ndarray, hi: np.ndarray, method: str,
         ideal: np.ndarray, lam: float) -> tuple:
    """Per-frame or space-time fit of the sliders to positions ``S`` (f, 3p); σ from the ideal weights."""
    if method == "perframe":
        return fit_frames(B, b0, S, lo, hi), None
    res = spacetime(B, b0, S, slider_scales(ideal, lo, hi), lam, lo=lo, hi=hi, relative=True)
    return res.weights, res


def retarget_weights(model: BlendshapeModel, ideal: ArrayLike, method: str, lam: float = 1e-7) -> PerformanceFit:
    """Retarget an unlimited weight performance on the target's sliders.

    ``copy``/``learned``: ``W = clip(ideal, lo, hi)``.  ``perframe``/``spacetime``:
    the sliders fitted to the geometry ``b0 + ideal Bᵀ`` (thesis ch. 5 for
    space-time, λ relative to the data).  Errors are measured on
    ``(W − ideal) Bᵀ`` at every vertex (:mod:`.metrics`).

    Parameters
    ----------
    model : BlendshapeModel
        The target (n sliders, p vertices).
    ideal : ndarray (f, n)
    method : str
        One of :data:`METHODS`.
    lam : float

    Returns
    -------
    PerformanceFit
    """
    choice(method, "method", METHODS)
    raw = array(ideal, "ideal", shape=(None, model.n_targets))
    lo, hi = model.slider_min, model.slider_max
    solver = None
    if method in ("copy", "learned"):
        W = np.clip(raw, lo, hi)
    else:
        B, b0, _ = normalised_basis(model)
        W, solver = _fit(B, b0, b0 + raw @ B.T, lo, hi, method, raw, lam)
    residual = (W - raw) @ model.delta_matrix.T
    return PerformanceFit(W, raw, position_error_rms(residual, model.scale),
                          velocity_error_rms(residual, model.scale), clipping_frames(raw, lo, hi), solver)


def retarget_positions(model: BlendshapeModel, positions: ArrayLike, method: str,
                       lam: float = 1e-7) -> PerformanceFit:
    """Retarget a dense performance given on the target's vertices.

    The ideal weights are the per-frame fit within ±:data:`IDEAL_BOUND`
    (clipping counted with 1e-6 slack, as they are a numerical fit); ``W`` the
    ``perframe`` or ``spacetime`` fit within the slider ranges.  Errors are
    measured on ``b0 + W Bᵀ − positions`` at every vertex (:mod:`.metrics`).

    Parameters
    ----------
    model : BlendshapeModel
    positions : ndarray (f, 3p)
        Target-vertex positions per frame, model units.
    method : str
        ``perframe`` or ``spacetime``.
    lam : float

    Returns
    -------
    PerformanceFit
    """
    choice(method, "method", GEOMETRIC_METHODS)
    S = array(positions, "positions", shape=(None, 3 * model.n_vertices))
    B, b0, unit = normalised_basis(model)
    lo, hi = model.slider_min, model.slider_max
    bound = np.full(model.n_targets, IDEAL_BOUND)
    ideal = fit_frames(B, b0, S / unit, -bound, bound)
    W, solver = _fit(B, b0, S / unit, lo, hi, method, ideal, lam)
    residual = (b0 + W @ B.T) * unit - S
    return PerformanceFit(W, ideal, position_error_rms(residual, model.scale),
                          velocity_error_rms(residual, model.scale), clipping_frames(ideal, lo, hi, 1e-6), solver)
