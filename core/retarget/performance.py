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

Keys that move nothing (:func:`empty_keys`) take no part in a geometric fit: no
solver changes their sliders.  From a weight performance they keep the copied
value (clipped to the range, as ``copy`` keys them), from a dense performance
they stay at rest (0, or the nearest end of the range).  A geometric fit whose
dense positions would exceed :data:`MAX_DENSE_BYTES` is refused before any
work, and every result is checked finite (a NaN names the slider).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..blendshape import BlendshapeModel, normalised_unit
from ..errors import ErrorCode
from ..progress import ProgressFn, notify, scaled
from ..result import ShapeSpaceError
from ..validate import array, choice, positive
from .metrics import clipped_mask, per_vertex_mm, position_error_rms, slider_scales, velocity_error_rms, weight_errors
from .perframe import fit_frames
from .spacetime_solver import SpacetimeResult, spacetime

__all__ = ["METHODS", "GEOMETRIC_METHODS", "PerformanceFit", "normalised_basis", "retarget_weights",
           "retarget_positions", "empty_keys", "check_dense_budget", "check_finite_weights", "EMPTY_TOL",
           "MAX_DENSE_BYTES"]

METHODS = ("copy", "learned", "perframe", "spacetime")
GEOMETRIC_METHODS = ("perframe", "spacetime")

#: Bounds of the unbounded ("ideal") per-frame fit of a dense performance.
IDEAL_BOUND = 10.0

#: A key whose largest vertex offset is at most this fraction of the rig's size moves nothing (the
#: ``empty_target`` of :func:`~core.blendshape.diagnose_model`).
EMPTY_TOL = 1e-7

