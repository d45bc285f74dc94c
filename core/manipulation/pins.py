"""Pins: surface points of a blendshape model and their rows of the delta matrix (thesis Eq. 4.5).

A pin is a point on the surface, a barycentric combination of 1–3 vertices
(a vertex, an edge point or a triangle point).  For ``k`` pins and ``n``
sliders the data term of Eq. 4.5 is ``‖R w − m‖²`` with ``R`` (3k × n) the
pins' rows of the delta matrix and ``m`` their targets minus the neutral;
:class:`PinRows` computes these once per set of pins and evaluates the pins'
positions, including in-between and combination (driven) keys.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..blendshape import BlendshapeModel, normalised_unit
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .rig import check_model, rig_facts

__all__ = ["Pin", "PinRows", "pin_matrix", "pin_rest_positions", "pin_positions", "pins_key"]


@dataclass(frozen=True)
class Pin:
    """A point on the surface: ``Σ weights[i] · vertex[vertices[i]]``.

    Parameters
    ----------
    vertices : tuple of int
        1–3 vertex indices (a vertex, an edge point or a triangle point).
    weights : tuple of float
        Barycentric weights, same length, summing to 1.
    """

    vertices: tuple
    weights: tuple = (1.0,)

    @staticmethod
    def at_vertex(index: int) -> "Pin":
        """The pin sitting exactly on vertex ``index``."""
        return Pin((int(index),), (1.0,))


def pins_key(pins: Sequence[Pin]) -> tuple:
    """A hashable identity of a list of pins (vertices and weights), to tell whether pin rows can be reused."""
    return tuple((tuple(p.vertices), tuple(p.weights)) for p in pins)


def _pin_arrays(pins, p):
    """Vertex indices (k, 3) and barycentric weights (k, 3) of the pins, checked against ``p`` vertices."""
    if len(pins) == 0:
        raise ShapeSpaceError("no pins: add at least one pin", ErrorCode.NO_PINS)
    k = len(pins)
    idx = np.zeros((k, 3), dtype=np.int64)
    bary = np.zeros((k, 3))
    for j, pin in enumerate(pins):
        v, b = tuple(pin.vertices), tuple(pin.weights)
        if not 1 <= len(v) <= 3 or len(v) != len(b):
            raise ShapeSpaceError(f"pin {j}: vertices and weights must have 1–3 matching entries", ErrorCode.PIN)
        idx[j, :len(v)] = v
        bary[j, :len(b)] = b
    out_of_range = np.flatnonzero(((idx < 0) | (idx >= p)).any(axis=1))
    if out_of_range.size:
        raise ShapeSpaceError(f"pin {out_of_range[0]}: vertex index out of range 0..{p - 1}", ErrorCode.PIN)
    bad = np.flatnonzero(~np.isfinite(bary).all(axis=1) | (np.abs(bary.sum(axis=1) - 1.0) > 1e-6))
    if bad.size:
        raise ShapeSpaceError(f"pin {bad[0]}: barycentric weights must be finite and sum to 1", ErrorCode.PIN)
    return idx, bary


def _rows(model, idx, bary, deltas=None):
    """Barycentric rows of ``deltas`` (t, p, 3) at the pins, (3k, t); muted keys zeroed for the model's own.

    Gathers only the vertex slots some pin uses (a pin on a vertex uses one of its three).
    """
    d = model.deltas if deltas is None else deltas
    rows = None
    for slot in range(3):
        w = bary[:, slot]
        if slot and not w.any():
            continue
        part = np.take(d, idx[:, slot], axis=1)               # (t, k, 3)
        if not (w == 1.0).all():
            with np.errstate(invalid="ignore"):                   # inf × 0: a non-finite rig is named later
                part *= w[None, :, None]
        rows = part if rows is None else rows + part
    rows = np.ascontiguousarray(rows.reshape(d.shape[0], -1).T)  # (3k, t)
    if deltas is None:
        rows[:, model.mute] = 0.0
    return rows


class PinRows:
    """Everything a drag solve needs about a set of pins, computed once.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` sliders on ``p`` vertices.
    pins : sequence of Pin, length k

    Attributes
    ----------
    model : BlendshapeModel
    key : tuple
        :func:`pins_key` of the pins (a :class:`~.session.DragSession` reuses the rows while it matches).
    idx, bary : ndarray, shape (k, 3)
        Vertex indices and barycentric weights (zero-padded).
    R : ndarray, shape (3k, n)
        Rows of the delta matrix at the pins (Eq. 4.5); muted keys have zero columns.
    rest : ndarray, shape (k, 3)
        Neutral positions of the pins.
    Rd : ndarray, shape (3k, d) or None
        Rows of the driven (in-between and combination) keys; ``None`` for a linear rig.
    unit : float
        Model units per normalised unit (:func:`~core.blendshape.normalised_unit`).

    Raises
    ------
    ShapeSpaceError
        ``no_pins`` / ``pin`` for bad pins.
    """

    def __init__(self, model: BlendshapeModel, pins: Sequence[Pin]):
        self.model = model
        self.key = pins_key(pins)
        self.idx, self.bary = _pin_arrays(pins, model.n_vertices)
        self._inert = None
        self.R = _rows(model, self.idx, self.bary)
        self.rest = np.einsum("kc,kcx->kx", self.bary, model.neutral[self.idx])
        self.Rd = None if model.is_linear else _rows(model, self.idx, self.bary, model.driven_deltas())
        self.unit = normalised_unit(model)

    @property
    def inert(self) -> np.ndarray:
        """Sliders whose keys move no vertex (:func:`~.rig.inert_keys`), bool (n,): a solve leaves them be.

        The first access for a model object checks the whole model (:func:`~.rig.rig_facts`, code
        ``non_finite`` naming the key and vertex) — one pass over the deltas, kept on the model, so a new set of
        pins (a new drag) on the same model costs only its own rows.
        """
        if self._inert is None:
            self._inert = rig_facts(self.model).inert
        return self._inert

    def matches(self, model: BlendshapeModel, pins: Sequence[Pin]) -> bool:
        """True when these rows were built for this very model object and these pins."""
        return self.model is model and self.key == pins_key(pins)

    def positions(self, w: np.ndarray) -> np.ndarray:
        """Pin positions at slider values ``w`` (n,), as Blender evaluates them: (k, 3)."""
        pos = self.rest + (self.R @ self.model.effective_weights(w)).reshape(-1, 3)
        if self.Rd is not None:
            pos = pos + (self.Rd @ self.model.driven_values(w)).reshape(-1, 3)
        return pos

    def linearised(self, targets: np.ndarray, x: np.ndarray, sides: np.ndarray | None = None,
                   linear_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Normalised rows and right-hand side of the data term ``‖R w − m‖²`` of Eq. 4.5, linearised at ``x``.

        Parameters
        ----------
        targets : ndarray, shape (k, 3)
        x : ndarray, shape (n,)
            Linearisation point (only used for a rig with driven keys).
        sides : ndarray, shape (n,), optional
            +1/−1 per slider: which piece of an in-between tent to differentiate at a kink.
        linear_only : bool
            Ignore the driven keys.

        Returns
        -------
        R : ndarray, shape (3k, n)
        m : ndarray, shape (3k,)
        """
        R = self.R / self.unit
        m = (targets - self.rest).reshape(-1) / self.unit
        if self.Rd is not None and not linear_only:
            driven = self.Rd / self.unit
            slopes = self.model.driven_slopes(x, sides)
            m = m - driven @ (self.model.driven_values(x) - slopes @ x)
            R = R + driven @ slopes
        return R, m


def pin_matrix(model: BlendshapeModel, pins: Sequence[Pin], deltas: np.ndarray | None = None) -> np.ndarray:
    """Rows of the delta matrix at the pins, ``R`` of Eq. 4.5.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` sliders on ``p`` vertices.
    pins : sequence of Pin, length k
    deltas : ndarray, shape (t, p, 3), optional
        Overrides the model's targets (used for the driven keys' Jacobian).

    Returns
    -------
    ndarray, shape (3k, n) (or (3k, t) with ``deltas``)
        Muted keys get zero columns (Blender ignores them).
    """
    idx, bary = _pin_arrays(pins, model.n_vertices)
    return _rows(model, idx, bary, deltas)


def pin_rest_positions(model: BlendshapeModel, pins: Sequence[Pin]) -> np.ndarray:
    """Neutral positions of the pins.

    Parameters
    ----------
    model : BlendshapeModel
    pins : sequence of Pin, length k

    Returns
    -------
    ndarray, shape (k, 3)
    """
    idx, bary = _pin_arrays(pins, model.n_vertices)
    return np.einsum("kc,kcx->kx", bary, model.neutral[idx])


def pin_positions(model: BlendshapeModel, pins: Sequence[Pin], weights: np.ndarray) -> np.ndarray:
    """Pin positions on the face at slider values ``weights`` — as Blender evaluates them.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` sliders (in-betweens and combinations included).
    pins : sequence of Pin, length k
    weights : array_like, shape (n,)

    Returns
    -------
    ndarray, shape (k, 3)

    Raises
    ------
    ShapeSpaceError
        ``non_finite`` when a position is not finite, naming the key and vertex when the rig is the cause.
    """
    with np.errstate(invalid="ignore", over="ignore"):      # a non-finite rig is reported below, by name
        pos = PinRows(model, pins).positions(weights)
    if not np.isfinite(pos).all():
        check_model(model)
        raise ShapeSpaceError("the pin positions are not finite: the slider values contain NaN or infinity",
                              ErrorCode.NON_FINITE)
    return pos
