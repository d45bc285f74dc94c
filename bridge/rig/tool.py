"""The Pin tool on any face rig (issue #25 item 2): the Drag Pins tool's interface over :class:`RigDrag`.

The Drag Pins tool (``operators/manipulation/drag_pins.py``) speaks the interface of
:class:`bridge.manipulation.Drag` — made at mouse-down, then ``grab`` / ``move`` / ``cancel`` / ``key``, its
``result`` and ``model``.  :func:`drag_for` gives that interface for the face under the tool:

- a face whose stored control set (:mod:`bridge.rig.stored`) has a channel that is not one of its own shape-key
  sliders — bones, custom properties, another object's sliders: a bone-, driver- or hybrid-driven face
  (:func:`uses_rig`) — gets a :class:`RigPinDrag`: the stored pins held where Blender draws them at
  mouse-down, the grabbed one following the mouse, solved in control space by :class:`RigDrag` (every step
  verified by the depsgraph), the changed channels keyed on their datablocks' actions on release
  (:meth:`RigPinDrag.key`), every channel put back exactly on cancel;
- any other face (a plain shape-key face) keeps the exact linear path, :class:`bridge.manipulation.Drag`.

On a rig face the pins keep their stored targets (shape-key space means nothing for a bone): the pins are held
where they are drawn at mouse-down.  The panel's settings apply as on the linear path:

- *Direct* mode: the solve stays near the controls at mouse-down.
- *Learned* mode: a Gaussian prior on the control channels trained from the panel's prior action over its frame
  range (:func:`prior_samples`: the action's F-curves per frame on every channel it keys — bone rotation,
  location, scale, custom properties, sliders; channels it does not key hold their value at mouse-down), added to
  the solve as ``λ (x − x₀)ᵀ Σ⁻¹ (x − x₀)`` around the controls at mouse-down ``x₀`` in place of the Direct pull
  (:mod:`core.rig.prior`; centred and weighted (α) as the linear path's Learned mode: the covariance makes the
  moves the action makes together cheap, it never pulls the face toward the action's mean pose).  No prior
  action, an empty frame range, an action that keys none of the face's control channels or moves none of them,
  fewer than 2 frames or a non-finite value: refused by name at mouse-down.
- *Symmetric*: a new pin comes with its mirror pin (through the stored mirror map, linked both ways; a centre-line
  pin is linked to itself), and dragging a pin with a mirror link moves its mirror pin to the reflected target —
  reflected across the face's *current* mirror plane, fitted at mouse-down from the evaluated world positions of
  the map's vertex pairs (a turned head reflects across its turned plane; :func:`core.rig.mirror.fit_mirror_plane`)
  — and a centre-line pin's target is projected onto that plane.  A symmetric drag of a linked pin without a
  usable mirror map is refused by name before anything changes.  Cancel puts every channel back and removes the
  pins the drag made (the mirror pin with it); the stored pins are otherwise untouched.
"""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.manipulation.geometry import mirror_pin
from ...core.result import ShapeSpaceError, Status
from ...core.rig.controls import ChannelKind
from .. import manipulation, symmetry
from ..manipulation.pins import mirror_partner, pin_index, store_pin
from ..manipulation.surface import finite_point
from . import stored
from .channels import bind
from .drag import RigDrag, sample_action
from .evaluate import check_editable, rig_ids

#: Verified steps (rig evaluations and, when a step stalls, a Jacobian refresh) per timer tick while the mouse rests.
REST_STEPS = 3

__all__ = ["RigPinDrag", "add_pin", "drag_for", "finish", "prior_samples", "report_text", "rig_pin_problem",
           "status_line", "uses_rig"]