#: Largest dense performance a geometric fit builds: frames × 3 × vertices × 8 bytes (4 GiB).
MAX_DENSE_BYTES = 4 * 2 ** 30


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
    clipped : ndarray of bool (f,)
        Which frames clip (their ideal weights leave the slider ranges), :func:`~.metrics.clipped_mask`.
    solver : SpacetimeResult or None
        The space-time solve, for the ``spacetime`` method.
    vertices : int
        The target's vertex count (the errors per vertex, :attr:`position_error_mm`).
    """

    weights: np.ndarray
    ideal: np.ndarray
    position_error_rms: float
    velocity_error_rms: float
    clipped: np.ndarray
    solver: SpacetimeResult | None = None
    vertices: int = 0

    @property
    def clipping_frames(self) -> int:
        """How many frames clip (:attr:`clipped`)."""
        return int(np.count_nonzero(self.clipped))

    @property
    def position_error_mm(self) -> float:
        """RMS per vertex of the position error, mm at a 30 cm head (:func:`~.metrics.per_vertex_mm`)."""
        return per_vertex_mm(self.position_error_rms, self.vertices)

    @property
    def velocity_error_mm(self) -> float:
        """RMS per vertex of the frame-to-frame error, mm at a 30 cm head."""
        return per_vertex_mm(self.velocity_error_rms, self.vertices)


def normalised_basis(model: BlendshapeModel) -> tuple:
    """The rig in size-normalised units: ``B`` (3p, n), ``b0`` (3p,) and the unit.

    The unit is :func:`~core.blendshape.normalised_unit` (model units per normalised unit).
    """
    unit = normalised_unit(model)
    return model.delta_matrix / unit, model.neutral.ravel() / unit, unit


def empty_keys(model: BlendshapeModel, rel_tol: float = EMPTY_TOL) -> np.ndarray:
    """Keys that move no vertex: bool (n,), ``max |δ_k| ≤ rel_tol · size``."""
    D = model.delta_matrix
    if D.size == 0:
        return np.ones(model.n_targets, dtype=bool)
    return np.abs(D).max(axis=0) <= rel_tol * (model.scale or 1.0)


def check_dense_budget(frames: int, vertices: int, what: str = "the fit") -> None:
    """Refuse a dense performance of ``frames`` × ``vertices`` beyond :data:`MAX_DENSE_BYTES` (before building it)."""
    size = int(frames) * 3 * int(vertices) * 8
    if size > MAX_DENSE_BYTES:
        raise ShapeSpaceError(f"{what} of {int(frames)} frames on {int(vertices)} vertices needs "
                              f"{size / 2 ** 30:.1f} GiB; the limit is {MAX_DENSE_BYTES / 2 ** 30:g} GiB: split the "
                              "take, or use the copy method", ErrorCode.TOO_LARGE)


def check_finite_weights(W: ArrayLike, names: list, what: str = "the fit") -> None:
    """Refuse NaN or infinite weights (f, n), naming the first slider and frame index affected."""
    W = np.asarray(W, dtype=np.float64)
    bad = ~np.isfinite(W)
    if bad.any():
        f, j = (int(i) for i in np.argwhere(bad)[0])
        name = names[j] if j < len(names) else f"#{j}"
        raise ShapeSpaceError(f"{what} gave NaN or infinite weights for slider {name!r} (first at frame index {f}, "
                              f"{int(bad.any(axis=0).sum())} sliders in all)", ErrorCode.NON_FINITE)


#: Frames clipped per progress report by the ``copy`` and ``learned`` methods.
CLIP_CHUNK = 4096


def _fit(B: np.ndarray, b0: np.ndarray, S: np.ndarray, lo: np.ndarray, hi: np.ndarray, method: str,
         ideal: np.ndarray, lam: float, names: list, progress: ProgressFn | None = None) -> tuple:
    """Per-frame or space-time fit of the sliders to positions ``S`` (f, 3p); σ from the ideal weights."""
    if method == "perframe":
        return fit_frames(B, b0, S, lo, hi, progress=progress), None
    # anchored regulariser (#11): pull towards the per-frame ridge fit, not zero, so long takes do not drift
    res = spacetime(B, b0, S, slider_scales(ideal, lo, hi), lam, lo=lo, hi=hi, relative=True, names=names,
                    anchor=True, progress=progress)
    return res.weights, res


def _clip(raw: np.ndarray, lo: np.ndarray, hi: np.ndarray, progress: ProgressFn | None) -> np.ndarray:
    """``clip(raw, lo, hi)`` a chunk of :data:`CLIP_CHUNK` frames at a time, reporting after each."""
    W = np.empty_like(raw)
    for a in range(0, raw.shape[0], CLIP_CHUNK):
        np.clip(raw[a:a + CLIP_CHUNK], lo, hi, out=W[a:a + CLIP_CHUNK])
        notify(progress, min(a + CLIP_CHUNK, raw.shape[0]) / max(raw.shape[0], 1))
    return W


def reduced_geometry(model: BlendshapeModel, raw: np.ndarray, live: np.ndarray) -> tuple:
    """The geometric fit of a weight performance in the rig's own n-dimensional coordinates.

    With ``B = Q R`` (thin QR of the live keys' normalised deltas, ``Q`` orthonormal columns),
    ``‖(W − raw) Bᵀ‖ = ‖(W − raw) Rᵀ‖`` frame by frame and for every linear combination of frames
    (velocities), so the per-frame and space-time fits of ``W`` to the positions ``b0 + raw Bᵀ`` are the
    same problems as fits to ``raw Rᵀ`` with basis ``R`` and a zero neutral — the same normal equations
    ``BᵀB = RᵀR``, the same minimiser — but the source never exists as (f, 3p) positions: memory
    and time are linear in the take length with a constant of the key count, not the vertex count.

    Parameters
    ----------
    model : BlendshapeModel
        The target (n sliders, p vertices).
    raw : ndarray (f, n)
        The ideal (unbounded) weights.
    live : ndarray of bool (n,)
        The keys that move something.

    Returns
    -------
    R : ndarray (r, k)
        ``k = live.sum()``, ``r = min(3p, k)``; upper triangular.
    S : ndarray (f, r)
        ``raw[:, live] Rᵀ``.
    """
    B, _, _ = normalised_basis(model)
    R = np.linalg.qr(B[:, live], mode="r")
    return R, raw[:, live] @ R.T


def retarget_weights(model: BlendshapeModel, ideal: ArrayLike, method: str, lam: float = 1e-7, *,
                     progress: ProgressFn | None = None) -> PerformanceFit:
    """Retarget an unlimited weight performance on the target's sliders.

    ``copy``/``learned``: ``W = clip(ideal, lo, hi)``.  ``perframe``/``spacetime``:
    the sliders of the keys that move something fitted to the geometry
    ``b0 + ideal Bᵀ`` (thesis ch. 5 for space-time, λ relative to the data), solved in the rig's own
    coordinates (:func:`reduced_geometry`, no per-vertex source is built);
    the sliders of empty keys keep ``clip(ideal, lo, hi)``.  Errors are
    measured on ``(W − ideal) Bᵀ`` at every vertex (:mod:`.metrics`).

    Parameters
    ----------
    model : BlendshapeModel
        The target (n sliders, p vertices).
    ideal : ndarray (f, n)
        Finite.
    method : str
        One of :data:`METHODS`.
    lam : float
        Positive, finite.
    progress : callable, optional
        ``progress(fraction)`` (:mod:`core.progress`), called as the work goes on (per chunk of frames for
        ``copy``/``learned``, by the solver for the fits); raising :class:`~core.progress.Cancelled` from it
        stops the work.

    Returns
    -------
    PerformanceFit
        ``weights`` finite and within the slider ranges.
    """
    choice(method, "method", METHODS)
    raw = array(ideal, "ideal", shape=(None, model.n_targets))
    lo, hi = model.slider_min, model.slider_max
    solver = None
    geometric = method in GEOMETRIC_METHODS
    W = _clip(raw, lo, hi, scaled(progress, 0.0, 0.05 if geometric else 0.9))
    if geometric:
        positive(lam, "lam")
        live = ~empty_keys(model)
        if live.any():
            R, S = reduced_geometry(model, raw, live)
            W[:, live], solver = _fit(R, np.zeros(R.shape[0]), S, lo[live], hi[live], method, raw[:, live],
                                      lam, [n for n, keep in zip(model.names, live) if keep],
                                      scaled(progress, 0.05, 0.9))
    check_finite_weights(W, model.names, f"the {method} fit")
    pos, vel = weight_errors(W - raw, model.delta_matrix, model.scale)
    notify(progress, 1.0)
    return PerformanceFit(W, raw, pos, vel, clipped_mask(raw, lo, hi), solver, model.n_vertices)


def retarget_positions(model: BlendshapeModel, positions: ArrayLike, method: str,
                       lam: float = 1e-7, *, progress: ProgressFn | None = None) -> PerformanceFit:
    """Retarget a dense performance given on the target's vertices.

    The ideal weights are the per-frame fit within ±:data:`IDEAL_BOUND`
    (clipping counted with 1e-6 slack, as they are a numerical fit); ``W`` the
    ``perframe`` or ``spacetime`` fit within the slider ranges of the keys that
    move something (empty keys stay at rest, 0 within the range).  Errors are
    measured on ``b0 + W Bᵀ − positions`` at every vertex (:mod:`.metrics`).

    Parameters
    ----------
    model : BlendshapeModel
    positions : ndarray (f, 3p)
        Target-vertex positions per frame, model units; finite.
    method : str
        ``perframe`` or ``spacetime``.
    lam : float
        Positive, finite.
    progress : callable, optional
        ``progress(fraction)`` (:mod:`core.progress`): the ideal fit, then the bounded one; raising
        :class:`~core.progress.Cancelled` from it stops the work.

    Returns
    -------
    PerformanceFit
    """
    choice(method, "method", GEOMETRIC_METHODS)
    positive(lam, "lam")
    S = array(positions, "positions", shape=(None, 3 * model.n_vertices))
    B, b0, unit = normalised_basis(model)
    lo, hi = model.slider_min, model.slider_max
    live = ~empty_keys(model)
    ideal = np.zeros((S.shape[0], model.n_targets))
    W = np.broadcast_to(np.clip(0.0, lo, hi), ideal.shape).copy()
    solver = None
    if live.any():
        Bl = B[:, live]
        bound = np.full(int(live.sum()), IDEAL_BOUND)
        ideal[:, live] = fit_frames(Bl, b0, S / unit, -bound, bound, progress=scaled(progress, 0.0, 0.4))
        W[:, live], solver = _fit(Bl, b0, S / unit, lo[live], hi[live], method, ideal[:, live], lam,
                                  [n for n, keep in zip(model.names, live) if keep], scaled(progress, 0.4, 0.95))
    check_finite_weights(W, model.names, f"the {method} fit")
    residual = (b0 + W @ B.T) * unit - S
    notify(progress, 1.0)
    return PerformanceFit(W, ideal, position_error_rms(residual, model.scale),
                          velocity_error_rms(residual, model.scale), clipped_mask(ideal, lo, hi, 1e-6), solver,
                          model.n_vertices)
