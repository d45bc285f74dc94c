"""The state one interactive drag carries from mouse move to mouse move (warm start of the solve).

During a drag the pins stay the same and the active set of the bounded QP
changes little between two mouse moves, so each solve of Eq. 4.5 starts from
the previous move's sliders and dual variables and reuses the pins' rows of
the delta matrix.  :class:`DragSession` holds exactly that; the caller
creates one when the drag starts, passes it to every
:func:`~.solve.solve_drag` of the drag (``session=``) and drops it when the
drag ends.  It holds plain numpy data only (never Blender data).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..blendshape import BlendshapeModel
from .pins import Pin, PinRows

__all__ = ["DragSession"]


@dataclass
class DragSession:
    """Warm-start state of one drag: pin rows, last sliders and last dual.

    Attributes
    ----------
    rows : PinRows or None
        The pins' rows of the delta matrix (reused while the model object and the pins stay the same).
    weights : ndarray, shape (n,), or None
        Sliders of the previous solve: the next solve starts there (unless given ``x0``).
    dual : ndarray, shape (3k,), or None
        Dual variables of the previous solve's plain-mode QP (Eq. 4.5): warm-start the next dual solve.
    """

    rows: PinRows | None = None
    weights: np.ndarray | None = None
    dual: np.ndarray | None = None

    def pin_rows(self, model: BlendshapeModel, pins: Sequence[Pin]) -> PinRows:
        """The session's pin rows when they fit ``model`` and ``pins``, else new ones (kept for the next move)."""
        if self.rows is None or not self.rows.matches(model, pins):
            self.rows = PinRows(model, pins)
        return self.rows

    def start(self, n: int) -> np.ndarray | None:
        """The previous sliders when they fit ``n`` sliders (else ``None``)."""
        if self.weights is not None and len(self.weights) == n:
            return self.weights
        return None

    def record(self, weights: np.ndarray, dual: np.ndarray | None) -> None:
        """Keep a solve's sliders (n,) and dual (3k,) (``None``: the solve had no dual) for the next move."""
        self.weights = np.array(weights, dtype=np.float64)
        self.dual = dual