def uses_rig(obj) -> bool:
    """Whether the Pin tool drags ``obj`` through its rig: a control set is stored on it with an enabled channel
    that is not one of its own shape-key sliders (a damaged set counts: the drag then names the damage)."""
    if obj is None or obj.type != "MESH" or stored.PROP not in obj:
        return False
    _arm, entries, problem = stored.status(obj)
    if problem:
        return True
    return any(e.enabled and not (e.kind == ChannelKind.SHAPE_KEY and e.object == obj.name) for e in entries)


def rig_pin_problem(obj) -> str:
    """Why the Pin tool cannot drag the rig face ``obj`` ('' when it can): the mode, a control set that does not
    read, channels that are gone, linked data or Edit Mode among the rig's objects.  (The Learned prior and the
    mirror map are read at mouse-down, where their refusals name them.)"""
    st = manipulation.settings(obj)
    if st.mode == "SLIDERS":
        return "Switch the ShapeSpace mode to Direct or Learned"
    try:
        controls = stored.control_set(obj)
        check_editable(rig_ids(obj, bind(controls)))
    except ShapeSpaceError as exc:
        return str(exc)
    return ""


def prior_samples(obj, controls) -> np.ndarray:
    """The Learned mode's training frames (f, n) of ``controls`` on the rig face ``obj``: the panel's prior action
    sampled on its frame range (:func:`bridge.rig.drag.sample_action`).  Refused by name: no prior action, an empty
    range or fewer than 2 frames, an action that keys none of the control channels or moves none of them, a
    non-finite value."""
    st = manipulation.settings(obj)
    if st.prior_action is None:
        raise ShapeSpaceError("learned mode needs a prior action: pick one in the panel", ErrorCode.NO_PRIOR)
    if st.prior_end < st.prior_start:
        raise ShapeSpaceError("the prior's frame range is empty (end before start)", ErrorCode.PRIOR_FRAMES)
    frames = np.arange(st.prior_start, st.prior_end + 1, dtype=np.float64)
    if frames.size < 2:
        raise ShapeSpaceError(f"a prior needs at least 2 frames of animation, got {frames.size} (frames "
                              f"{st.prior_start}–{st.prior_end})", ErrorCode.PRIOR_FRAMES)
    values, keyed = sample_action(controls, st.prior_action, frames)
    name = st.prior_action.name
    if not keyed.any():
        raise ShapeSpaceError(f"action {name!r} keys none of {obj.name!r}'s control channels "
                              f"({', '.join(ch.name for ch in controls.channels[:4])}"
                              f"{', …' if len(controls.channels) > 4 else ''})", ErrorCode.PRIOR_CONSTANT)
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        f, j = (int(i) for i in bad[0])
        raise ShapeSpaceError(f"action {name!r} gives {values[f, j]} for channel {controls.channels[j].name!r} at "
                              f"frame {int(frames[f])}", ErrorCode.NON_FINITE)
    if not np.any(np.ptp(values[:, keyed], axis=0) > 0):
        raise ShapeSpaceError(f"action {name!r} moves none of the control channels over frames "
                              f"{st.prior_start}–{st.prior_end}", ErrorCode.PRIOR_CONSTANT)
    return values


def drag_for(obj):
    """The drag the Pin tool starts at mouse-down on ``obj``: :class:`RigPinDrag` on a rig face (:func:`uses_rig`),
    else the linear :class:`bridge.manipulation.Drag`."""
    return RigPinDrag(obj) if uses_rig(obj) else manipulation.Drag(obj)


