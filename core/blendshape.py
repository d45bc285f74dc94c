"""Linear blendshape model (thesis ch. 3, Eq. 3.1 in delta form).

The face is ``f = b0 + B w``: ``b0`` is the neutral (the reference key,
"Basis"), ``B`` the delta matrix of size ``3p × n`` whose column ``k`` holds
target ``k`` minus the key it is relative to, scaled by that key's
vertex-group mask, and ``w`` the slider values clamped to each key's slider
range.  This is exactly how Blender evaluates relative shape keys
(``key_evaluate_relative``): muted keys contribute nothing, values outside
``[slider_min, slider_max]`` are clamped, and a key relative to another
non-basis key contributes ``value · (key − relative_key)``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .result import Issue, Result, ShapeSpaceError

__all__ = ["BlendshapeModel", "InBetween", "Combination", "diagnose_model", "bounding_box_diagonal", "hat",
           "NORMALISED_DIAGONAL", "normalised_unit", "MAX_ABS_WEIGHT"]

#: Bounding-box diagonal of the normalised model space: 30, a real head's diagonal in centimetres (the scale
#: at which the thesis' α = 0.1 and μ = 0.001 were tuned).  Solvers and error metrics work in units where
#: the model measures this, so a rig in metres, centimetres or int16 capture units behaves the same.
NORMALISED_DIAGONAL = 30.0

#: Largest captured weight magnitude read (ARKit weights lie in [0, 1]): beyond it a value is damaged data, refused
#: by the offline capture reader (a CSV cell) and by the live decoders (a packet) alike.
MAX_ABS_WEIGHT = 100.0


def hat(w: ArrayLike, left: float, peak: float, right: float) -> np.ndarray:
    """Piecewise-linear tent: 0 at ``left`` and ``right``, 1 at ``peak`` (thesis 3.3.2).

    This is the driver expression ShapeSpace writes for an in-between key:
    ``max(0, min((w - left) / (peak - left), (right - w) / (right - peak)))``.
    """
    w = np.asarray(w, dtype=np.float64)
    return np.maximum(0.0, np.minimum((w - left) / (peak - left), (right - w) / (right - peak)))


def hat_slope(w: ArrayLike, left: float, peak: float, right: float, side: str = "right") -> np.ndarray:
    """One-sided derivative of :func:`hat` (``side`` = "right" or "left"), used by Gauss–Newton."""
    w = np.asarray(w, dtype=np.float64)
    if side == "right":
        up = (w >= left) & (w < peak)
        down = (w >= peak) & (w < right)
    else:
        up = (w > left) & (w <= peak)
        down = (w > peak) & (w <= right)
    return np.where(up, 1.0 / (peak - left), np.where(down, -1.0 / (right - peak), 0.0))


@dataclass
class InBetween:
    """An in-between shape of a primary target, stored as a driven corrective key.

    The face at primary weight ``w`` is piecewise linear through the knots
    (thesis 3.3.2).  Blender has no native in-betweens, so ShapeSpace stores
    ``delta = S_t − t·S_primary`` in a key whose value is driven by
    ``hat(w_primary; left, peak, right)``: at ``w = peak`` the face is ``S_t``
    exactly and between knots it interpolates linearly.

    Attributes
    ----------
    name : str
        The driven key.
    primary : int
        Index of the primary target in :attr:`BlendshapeModel.names`.
    knots : tuple of float
        ``(left, peak, right)``.
    delta : ndarray, shape (p, 3)
    """

    name: str
    primary: int
    knots: tuple
    delta: np.ndarray


@dataclass
class Combination:
    """A combination (corrective) shape: weight = product of 2–3 primary weights (thesis 3.3.3).

    Attributes
    ----------
    name : str
        The driven key.
    inputs : tuple of int
        Indices of the primary targets.
    delta : ndarray, shape (p, 3)
    """

    name: str
    inputs: tuple
    delta: np.ndarray


def bounding_box_diagonal(points: ArrayLike) -> float:
    """Length of the axis-aligned bounding-box diagonal of ``points`` (p, 3)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] == 0:
        return 0.0
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


