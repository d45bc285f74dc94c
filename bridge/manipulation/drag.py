"""The drag solves: the stored pins and the panel's settings → sliders (the core solve, then one write).

:func:`solve_pins` (the core solve :func:`core.manipulation.solve_drag`, then the write), :func:`drag_step` and
:class:`Drag` (one interactive drag: the Drag Pins tool and scripted drags make the same calls per mouse move),
:func:`symmetric_move` (a symmetric drag's two targets), :func:`solve_to_target` (the Solve Pins operator),
:func:`prior_from_settings` (the learned prior the panel names); what a drag reports (:func:`drag_status_line`,
:func:`report_text`) and keys (:func:`key_changed`).

Every verb validates and computes first and writes last: a refused solve leaves sliders and pin targets exactly
as they were, and no slider is ever written with a non-finite value.
"""
from __future__ import annotations

import numpy as np

from ...core.blendshape import BlendshapeModel
from ...core.errors import ErrorCode
from ...core.manipulation import DragResult, DragSession, WeightPrior, solve_drag, train_prior
from ...core.manipulation.geometry import reflect_point, symmetric_target
from ...core.result import ShapeSpaceError, Status
from .. import actions, meshes, shapekeys
from .cache import RIGS, write_sliders
from .pins import (
    PinState,
    check_pins,
    deformed_to_shape_space,
    mirror_partner,
    mirror_plane,
    pin_index,
    pin_target,
    set_pin_target,
    settings,
    to_shape_space,
    undo_drag,
)
from .surface import finite_point, world_to_local

__all__ = ["Drag", "prior_from_settings", "solve_pins", "symmetric_move", "drag_step", "solve_to_target",
           "drag_status_line", "report_text", "current_sliders", "key_changed"]


# ---------------------------------------------------------------------------- the solve
def prior_from_settings(obj, model: BlendshapeModel) -> WeightPrior | None:
    """Train the learned prior from the panel's action and frame range (None in other modes)."""
    st = settings(obj)
    if st.mode != "LEARNED":
        return None
    if st.prior_action is None:
        raise ShapeSpaceError("learned mode needs a prior action: pick one in the panel", ErrorCode.NO_PRIOR)
    curves = actions.shape_key_curves(obj, st.prior_action)
    known = [n for n in model.names if n in curves]
    if not known:
        raise ShapeSpaceError(f"action {st.prior_action.name!r} animates none of {obj.name!r}'s shape keys",
                              ErrorCode.PRIOR_CONSTANT)
    if st.prior_end < st.prior_start:
        raise ShapeSpaceError("the prior's frame range is empty (end before start)", ErrorCode.PRIOR_FRAMES)
    frames = np.arange(st.prior_start, st.prior_end + 1, dtype=np.float64)
    weights = actions.sample_shape_keys(obj, model.names, frames, action=st.prior_action)
    return train_prior(weights, model.names)


def solve_pins(obj, x0=None, model: BlendshapeModel | None = None, prior: WeightPrior | None = None, w0=None,
               session: DragSession | None = None, move: tuple | None = None,
               state: PinState | None = None, plane: tuple | None = None) -> DragResult:
    """Solve for the sliders from the stored pins and the panel's settings, write them; return the DragResult.

    ``model`` defaults to the cached one (:func:`rig_model`).  ``session`` is the interactive drag this
    solve belongs to (its pin rows, previous sliders and duals warm-start the solve); ``None`` for a
    one-off solve.  ``move`` is ``(pin index, target in shape-key space)``: that pin's new target, stored
    with the sliders.  ``state``: the pins as already read.  Nothing is written when anything is refused,
    and never a non-finite slider value.  The sliders go in with one bulk write and one depsgraph update,
    ShapeSpace's own (:func:`write_sliders`), so the cached rig stays trusted: a drag's one update per mouse
    move; for the Solve Pins operator it is the update its undo step would make anyway.

    With the *Symmetric* setting on, the moved pin's mirror pin (``mirror_of``) gets the reflection of the new
    target across the mirror map's plane (``plane``: ``(axis, offset)`` as already loaded, else read from the
    stored map), stored with it; a pin on the centre line has its target moved onto the plane.  Both targets
    are in shape-key space, where the map's plane lives, whatever space the caller's target came in.
    """
    model = model or RIGS.model(obj)
    state = check_pins(obj, state)
    pins, targets = state.pins(), state.targets.copy()
    st = settings(obj)
    moves = []
    if move is not None:
        index, target = pin_index(obj, move[0]), finite_point(move[1], f"the target of pin {move[0]}")
        moves = symmetric_move(obj, index, target, plane) if st.symmetric else [(index, target)]
        for j, t in moves:
            targets[j] = t
    if prior is None and st.mode == "LEARNED":
        prior = prior_from_settings(obj, model)
    w0 = model.values if w0 is None else w0
    result = solve_drag(model, pins, targets, w0, alpha=st.alpha, mu=st.mu, prior=prior,
                        prior_form="pca" if st.prior_form == "PCA" else "covariance", snap=st.snap, x0=x0,
                        session=session)
    _refuse_non_finite(obj, model.names, result.weights)
    for j, t in moves:
        set_pin_target(obj, j, t)
    write_sliders(obj, model.names, result.weights)
    return result