def add_pin(obj, drag, pin, stationary: bool = False) -> int:
    """Store a new pin for ``drag`` (made by :func:`drag_for`); returns its index.  On a rig face it is stored with
    its undeformed position as target; with *Symmetric* on, its mirror pin (through the stored mirror map) is
    stored right after it, linked both ways (a centre-line pin: linked to itself) — a missing map or an unmapped
    vertex is refused before anything is stored.  Otherwise :func:`bridge.manipulation.add_pin` with the drag's
    model."""
    if not isinstance(drag, RigPinDrag):
        return manipulation.add_pin(obj, pin, None, stationary, model=drag.model)
    n = len(obj.data.vertices)
    if any(v < 0 or v >= n for v in pin.vertices):
        raise ShapeSpaceError(f"pin vertex out of range 0..{n - 1}", ErrorCode.PIN)
    co = np.empty(3 * n, dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    co = co.reshape(n, 3).astype(np.float64)

    def rest(p):
        return finite_point(sum(w * co[v] for v, w in zip(p.vertices, p.weights)), "the pin's position")

    symmetric = manipulation.settings(obj).symmetric
    twin = mirror_pin(pin, symmetry.load_map(obj), "the new pin") if symmetric else None
    index = store_pin(obj, pin, rest(pin), stationary)
    pins = manipulation.settings(obj).pins
    if symmetric and twin is None:
        pins[index].mirror_of = index
    elif twin is not None:
        other = store_pin(obj, twin, rest(twin), stationary)
        pins[index].mirror_of, pins[other].mirror_of = other, index
    manipulation.settings(obj).active_pin = index
    return index


class RigPinDrag:
    """One Pin-tool drag on a rig face (module doc), with the interface of :class:`bridge.manipulation.Drag`.

    Attributes
    ----------
    model : None
        No linear model: a rig face has none (:func:`add_pin` takes the drag instead).
    controls : ControlSet
        The face's enabled stored channels, read at mouse-down.
    index : int or None
        The dragged pin.
    mirror : int
        Its mirror pin in a symmetric drag (the *Symmetric* setting and a stored link; ``index`` itself for a
        centre-line pin), −1 otherwise.
    created : bool
        The pin was made by this drag (cancel removes it, and its mirror pin with it).
    targets : ndarray (p, 3) or None
        World-space targets of the pins: where Blender drew them at mouse-down, the grabbed one where the mouse is.
    result : RigSolveResult or None
        The last move's.
    """

    model = None

    def __init__(self, obj):
        problem = rig_pin_problem(obj)
        if problem:
            raise ShapeSpaceError(problem, ErrorCode.INVALID)
        manipulation.check_pins(obj)
        self.controls = stored.control_set(obj)
        st = manipulation.settings(obj)
        self.samples = prior_samples(obj, self.controls) if st.mode == "LEARNED" else None
        self.alpha = float(st.alpha)
        self.rig = None
        self.index, self.mirror, self.created, self.targets, self.result = None, -1, False, None, None

    def grab(self, obj, index: int, created: bool = False) -> None:
        """Drag pin ``index`` (``created``: this drag made it, with its mirror pin in a symmetric drag): open the rig
        (refusals name the culprit — the rig's, the prior's, the mirror map's; a refused grab of pins this drag made
        removes them again) and hold every pin where Blender draws it."""
        index = pin_index(obj, index)
        state = manipulation.check_pins(obj)
        mirror = mirror_partner(obj, index) if manipulation.settings(obj).symmetric else -1
        rig = RigDrag(obj, self.controls, prior_samples=self.samples, prior_alpha=self.alpha)
        try:
            self.targets = rig.begin(state.pins(), mirror_map=symmetry.load_map(obj) if mirror >= 0 else None)
        except ShapeSpaceError:
            if created:
                _remove_made(obj, index, mirror)
            raise
        self.rig, self.index, self.mirror, self.created = rig, index, mirror, created

    def move(self, obj, depsgraph, world_point):
        """One mouse move: the grabbed pin follows ``world_point`` (3,), the others stay; the controls found are live
        on the rig (a failed move puts the last accepted ones back and raises)."""
        point = finite_point(world_point, "the drag position")
        targets = self.targets.copy()
        targets[self.index] = point
        if self.mirror == self.index:                         # a centre-line pin stays on the face's plane
            targets[self.index] = self.rig.plane.project(point)
        elif self.mirror >= 0:
            targets[self.mirror] = finite_point(self.rig.plane.reflect(point), f"the mirror of pin {self.index}")
        self.result = self.rig.move(targets)
        return self.result

    def rest(self, obj) -> bool:
        """The mouse rests (a timer tick of the tool): finish a slice (``REST_STEPS`` verified steps) of the work the
        moves deferred (:meth:`RigDrag.settle`), so the pins reach their targets without waiting for the release.
        Returns True while there is more to do; False once the last solve converged, stopped gaining, or before any
        move.  A failed step puts the last accepted controls back and raises."""
        result = self.result
        if self.rig is None or self.rig.ev is None or result is None or result.status != Status.NOT_CONVERGED:
            return False
        before = result.diagnostics.get("objective_history", [np.inf])[-1]
        self.result = self.rig.settle(max_iter=REST_STEPS)
        after = self.result.diagnostics.get("objective_history", [before])[-1]
        return self.result.status == Status.NOT_CONVERGED and after < before

    def cancel(self, obj) -> None:
        """Put every channel back exactly as it was at mouse-down and remove the pins this drag made (the pin, and
        its mirror pin in a symmetric drag); nothing keyed."""
        if self.rig is not None and self.rig.ev is not None:
            self.rig.cancel()
        if self.created and self.index is not None and self.index < len(manipulation.settings(obj).pins):
            _remove_made(obj, self.index, self.mirror)
        self.rig = None

    def key(self, obj, frame: int) -> int:
        """End the drag keying the channels it changed at ``frame`` on their datablocks' actions (auto-key);
        returns how many channels were keyed."""
        if self.rig is None or self.rig.ev is None:
            return 0
        return len(self.rig.release(autokey=True, frame=frame))

    def release(self, obj) -> None:
        """End the drag keeping the controls, keying nothing."""
        if self.rig is not None and self.rig.ev is not None:
            self.rig.release(autokey=False)


def _remove_made(obj, index: int, mirror: int) -> None:
    """Remove pin ``index`` made by a drag and its mirror pin ``mirror`` (made with it; −1 or ``index``: none)."""
    made = {index} | ({mirror} if 0 <= mirror < len(manipulation.settings(obj).pins) else set())
    for i in sorted(made, reverse=True):
        manipulation.remove_pin(obj, i)


def rest(drag, obj) -> bool:
    """A timer tick while the mouse rests, for either kind of drag: a rig drag settles a slice of its deferred work
    (:meth:`RigPinDrag.rest`, True while more remains); the linear drag has none (False)."""
    return drag.rest(obj) if isinstance(drag, RigPinDrag) else False


def status_line(drag, result) -> str:
    """The header line after a mouse move (either kind of drag)."""
    if not isinstance(drag, RigPinDrag):
        return manipulation.drag_status_line(result)
    text = f"ShapeSpace: largest pin error {_largest(result):.3g}"
    if result.status == Status.NOT_CONVERGED:
        return text + " · NOT CONVERGED: the rig could not reach the pins (controls are the best found)"
    return text if result.status == Status.OK else text + " · " + result.message


def report_text(drag) -> tuple:
    """``(level, text)`` for the user after a drag (``"INFO"`` when clean), or None before any move."""
    result = drag.result
    if result is None:
        return None
    if not isinstance(drag, RigPinDrag):
        return manipulation.report_text(result)
    text = f"{result.message}; largest pin error {_largest(result):.4g}"
    return ("INFO" if result.status == Status.OK else "WARNING"), text


def _largest(result) -> float:
    errors = np.asarray(result.pin_errors if result.pin_errors is not None else [], dtype=np.float64)
    return float(errors.max(initial=0.0))


def finish(drag, obj, frame: int, autokey: bool) -> int:
    """End either kind of drag on release: with ``autokey`` key what it changed at ``frame`` (returns how many);
    otherwise keep the result unkeyed."""
    if autokey:
        return drag.key(obj, frame)
    if isinstance(drag, RigPinDrag):
        drag.release(obj)
    return 0