@dataclass
class BlendshapeModel:
    """A relative shape-key rig as arrays.

    Parameters
    ----------
    neutral : ndarray, shape (p, 3)
        Reference-key vertex positions ``b0`` (object space).
    deltas : ndarray, shape (n, p, 3)
        Per-target displacements, already multiplied by the target's
        vertex-group mask.  ``delta_matrix`` exposes them as the thesis'
        ``B`` (3p × n, rows ordered x0, y0, z0, x1, ...).
    names : list of str, length n
        Shape-key names (reference key excluded).
    slider_min, slider_max : ndarray, shape (n,)
        Slider ranges; evaluation clamps to them as Blender does.
    mute : ndarray of bool, shape (n,)
        Muted keys contribute nothing.
    relative_to : list of str, length n
        Name of the key each target is relative to (the reference key name
        for ordinary targets).
    masks : dict of str -> ndarray (p,)
        Vertex-group masks by target name (only targets that have one).
    values : ndarray, shape (n,)
        Current slider values, as read from the file.
    reference_name : str
        Name of the reference ("Basis") key.
    """

    neutral: np.ndarray
    deltas: np.ndarray
    names: list
    slider_min: np.ndarray = None
    slider_max: np.ndarray = None
    mute: np.ndarray = None
    relative_to: list = None
    masks: dict = field(default_factory=dict)
    values: np.ndarray = None
    reference_name: str = "Basis"
    inbetweens: list = field(default_factory=list)
    combinations: list = field(default_factory=list)

    def __post_init__(self):
        self.neutral = np.ascontiguousarray(self.neutral, dtype=np.float64)
        if self.neutral.ndim != 2 or self.neutral.shape[1] != 3:
            raise ShapeSpaceError(
                f"neutral must have shape (p, 3), got {self.neutral.shape}", "shape")
        p = self.neutral.shape[0]
        self.deltas = np.ascontiguousarray(self.deltas, dtype=np.float64)
        if self.deltas.ndim == 2 and self.deltas.shape[0] == 3 * p:
            # accept the thesis' 3p × n layout too
            self.deltas = np.ascontiguousarray(self.deltas.T.reshape(-1, p, 3))
        if self.deltas.ndim != 3 or self.deltas.shape[1:] != (p, 3):
            raise ShapeSpaceError(
                f"deltas must have shape (n, {p}, 3) or ({3 * p}, n), got {self.deltas.shape}",
                "shape")
        n = self.deltas.shape[0]
        self.names = list(self.names)
        if len(self.names) != n:
            raise ShapeSpaceError(f"names has {len(self.names)} entries, deltas has {n} targets", "shape")
        self.slider_min = self._vector(self.slider_min, 0.0, "slider_min")
        self.slider_max = self._vector(self.slider_max, 1.0, "slider_max")
        if np.any(self.slider_min > self.slider_max):
            bad = [self.names[i] for i in np.flatnonzero(self.slider_min > self.slider_max)]
            raise ShapeSpaceError(f"slider_min exceeds slider_max for {', '.join(bad)}", "range")
        if self.mute is None:
            self.mute = np.zeros(n, bool)
        else:
            self.mute = np.asarray(self.mute, bool)
            if self.mute.shape != (n,):
                raise ShapeSpaceError(f"mute must have shape ({n},), got {self.mute.shape}", "shape")
        self.values = self._vector(self.values, 0.0, "values")
        self._scale = None
        if self.relative_to is None:
            self.relative_to = [self.reference_name] * n
        self.relative_to = list(self.relative_to)
        if len(self.relative_to) != n:
            raise ShapeSpaceError(f"relative_to has {len(self.relative_to)} entries for {n} targets", "shape")

    def _vector(self, v, default, name):
        n = self.deltas.shape[0]
        if v is None:
            return np.full(n, default, dtype=np.float64)
        arr = np.asarray(v, dtype=np.float64)
        if arr.shape != (n,):
            raise ShapeSpaceError(f"{name} must have shape ({n},), got {arr.shape}", "shape")
        return arr.copy()

    # ------------------------------------------------------------------ views
    @property
    def n_targets(self) -> int:
        return self.deltas.shape[0]

    @property
    def n_vertices(self) -> int:
        return self.neutral.shape[0]

    @property
    def delta_matrix(self) -> np.ndarray:
        """The thesis' ``B``, shape (3p, n) (a transposed view, no copy)."""
        return self.deltas.reshape(self.n_targets, 3 * self.n_vertices).T

    @property
    def scale(self) -> float:
        """Model size: bounding-box diagonal of the neutral (used to normalise units).

        Computed once; the model is treated as immutable after construction.
        """
        if self._scale is None:
            self._scale = bounding_box_diagonal(self.neutral)
        return self._scale

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ShapeSpaceError(f"the rig has no shape key named {name!r}", "missing_key") from None

    # ------------------------------------------------------------- evaluation
    def effective_weights(self, weights: ArrayLike) -> np.ndarray:
        """Weights as Blender applies them: clamped to the slider range, 0 when muted.

        Parameters
        ----------
        weights : array_like, shape (n,) or (f, n)
        """
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[-1] != self.n_targets:
            raise ShapeSpaceError(
                f"weights must have last dimension {self.n_targets}, got shape {w.shape}", "shape")
        w = np.clip(w, self.slider_min, self.slider_max)
        return np.where(self.mute, 0.0, w)

    @property
    def is_linear(self) -> bool:
        """True when the rig has no in-betweens or combination shapes."""
        return not (self.inbetweens or self.combinations)

    def driven_values(self, weights: ArrayLike) -> np.ndarray:
        """Values Blender's drivers give the in-between and combination keys, shape (..., d)."""
        w = np.clip(np.asarray(weights, dtype=np.float64), self.slider_min, self.slider_max)
        cols = [hat(w[..., ib.primary], *ib.knots) for ib in self.inbetweens]
        cols += [np.prod(w[..., list(c.inputs)], axis=-1) for c in self.combinations]
        if not cols:
            return np.zeros(w.shape[:-1] + (0,))
        return np.stack(cols, axis=-1)

    def knots_of(self, index: int) -> np.ndarray:
        """Sorted kink positions of slider ``index``'s in-between tents (empty when it has none)."""
        pts = {k for ib in self.inbetweens if ib.primary == index for k in ib.knots}
        return np.array(sorted(pts))

    def segment(self, index: int, w: float, direction: int, eps: float = 1e-9) -> tuple:
        """The interval between kinks that slider ``index`` enters moving from ``w`` in ``direction`` (±1)."""
        knots = self.knots_of(index)
        lo, hi = self.slider_min[index], self.slider_max[index]
        if knots.size == 0:
            return lo, hi
        probe = w + direction * eps
        below = knots[knots <= probe]
        above = knots[knots > probe]
        return (max(lo, below[-1]) if below.size else lo), (min(hi, above[0]) if above.size else hi)

    def driven_slopes(self, weights: ArrayLike, sides: ArrayLike | None = None) -> np.ndarray:
        """Derivative of :meth:`driven_values` w.r.t. the sliders, shape (d, n), at one setting.

        ``sides`` (n,) of ±1 picks, at a kink of an in-between's tent, the
        derivative of the piece entered moving up (+1, default) or down (−1);
        at a slider's upper bound the downward piece is always used (the only
        feasible direction).
        """
        w = np.clip(np.asarray(weights, dtype=np.float64), self.slider_min, self.slider_max)
        sides = np.ones(self.n_targets) if sides is None else np.asarray(sides)
        out = np.zeros((len(self.inbetweens) + len(self.combinations), self.n_targets))
        for r, ib in enumerate(self.inbetweens):
            i = ib.primary
            down = sides[i] < 0 or w[i] >= self.slider_max[i]
            out[r, i] = hat_slope(w[i], *ib.knots, side="left" if down else "right")
        for r, c in enumerate(self.combinations, start=len(self.inbetweens)):
            for i in c.inputs:
                out[r, i] += np.prod([w[j] for j in c.inputs if j != i])
        return out

    def driven_deltas(self) -> np.ndarray:
        """Corrective deltas of the driven keys, shape (d, p, 3)."""
        items = [ib.delta for ib in self.inbetweens] + [c.delta for c in self.combinations]
        if not items:
            return np.zeros((0, self.n_vertices, 3))
        return np.stack([np.asarray(d, dtype=np.float64) for d in items])

    def evaluate(self, weights: ArrayLike | None = None) -> np.ndarray:
        """Vertex positions ``b0 + B w`` (+ driven in-betweens and combinations) for slider settings.

        Parameters
        ----------
        weights : array_like, shape (n,) or (f, n), optional
            Slider values; defaults to :attr:`values`.

        Returns
        -------
        ndarray, shape (p, 3) or (f, p, 3)
        """
        w = self.effective_weights(self.values if weights is None else weights)
        flat = self.deltas.reshape(self.n_targets, 3 * self.n_vertices)
        out = w @ flat
        if not self.is_linear:
            raw = self.values if weights is None else weights
            out = out + self.driven_values(raw) @ self.driven_deltas().reshape(-1, 3 * self.n_vertices)
        return self.neutral + out.reshape(w.shape[:-1] + (self.n_vertices, 3))