def symmetric_move(obj, index: int, target, plane: tuple | None = None) -> list:
    """``[(pin, target), …]`` a symmetric drag of pin ``index`` to ``target`` (shape-key space) sets: the pin's,
    and its mirror pin's reflected target (a centre-line pin: its target moved onto the plane).  ``plane``:
    the stored map's ``(axis, offset)`` (read when None and the pin has a mirror link)."""
    j = mirror_partner(obj, index)
    if j < 0:
        return [(index, target)]
    plane = mirror_plane(obj) if plane is None else plane
    if j == index:
        return [(index, symmetric_target(target, plane))]
    return [(index, target), (j, finite_point(reflect_point(target, plane), f"the mirror of pin {index}'s target"))]


def _refuse_non_finite(obj, names, values) -> None:
    """The last guard before sliders are written: a NaN/inf value is refused, naming the key."""
    values = np.asarray(values, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ShapeSpaceError(f"refusing to write {values[bad[0]]} into shape key {names[bad[0]]!r} of "
                              f"{obj.name!r}: nothing was changed", ErrorCode.NON_FINITE)


def drag_step(obj, depsgraph, index: int, world_point, model: BlendshapeModel, prior: WeightPrior | None,
              w0, x0, session: DragSession, plane: tuple | None = None) -> DragResult:
    """One mouse move of a drag: pin ``index`` follows ``world_point`` (3,) and the sliders are solved.

    ``model`` and ``prior`` are the drag's, ``w0`` the sliders when it started and ``x0`` the previous
    move's; ``plane`` the mirror plane of a symmetric drag.  The pin target and the sliders are written only
    when the solve succeeded (:func:`solve_pins`).
    """
    state = check_pins(obj)
    pins = state.pins()
    pin = pins[pin_index(obj, index)]
    local = world_to_local(obj, finite_point(world_point, "the drag position")[None])[0]
    rows = session.rows if session is not None and session.rows is not None else None
    shape_pos = None
    if rows is not None and rows.matches(model, pins):
        with np.errstate(invalid="ignore", over="ignore"):
            shape_pos = rows.positions(np.asarray(x0, dtype=np.float64))[index]
        shape_pos = shape_pos if np.isfinite(shape_pos).all() else None
    target = deformed_to_shape_space(obj, depsgraph, pin, model, x0, local, shape_pos)
    return solve_pins(obj, x0=x0, model=model, prior=prior, w0=w0, session=session, state=state,
                      move=(index, finite_point(target, "the dragged target")), plane=plane)


class Drag:
    """One interactive drag: what the Drag Pins tool (or a script) keeps from mouse-down to release.

    Numbers only — the object is passed to every call, never kept, so undo in between leaves nothing
    dangling.  Created when the mouse goes down (reads the model from :data:`RIGS`, the learned prior, the
    sliders to go back to); :meth:`grab` names the pin; each :meth:`move` is one mouse move: the target
    mapped to shape-key space through the cached crazy-space map, a warm-started solve, the pin target and
    the sliders written, one depsgraph update.  The cached model is trusted between moves while the
    depsgraph reports no foreign edit of the rig; an edit, a key added or deleted, undo or a file load
    mid-drag makes the next move read the rig again (sliders matched by name).

    Attributes
    ----------
    model : BlendshapeModel
    index : int or None
        The dragged pin.
    created : bool
        The pin was created by this drag (cancel removes it, and its mirror pin with it).
    mirror : tuple or None
        ``(index, start target)`` of the dragged pin's mirror pin when the drag is symmetric (the *Symmetric*
        setting at mouse-down and a mirror link): it moves along and cancel puts it back too.
    plane : tuple or None
        The mirror plane ``(axis, offset)`` of a symmetric drag, read once at mouse-down.
    before : tuple
        ``(names, values)`` of the sliders at mouse-down.
    solution : ndarray, shape (n,)
        The sliders after the last move (``model.names`` order).
    result : DragResult or None
        The last move's.
    """

    def __init__(self, obj):
        self.model = RIGS.model(obj)
        check_pins(obj)
        self.prior = prior_from_settings(obj, self.model)
        self.before = (list(self.model.names), self.model.values.copy())
        self.w0 = self.model.values.copy()
        self.solution = self.w0.copy()
        self.session = DragSession()
        self.index, self.created, self.start_target, self.result = None, False, None, None
        self.mirror, self.plane = None, None

    def grab(self, obj, index: int, created: bool = False) -> None:
        """Drag pin ``index`` (``created``: this drag made it, with its mirror pin in a symmetric drag).

        A symmetric drag of a pin with a mirror link reads the mirror plane now (refused when the map is gone or
        stale, before anything changes)."""
        index = pin_index(obj, index)
        j = mirror_partner(obj, index) if settings(obj).symmetric else -1
        plane = mirror_plane(obj) if j >= 0 else None
        self.index, self.created, self.plane = index, created, plane
        self.start_target = pin_target(obj, index)
        self.mirror = (j, pin_target(obj, j)) if j >= 0 and j != index else None

    def _rebase(self, obj, model: BlendshapeModel) -> None:
        """The rig was read again mid-drag: carry the start and last sliders over by name."""
        before = dict(zip(*self.before))
        last = dict(zip(self.model.names, self.solution))
        self.w0 = np.array([before.get(n, v) for n, v in zip(model.names, model.values)])
        self.solution = np.array([last.get(n, v) for n, v in zip(model.names, model.values)])
        self.model, self.session = model, DragSession()
        if self.prior is not None:
            self.prior = prior_from_settings(obj, model)

    def move(self, obj, depsgraph, world_point) -> DragResult:
        """One mouse move: the pin follows ``world_point`` (3,), world space on the evaluated surface."""
        model = RIGS.entry(obj, trust=True).model
        if model is not self.model:
            self._rebase(obj, model)
        self.result = drag_step(obj, depsgraph, self.index, world_point, model, self.prior, self.w0,
                                self.solution, self.session, plane=self.plane)
        self.solution = self.result.weights
        return self.result

    def cancel(self, obj) -> None:
        """Put back the sliders and the pin as they were at mouse-down (of the keys that still exist; a key
        added mid-drag gets its value from when the drag first saw it)."""
        blocks = obj.data.shape_keys.key_blocks if obj.data.shape_keys else {}
        start = dict(zip(*self.before))
        start.update(zip(self.model.names, self.w0))
        names = [n for n in start if n in blocks]
        undo_drag(obj, (names, [start[n] for n in names]),
                  self.index if self.index is not None else len(settings(obj).pins), self.created,
                  self.start_target, self.mirror)

    def key(self, obj, frame: int) -> int:
        """Key the sliders this drag changed at ``frame``; return how many."""
        return key_changed(obj, (list(self.model.names), self.w0), self.solution, frame)


def solve_to_target(obj, depsgraph, pin: int = -1, target=None, space: str = "LOCAL",
                    key_frame: int | None = None) -> DragResult:
    """The Solve Pins operator: optionally move pin ``pin`` to ``target`` (in ``space``), solve, write, key.

    ``key_frame`` keys the sliders that changed at that frame (``None``: no keys).  Validates and solves
    before writing anything; the model comes from the rig cache.
    """
    model = RIGS.model(obj)
    state = check_pins(obj)
    move = None
    if pin >= 0:
        move = (pin, to_shape_space(obj, depsgraph, state.pins()[pin_index(obj, pin)], model, target, space))
    before = (list(model.names), model.values.copy())
    result = solve_pins(obj, model=model, move=move, state=state)
    if key_frame is not None:
        key_changed(obj, before, result.weights, key_frame)
    return result


# ---------------------------------------------------------------------------- reporting and keys
def drag_status_line(result: DragResult) -> str:
    """The header line a drag shows after each mouse move: the largest pin error, and any warning."""
    text = f"ShapeSpace: largest pin error {result.residuals.max(initial=0.0):.3g}"
    if result.status == Status.NOT_CONVERGED:
        return text + " · NOT CONVERGED: the solver stopped at its iteration limit (sliders are the best found)"
    if result.status != Status.OK:
        return text + " · " + result.message
    return text


def report_text(result: DragResult, obj=None, space: str | None = None) -> tuple[str, str]:
    """``(level, text)`` for the user: ``"INFO"`` when the solve is clean, ``"WARNING"`` otherwise.

    A solve that stopped at its iteration limit leads with "not converged".  With ``obj`` and
    ``space="LOCAL"``, an unreachable target on a transformed object adds a hint about ``space='WORLD'``.
    """
    text = f"{result.message}; largest pin error {result.residuals.max(initial=0.0):.4g}"
    if result.status == Status.NOT_CONVERGED and not result.message.startswith("not converged"):
        text = "not converged: " + text
    unreachable = any(i.code == "unreachable" for i in result.issues)
    if unreachable and obj is not None and space == "LOCAL" and not np.allclose(meshes.world_matrix(obj),
                                                                                 np.eye(4)):
        text += (f" (the target was taken in {obj.name!r}'s local shape-key space; "
                 "pass space='WORLD' for a world-space point)")
    return ("INFO" if result.status == Status.OK else "WARNING"), text


def current_sliders(obj):
    """``(names, values)`` of the free sliders."""
    names = shapekeys.slider_names(obj)
    return names, shapekeys.read_slider_values(obj, names)


def key_changed(obj, before, after_values, frame, tol: float = 1e-6) -> int:
    """Key the sliders whose value changed from ``before`` (names, values); return how many."""
    names, values = before
    changed = [n for n, a, b in zip(names, values, after_values) if abs(a - b) > tol]
    return actions.key_sliders(obj, changed, frame)
