"""Pin-and-drag on any face rig (issue #25, item 2): one interactive drag in the rig's control space.

A :class:`RigDrag` is what a drag keeps from mouse-down to release on a face deformed by a rig that is not a
linear shape-key model (bones, drivers, hybrids): a :class:`~bridge.rig.evaluate.RigEvaluator` opened once
(refusals, natural scales, finite-difference steps), the pins as surface points (a vertex, or barycentric
weights on 1–3 vertices, :class:`core.manipulation.Pin`), the controls at mouse-down and after the last move,
and the last Jacobian of the pins.

- :meth:`RigDrag.begin` opens the evaluator (Edit Mode, linked data, locked or inert channels, invalid drivers,
  non-deterministic rigs refused by name) and returns where Blender draws the pins now (world space).
- :meth:`RigDrag.move` is one mouse move: one bounded Levenberg–Marquardt solve
  (:func:`core.rig.solve.solve_controls`) warm-started from the last controls and their verified evaluation,
  starting from the cached Jacobian (Broyden-updated by the solve), stopping when the pins are within
  ``pin_tol`` or the next step would move no pin by more than ``xtol``; every accepted step is an evaluation by
  Blender's depsgraph (the objective never increases), and the controls the solve ends on are live on the rig,
  so the pins land where the viewport draws them.  Only the first move computes a Jacobian (one evaluation
  per channel outside the analytic slider columns): when a later step stalls or is refused on the
  Broyden-updated Jacobian the move stops there with its verified controls (``defer_refresh``, the default)
  instead of spending one evaluation per channel inside the mouse move; and it makes at most ``move_steps``
  (one) verified steps, the next move going on from there — a move costs one rig evaluation and a small
  bounded least-squares solve, and the pins may trail the mouse by what one step does not close.  A move that
  follows one which could not move at all on the stale Jacobian refreshes it (the drag never freezes).
- :meth:`RigDrag.settle` is that deferred work: from the last controls, a solve toward the last move's targets
  that recomputes the Jacobian whenever a step stalls, until the pins are within ``pin_tol`` or the controls are
  stationary — for an idle moment (a timer while the mouse rests), and done by :meth:`RigDrag.release` when the
  last move stopped short (``NOT_CONVERGED``), so a released drag lands its pins as a full solve would.
- :meth:`RigDrag.release` keeps the controls and (``autokey``) keys the channels that changed on their
  datablocks' actions at the current frame (a bone in ``QUATERNION`` / ``AXIS_ANGLE`` mode: all four
  components); :meth:`RigDrag.cancel` writes every channel back exactly as it was at mouse-down.  Nothing is
  keyed by a move, a failure or a cancel; a move that fails puts the last accepted controls back.

Two settings of the linear path carry over (thesis ch. 4):

- *Learned* prior: ``prior_samples`` (f, n), the control channels per frame of the prior action
  (:func:`sample_action`: the F-curves evaluated, not the depsgraph), train a Gaussian on the controls when the
  drag begins (:func:`core.rig.prior.train_control_prior`, with the natural scales the evaluator measured and the
  evaluated diagonal) and every solve's pull toward the controls at mouse-down ``r`` becomes
  ``λ (x − r)ᵀ Σ⁻¹ (x − r)`` (:attr:`RigDrag.prior`): centred on the pose at mouse-down as the linear path's
  Learned mode, the prior's covariance the metric — moves the action makes together are cheap, channels it does
  not tie to the pinned ones stay where they are, nothing is pulled toward the action's mean pose.
- *Symmetric*: ``begin(pins, mirror_map=...)`` also fits the face's current mirror plane in world space from the
  evaluated positions of the map's vertex pairs (:func:`core.rig.mirror.fit_mirror_plane`; the face may be posed:
  a turned head, a moved object) — :attr:`RigDrag.plane`, across which the Pin tool reflects a mirror pin's target.

A pure shape-key face keeps the exact linear path of :mod:`bridge.manipulation.drag`.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.blendshape import NORMALISED_DIAGONAL
from ...core.errors import ErrorCode
from ...core.manipulation import Pin
from ...core.manipulation.pins import _pin_arrays
from ...core.result import ShapeSpaceError, Status
from ...core.rig import ChannelKind, ControlSet, RigSolveResult, rotation_vector_from_quaternion, solve_controls
from ...core.rig.mirror import fit_mirror_plane
from ...core.rig.prior import train_control_prior
from .. import actions, symmetry
from .channels import EULER_MODES, bind
from .evaluate import RigEvaluator
from .take import CHANGED_REL_TOL, PIN_TOL_REL, _animated

__all__ = ["RigDrag", "sample_action"]

#: A move stops when the bounded Gauss–Newton step on the current (cached, Broyden-updated) Jacobian would move
#: no pin by more than this fraction of the evaluated diagonal (a tenth of the recovery goal, 0.03 mm on a 30 cm
#: head): a small mouse move then costs one or two rig evaluations instead of fresh Jacobians chasing a target the
#: rig cannot reach exactly; the next move goes on from there.
DRAG_XTOL_REL = 1e-4


def _curve_table(action, idb) -> dict:
    """``{(data path, index): F-Curve}`` of what ``action`` animates on ``idb`` (its slot on 4.4+; on 4.2 an
    action meant for another ID type animates nothing here)."""
    if not actions.LAYERED and getattr(action, "id_root", "") not in ("", idb.id_type):
        return {}
    return {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(action, idb)}


def _rotation_vectors(values: np.ndarray, attr: str, action, channel: str, frames: np.ndarray) -> np.ndarray:
    """Rotation vectors (f, 3) of quaternions or axis–angles (f, 4) sampled from ``action``'s F-curves at ``frames``
    (f,); a quaternion that is not a rotation (non-finite or zero) is refused naming the action, ``channel`` and
    the frame."""
    if attr == "rotation_quaternion":
        bad = ~np.isfinite(values).all(axis=1) | ~(np.linalg.norm(np.nan_to_num(values), axis=1) > 0)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ShapeSpaceError(f"action {action.name!r} gives the quaternion {values[k].tolist()} for channel "
                                  f"{channel!r} at frame {frames[k]:g}: not a rotation", ErrorCode.NON_FINITE)
        return np.array([rotation_vector_from_quaternion(q) for q in values])
    norm = np.linalg.norm(values[:, 1:], axis=1, keepdims=True)
    return np.where(norm > 0, values[:, :1] * values[:, 1:] / np.where(norm > 0, norm, 1.0), 0.0)


def sample_action(controls: ControlSet, action, frames) -> tuple:
    """The channels of ``controls`` at ``frames`` (f,) as ``action`` keys them: its F-curves evaluated per frame
    (not the depsgraph: no driver, constraint or other action takes part), on each channel's datablock (the
    armature or other object for bones and properties, the mesh's shape-key datablock for sliders).  A channel
    the action does not key holds its current value; a bone in ``QUATERNION`` / ``AXIS_ANGLE`` mode is sampled on
    its four components (those not keyed: their current value) and read as its rotation vector.

    Returns
    -------
    values : ndarray (f, n)
    keyed : ndarray (n,) bool
        The channels the action keys.
    """
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    bindings = bind(controls)
    values = np.empty((frames.size, len(bindings)))
    keyed = np.zeros(len(bindings), dtype=bool)
    tables = {}
    for j, b in enumerate(bindings):
        ch = b.channel
        idb, path = _animated(b)
        table = tables.get(idb.as_pointer())
        if table is None:
            table = tables[idb.as_pointer()] = _curve_table(action, idb)
        if ch.kind == ChannelKind.ROTATION and ch.rotation_mode not in EULER_MODES:
            curves = [table.get((path, k)) for k in range(4)]
            if any(fc is not None for fc in curves):
                raw = np.array(b.raw(), dtype=np.float64)
                comps = np.column_stack([actions.sample_curve(fc, frames) if fc is not None
                                         else np.full(frames.size, raw[k]) for k, fc in enumerate(curves)])
                values[:, j] = _rotation_vectors(comps, b.attr, action, ch.name, frames)[:, ch.index]
                keyed[j] = True
                continue
        else:
            fc = table.get((path, max(ch.index, 0)))
            if fc is not None:
                values[:, j] = actions.sample_curve(fc, frames)
                keyed[j] = True
                continue
        values[:, j] = b.get()
    return values, keyed


def _pins(pins, n_vertices: int) -> tuple:
    """Pins (vertex indices or :class:`Pin` s) as (vertices (m,), barycentric matrix (p, m)) of distinct
    vertices; refused by pin index when malformed."""
    pins = [Pin.at_vertex(int(p)) if isinstance(p, (int, np.integer)) else p for p in pins]
    idx, bary = _pin_arrays(pins, n_vertices)
    verts, inverse = np.unique(idx, return_inverse=True)
    B = np.zeros((len(pins), verts.size))
    np.add.at(B, (np.repeat(np.arange(len(pins)), 3), inverse.reshape(-1)), bary.reshape(-1))
    return verts, B


class RigDrag:
    """One drag of pins on ``mesh_obj`` through the channels of ``controls`` (module doc).

    Parameters
    ----------
    mesh_obj : bpy.types.Object
        The deformed face mesh.
    controls : ControlSet
        The channels the drag may move.
    mu : float
        Regularisation toward the controls at mouse-down (:func:`core.rig.solve.solve_controls`).
    pin_tol : float, optional
        A move stops once every pin is this close to its target (default 1e-5 of the evaluated diagonal).
    xtol : float, optional
        A move also stops when the Gauss–Newton step would move no pin by more than this distance (default
        :data:`DRAG_XTOL_REL` of the evaluated diagonal).
    max_iter : int
        Trial steps per move.
    defer_refresh : bool
        Moves after the first never recompute the Jacobian (module doc); False: a move refreshes it whenever a
        step stalls (each refresh one evaluation per finite-difference channel inside the move).
    move_steps : int
        Verified steps (rig evaluations) a deferring move makes at most (module doc; ``max_iter`` otherwise).
    prior_samples : ndarray (f, n), optional
        The Learned mode's training frames of the controls (:func:`sample_action`); None: Direct mode.
    prior_alpha : float
        The Learned prior's weight α (the panel's, as the linear path's Learned mode).

    Attributes
    ----------
    start : ndarray (n,)
        Controls at mouse-down.
    controls_now : ndarray (n,)
        Controls after the last move (live on the rig).
    points : ndarray (p, 3)
        Blender's evaluation of the pins at ``controls_now`` (world space).
    result : RigSolveResult or None
        The last move's (or :meth:`settle`'s).
    targets : ndarray (p, 3) or None
        The last move's targets.
    prior : ControlPrior or None
        The Learned prior, trained when the drag begins.
    plane : MirrorPlane or None
        The face's mirror plane at mouse-down (world space) when the drag began with a mirror map.
    """

    def __init__(self, mesh_obj, controls: ControlSet, *, mu: float = 1e-6, pin_tol: float | None = None,
                 xtol: float | None = None, max_iter: int = 20, defer_refresh: bool = True,
                 move_steps: int = 1, prior_samples=None, prior_alpha: float = 0.1):
        self.mesh_obj, self.controls = mesh_obj, controls
        self.mu, self.pin_tol, self.xtol, self.max_iter = mu, pin_tol, xtol, max_iter
        self.defer_refresh, self.move_steps = defer_refresh, move_steps
        self.targets = None
        self.ev = None
        self.B = None
        self.start = self.controls_now = self.points = None
        self.jacobian_cache = None
        self.result = None
        self._last = None
        self._bounds = self._scale = None
        self.prior_samples, self.prior_alpha = prior_samples, prior_alpha
        self.prior = self.plane = None

    # -- lifecycle -----------------------------------------------------------------------------------------
    def begin(self, pins, mirror_map=None) -> np.ndarray:
        """Open the drag on ``pins`` (vertex indices or :class:`Pin` s); return the pins' world positions (p, 3)
        as Blender draws them.  With ``prior_samples`` the Learned prior is trained now; with ``mirror_map``
        (:class:`core.symmetry.MirrorMap` of the face) the face's current mirror plane is fitted
        (:attr:`plane`).  Refusals (the rig's, a prior that does not train, a map without pairs) leave the rig
        exactly as it was."""
        if self.ev is not None:
            raise ShapeSpaceError("the drag has already begun", ErrorCode.INVALID)
        if self.mesh_obj is None or self.mesh_obj.type != "MESH":
            raise ShapeSpaceError(f"{getattr(self.mesh_obj, 'name', self.mesh_obj)!r} is not a mesh object",
                                  ErrorCode.NOT_MESH)
        verts, self.B = _pins(pins, len(self.mesh_obj.data.vertices))
        ev = RigEvaluator(self.mesh_obj, self.controls, verts, check=False)
        try:
            ev.check()
            self.start = ev.c0.copy()
            self.controls_now = self.start.copy()
            self.points = self._evaluate_with(ev, self.start)
            prior = None if self.prior_samples is None else train_control_prior(
                self.prior_samples, [ch.name for ch in ev.controls.channels], ev.controls.scale,
                ev.diagonal / NORMALISED_DIAGONAL, self.prior_alpha)
            plane = None if mirror_map is None else self._plane(ev, mirror_map)
        except BaseException:
            ev.restore()
            raise
        self.ev, self.jacobian_cache, self.result, self.targets = ev, None, None, None
        self._bounds = ev.controls.solve_bounds(ev.c0)      # fixed for the drag: read once, not per move
        self._scale = ev.controls.scale
        self.prior, self.plane = prior, plane
        return self.points.copy()

    def _plane(self, ev, mmap):
        """The face's mirror plane now (world space), from the evaluated positions of ``mmap``'s pairs."""
        rest = symmetry.rest_positions(self.mesh_obj)
        return fit_mirror_plane(ev.all_points(None), mmap.mirror, rest[:, mmap.axis] - mmap.offset)

    def _evaluate_with(self, ev, c) -> np.ndarray:
        verts = ev.evaluate(c)
        self._last = (np.array(c, dtype=np.float64), verts)
        return self.B @ verts

    def _open(self) -> RigEvaluator:
        if self.ev is None:
            raise ShapeSpaceError("the drag is not active (begin it first)", ErrorCode.INVALID)
        return self.ev

    # -- the solve -----------------------------------------------------------------------------------------
    def _evaluate(self, c) -> np.ndarray:
        return self._evaluate_with(self.ev, c)

    def _jacobian(self, c, base=None) -> np.ndarray:
        """Jacobian of the pins (3p, n): the evaluator's vertex Jacobian through the barycentric rows."""
        last = self._last
        verts = last[1] if last is not None and np.array_equal(last[0], c) else None
        Jv = self.ev.jacobian(c, verts).reshape(-1, 3, len(c))
        self._last = None                     # the finite differences left other controls evaluated last
        return np.einsum("pm,mkn->pkn", self.B, Jv).reshape(-1, len(c))

    def move(self, targets) -> RigSolveResult:
        """One mouse move: bring the pins toward world-space ``targets`` (p, 3); the controls found are live.

        Returns the solve's result (``points``: Blender's evaluation of the pins at ``value``; the diagnostics'
        ``objective_history`` never increases).  On failure the last accepted controls are put back and the
        error re-raised.
        """
        ev = self._open()
        t = np.array(targets, dtype=np.float64)
        if t.shape != self.points.shape:
            raise ShapeSpaceError(f"targets: expected {self.points.shape}, got {t.shape}", ErrorCode.SHAPE)
        bad = np.flatnonzero(~np.isfinite(t).all(axis=1))
        if bad.size:
            raise ShapeSpaceError(f"target of pin {int(bad[0])} is not finite", ErrorCode.NON_FINITE)
        last = self.result
        stuck = last is not None and last.diagnostics.get("jacobian_stale") and len(last.diagnostics[
            "objective_history"]) == 1          # the last move could not move on the stale Jacobian: refresh now
        defer = self.defer_refresh and self.jacobian_cache is not None and not stuck
        res = self._solve(t, xtol=DRAG_XTOL_REL * ev.diagonal if self.xtol is None else self.xtol,
                          max_iter=min(self.max_iter, self.move_steps) if defer else self.max_iter, defer=defer)
        self.targets = t
        return res

    def settle(self, max_iter: int = 50) -> RigSolveResult | None:
        """The work moves defer (module doc): from the last controls, solve toward the last move's targets with the
        Jacobian recomputed whenever a step stalls, until every pin is within ``pin_tol`` or the controls are
        stationary; the controls found are live.  None before the first move.  On failure the last accepted
        controls are put back and the error re-raised."""
        self._open()
        if self.targets is None:
            return None
        return self._solve(self.targets, xtol=0.0, max_iter=max_iter, defer=False)

    def _solve(self, t, xtol, max_iter, defer) -> RigSolveResult:
        """One verified solve toward ``t`` from the last controls and Jacobian; its controls live on the rig."""
        ev = self.ev
        lo, hi = self._bounds
        tol = PIN_TOL_REL * ev.diagonal if self.pin_tol is None else self.pin_tol
        try:
            res = solve_controls(self._evaluate, self.controls_now, t, lo=lo, hi=hi, scale=self._scale,
                                 jacobian=self._jacobian, steps=ev.steps, reference=self.start, mu=self.mu,
                                 pin_tol=tol, xtol=xtol, max_iter=max_iter, first_jacobian=self.jacobian_cache,
                                 first_points=self.points, defer_refresh=defer,
                                 first_active=None if self.result is None else self.result.diagnostics["active"],
                                 prior=self.prior)
            if self._last is None or not np.array_equal(self._last[0], res.x):
                self._evaluate(res.x)                 # the rig shows the result (its points were verified)
        except BaseException:
            self._evaluate(self.controls_now)
            raise
        self.controls_now, self.points, self.jacobian_cache = res.x.copy(), res.points, res.jacobian
        self.result = res
        return res

    # -- the end of a drag ---------------------------------------------------------------------------------
    def changed(self) -> list:
        """Indices of the channels the drag changed (surface motion above 1e-7 of the diagonal)."""
        ev = self._open()
        moved = np.abs(self.controls_now - self.start) * self._scale
        return [int(i) for i in np.flatnonzero(moved > CHANGED_REL_TOL * ev.diagonal)]

    def _key_curves(self, changed) -> list:
        """``(datablock, data path, index, group, value)`` of every F-Curve key for the ``changed`` channels."""
        curves, done = [], set()
        for i in changed:
            b = self.ev.bindings[i]
            ch = b.channel
            idb, path = _animated(b)
            group = path.split('"')[1] if path.startswith("pose.bones[") else ""
            if ch.kind == ChannelKind.ROTATION and ch.rotation_mode not in EULER_MODES:
                if (idb.as_pointer(), path) not in done:
                    done.add((idb.as_pointer(), path))
                    curves += [(idb, path, k, group, float(v)) for k, v in enumerate(b.raw())]
                continue
            value = b.raw()
            value = value if ch.index < 0 else value[ch.index]
            curves.append((idb, path, max(ch.index, 0), group, float(value)))
        return curves

    def release(self, autokey: bool = True, frame: int | None = None) -> list:
        """End the drag keeping the controls; with ``autokey`` key the changed channels at ``frame`` (the scene's
        current frame by default).  Returns the names of the channels keyed.

        When the last move stopped short of its targets (``NOT_CONVERGED``: a deferred Jacobian refresh, or its
        step limit) the drag first :meth:`settle` s, so the released pins land as a full solve puts them; if that
        fails the drag stays active, nothing is keyed, and the error is re-raised."""
        self._open()
        if self.targets is not None and self.result is not None and self.result.status != Status.OK:
            self.settle()
        changed = self.changed()
        keyed = []
        if autokey and changed:
            f = bpy.context.scene.frame_current if frame is None else frame
            curves = self._key_curves(changed)                   # everything read before anything is written
            for idb, path, index, group, value in curves:
                actions.insert_key(idb, path, f, value, index=index, group=group)
            keyed = [self.ev.bindings[i].channel.name for i in changed]
        self.ev = None
        return keyed

    def cancel(self) -> None:
        """End the drag putting every channel back exactly as it was at mouse-down (nothing keyed)."""
        ev = self._open()
        self.ev = None
        ev.restore()