def diagnose_model(model: BlendshapeModel, rel_tol: float = 1e-7) -> Result:
    """Find problems in a blendshape model before a solver uses it.

    Checks: non-finite coordinates (error), empty targets, duplicate targets
    (both make ``B`` rank-deficient: solvers regularise, the artist is told
    by name), keys relative to a non-basis key, degenerate slider ranges.

    Parameters
    ----------
    model : BlendshapeModel
    rel_tol : float
        Displacements below ``rel_tol × model.scale`` count as zero.

    Returns
    -------
    Result
        ``value`` is the numerical rank of ``B``; ``issues`` lists findings.
    """
    issues = []
    bad_neutral = ~np.isfinite(model.neutral).all(axis=1)
    if bad_neutral.any():
        issues.append(Issue("error", "non_finite", (
            f"the neutral has {int(bad_neutral.sum())} vertices with NaN or infinite coordinates "
            f"(first: vertex {int(np.flatnonzero(bad_neutral)[0])})")))
    bad_targets = [model.names[k] for k in range(model.n_targets)
                   if not np.isfinite(model.deltas[k]).all()]
    if bad_targets:
        issues.append(Issue("error", "non_finite",
                            f"NaN or infinite coordinates in shape keys: {', '.join(bad_targets)}",
                            tuple(bad_targets)))
    bad_ranges = [model.names[k] for k in range(model.n_targets)
                  if not (np.isfinite(model.slider_min[k]) and np.isfinite(model.slider_max[k]))]
    if bad_ranges:
        issues.append(Issue("error", "non_finite",
                            f"NaN or infinite slider range (slider_min/slider_max) on shape keys: "
                            f"{', '.join(bad_ranges)}", tuple(bad_ranges)))
    if any(i.severity == "error" for i in issues):
        return Result(value=None, status=-1, message=issues[0].message, diagnostics={}, issues=issues)

    scale = model.scale or 1.0
    flat = model.deltas.reshape(model.n_targets, 3 * model.n_vertices)
    norms = np.linalg.norm(flat, axis=1)
    peak = np.abs(flat).max(axis=1) if flat.size else np.zeros(0)
    empty = peak <= rel_tol * scale
    if empty.any():
        names = tuple(model.names[k] for k in np.flatnonzero(empty))
        issues.append(Issue("warning", "empty_target",
                            f"shape keys that move no vertex: {', '.join(names)}", names))
    live = np.flatnonzero(~empty)
    dups = []
    if live.size > 1:
        unit = flat[live] / norms[live, None]
        gram = unit @ unit.T
        close = np.triu(gram > 1.0 - 1e-9, k=1)
        for a, b in zip(*np.nonzero(close)):
            ka, kb = live[a], live[b]
            if abs(norms[ka] - norms[kb]) <= 1e-6 * max(norms[ka], norms[kb]):
                dups.append((model.names[ka], model.names[kb]))
    if dups:
        text = ", ".join(f"{a} = {b}" for a, b in dups)
        issues.append(Issue("warning", "duplicate_target", f"duplicate shape keys: {text}",
                            tuple(x for pair in dups for x in pair)))
    nonbasis = [(n, r) for n, r in zip(model.names, model.relative_to) if r != model.reference_name]
    if nonbasis:
        text = ", ".join(f"{n} (relative to {r})" for n, r in nonbasis)
        issues.append(Issue("warning", "relative_to_non_basis",
                            f"keys relative to a non-basis key, used as key minus its relative key: {text}",
                            tuple(n for n, _ in nonbasis)))
    flat_range = [model.names[k] for k in range(model.n_targets)
                  if model.slider_max[k] - model.slider_min[k] <= 0]
    if flat_range:
        issues.append(Issue("warning", "zero_range",
                            f"shape keys whose slider range is empty: {', '.join(flat_range)}",
                            tuple(flat_range)))
    # Same threshold as "moves no vertex": a direction whose largest singular value is below
    # rel_tol × scale is numerically absent.
    rank = int(np.linalg.matrix_rank(flat[live], tol=rel_tol * scale)) if live.size else 0
    status = 1 if issues else 0
    msg = issues[0].message if issues else f"{model.n_targets} targets, rank {rank}"
    return Result(value=rank, status=status, message=msg, diagnostics={"rank": rank, "n_targets": model.n_targets,
                                       "n_vertices": model.n_vertices, "scale": scale}, issues=issues)


def normalised_unit(model: BlendshapeModel) -> float:
    """Model units per normalised unit: ``model.scale / NORMALISED_DIAGONAL`` (1 for an empty model).

    Parameters
    ----------
    model : BlendshapeModel

    Returns
    -------
    float
        Multiply a normalised length by this to get model units.
    """
    return (model.scale or NORMALISED_DIAGONAL) / NORMALISED_DIAGONAL
