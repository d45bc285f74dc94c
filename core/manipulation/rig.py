"""What a drag solve must know about the rig itself: that it is finite, and which keys move nothing.

A drag never writes a non-finite slider value: :func:`check_model` refuses a
model with a NaN or infinite coordinate, displacement or slider range before
any solve, naming the key and the vertex.

A drag never changes the slider of a key that moves no vertex: such a
slider's value is invisible in the viewport, yet auto-key keys it and game
engines read it.  Nothing in Eq. 4.5 pins it down — its column of ``R`` is
zero, so only the regularisers (μ‖w‖², or a learned prior's coupling to the
other keys, Eq. 4.8) would set it.  :func:`inert_keys` finds these keys
(displacement below ``rel_tol`` × the model's size, and no in-between or
combination shape driven by them that moves anything); the solve fixes
their sliders where they were (bounds ``lo = hi = w0``), which for a
learned prior is the Gaussian conditioned on them staying put.

Both need a pass over all ``n × p × 3`` displacements — far more than a
solve itself costs on a production face — so :func:`rig_facts` computes
them once per model object and keeps the answer on the model (a
:class:`~core.blendshape.BlendshapeModel` is treated as immutable after
construction, as its cached ``scale`` already assumes).  A model that fails
the check keeps nothing, so every later solve with it is refused again.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["INERT_REL_TOL", "RigFacts", "check_model", "inert_keys", "rig_facts"]

#: Displacements below this fraction of the model's bounding-box diagonal count as zero (as in
#: :func:`core.blendshape.diagnose_model`'s "moves no vertex").
INERT_REL_TOL = 1e-7


def _first_bad(values: np.ndarray):
    """Index tuple of the first NaN/inf entry of ``values``, or ``None`` when all are finite."""
    if values.size == 0 or np.isfinite(values).all():
        return None
    return tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])


def check_model(model: BlendshapeModel) -> None:
    """Refuse a model with a non-finite coordinate, displacement or slider range, naming key and vertex.

    Parameters
    ----------
    model : BlendshapeModel
        ``neutral`` (p, 3), ``deltas`` (n, p, 3), slider ranges (n,), in-between and combination deltas (p, 3).

    Raises
    ------
    ShapeSpaceError
        Code ``non_finite``.
    """
    bad = _first_bad(model.neutral)
    if bad is not None:
        v, axis = bad
        raise ShapeSpaceError(
            f"the reference key {model.reference_name!r} has a non-finite coordinate ({'xyz'[axis]} = "
            f"{model.neutral[v, axis]}) at vertex {v}", ErrorCode.NON_FINITE)
    bad = _first_bad(model.deltas)
    if bad is not None:
        k, v, axis = bad
        raise ShapeSpaceError(
            f"shape key {model.names[k]!r} has a non-finite displacement ({'xyz'[axis]} = "
            f"{model.deltas[k, v, axis]}) at vertex {v}", ErrorCode.NON_FINITE)
    for kind, items in (("in-between", model.inbetweens), ("combination", model.combinations)):
        for item in items:
            delta = np.asarray(item.delta, dtype=np.float64)
            bad = _first_bad(delta)
            if bad is not None:
                v, axis = bad
                raise ShapeSpaceError(
                    f"{kind} key {item.name!r} has a non-finite displacement ({'xyz'[axis]} = "
                    f"{delta[v, axis]}) at vertex {v}", ErrorCode.NON_FINITE)
    for field in ("slider_min", "slider_max"):
        bad = _first_bad(getattr(model, field))
        if bad is not None:
            raise ShapeSpaceError(f"shape key {model.names[bad[0]]!r} has {field} = "
                                  f"{getattr(model, field)[bad[0]]}", ErrorCode.NON_FINITE)


def inert_keys(model: BlendshapeModel, rel_tol: float = INERT_REL_TOL) -> np.ndarray:
    """Sliders whose keys move no vertex — directly or through the in-betweens and combinations they drive.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` sliders; assumed finite (:func:`check_model`).
    rel_tol : float
        A displacement counts as zero below ``rel_tol`` × ``model.scale`` (the bounding-box diagonal).

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    limit = rel_tol * model.scale
    live = _peaks(model.deltas) > limit
    for ib in model.inbetweens:
        if np.abs(np.asarray(ib.delta, dtype=np.float64)).max(initial=0.0) > limit:
            live[ib.primary] = True
    for comb in model.combinations:
        if np.abs(np.asarray(comb.delta, dtype=np.float64)).max(initial=0.0) > limit:
            live[list(comb.inputs)] = True
    return ~live


@dataclass(frozen=True)
class RigFacts:
    """What every drag solve on one model needs to know about the rig itself (computed by :func:`rig_facts`).

    Attributes
    ----------
    inert : ndarray of bool, shape (n,)
        Sliders whose keys move no vertex (:func:`inert_keys`).
    """

    inert: np.ndarray


#: Attribute of a model object holding its :class:`RigFacts` (set by :func:`rig_facts`).
_FACTS = "_manipulation_facts"


def _peaks(deltas: np.ndarray) -> np.ndarray:
    """Largest absolute displacement of each key, (n,): NaN or inf when a displacement is not finite.

    Two reductions without a temporary array (``np.abs`` of ``deltas`` would be as large as the rig); a NaN
    propagates through ``max``/``min``, an infinity makes the peak infinite.
    """
    if deltas.shape[0] == 0 or deltas.size == 0:
        return np.zeros(deltas.shape[0])
    return np.maximum(deltas.max(axis=(1, 2)), -deltas.min(axis=(1, 2)))


def rig_facts(model: BlendshapeModel, rel_tol: float = INERT_REL_TOL) -> RigFacts:
    """The model's :class:`RigFacts`, computed on first use and kept on the model object.

    The first call checks the model (:func:`check_model`: refused, naming key and vertex, when anything is
    not finite) and finds its inert keys; later calls with the same model object return the same facts.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` sliders on ``p`` vertices.
    rel_tol : float
        As in :func:`inert_keys`.

    Returns
    -------
    RigFacts

    Raises
    ------
    ShapeSpaceError
        Code ``non_finite`` (nothing is kept: the next call raises again).
    """
    facts = model.__dict__.get(_FACTS)
    if facts is not None and facts[0] == rel_tol:
        return facts[1]
    peak = _peaks(model.deltas)
    driven = [np.asarray(item.delta, dtype=np.float64) for item in (*model.inbetweens, *model.combinations)]
    finite = (np.isfinite(peak).all() and np.isfinite(model.neutral).all()
              and np.isfinite(model.slider_min).all() and np.isfinite(model.slider_max).all()
              and all(np.isfinite(d).all() for d in driven))
    if not finite:
        check_model(model)           # names the key and the vertex
    limit = rel_tol * model.scale
    live = peak > limit
    for ib, d in zip(model.inbetweens, driven):
        if np.abs(d).max(initial=0.0) > limit:
            live[ib.primary] = True
    for comb, d in zip(model.combinations, driven[len(model.inbetweens):]):
        if np.abs(d).max(initial=0.0) > limit:
            live[list(comb.inputs)] = True
    facts = RigFacts(inert=~live)
    facts.inert.flags.writeable = False
    setattr(model, _FACTS, (rel_tol, facts))
    return facts
