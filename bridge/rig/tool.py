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
where they are drawn at mouse-down.  Direct mode applies (the solve stays near the controls at mouse-down); the
Learned prior (a shape-key action) and Symmetric drags are the linear path's and are refused by name
(:func:`rig_pin_problem`, the tool's poll message).
"""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError, Status
from ...core.rig.controls import ChannelKind
from .. import manipulation
from ..manipulation.pins import _store, pin_index
from ..manipulation.surface import finite_point
from . import stored
from .channels import bind
from .drag import RigDrag
from .evaluate import _rig_ids, check_editable

#: Verified steps (rig evaluations and, when a step stalls, a Jacobian refresh) per timer tick while the mouse rests.
REST_STEPS = 3

__all__ = ["RigPinDrag", "add_pin", "drag_for", "finish", "report_text", "rig_pin_problem", "status_line", "uses_rig"]


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
    """Why the Pin tool cannot drag the rig face ``obj`` ('' when it can): the mode, the prior, Symmetric, a
    control set that does not read, channels that are gone, linked data or Edit Mode among the rig's objects."""
    st = manipulation.settings(obj)
    if st.mode == "SLIDERS":
        return "Switch the ShapeSpace mode to Direct or Learned"
    if st.mode == "LEARNED":
        return (f"'{obj.name}' is driven by its rig's controls: the Learned prior is for shape-key faces, switch the "
                "mode to Direct")
    if st.symmetric:
        return f"'{obj.name}' is driven by its rig's controls: Symmetric drags are for shape-key faces, turn it off"
    try:
        controls = stored.control_set(obj)
        check_editable(_rig_ids(obj, bind(controls)))
    except ShapeSpaceError as exc:
        return str(exc)
    return ""


def drag_for(obj):
    """The drag the Pin tool starts at mouse-down on ``obj``: :class:`RigPinDrag` on a rig face (:func:`uses_rig`),
    else the linear :class:`bridge.manipulation.Drag`."""
    return RigPinDrag(obj) if uses_rig(obj) else manipulation.Drag(obj)


def add_pin(obj, drag, pin, stationary: bool = False) -> int:
    """Store a new pin for ``drag`` (made by :func:`drag_for`); returns its index.  On a rig face it is stored with
    its undeformed position as target (never mirrored: Symmetric is refused there); otherwise
    :func:`bridge.manipulation.add_pin` with the drag's model."""
    if not isinstance(drag, RigPinDrag):
        return manipulation.add_pin(obj, pin, None, stationary, model=drag.model)
    n = len(obj.data.vertices)
    if any(v < 0 or v >= n for v in pin.vertices):
        raise ShapeSpaceError(f"pin vertex out of range 0..{n - 1}", ErrorCode.PIN)
    co = np.empty(3 * n, dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    co = co.reshape(n, 3).astype(np.float64)
    rest = sum(w * co[v] for v, w in zip(pin.vertices, pin.weights))
    index = _store(obj, pin, finite_point(rest, "the pin's position"), stationary)
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
    created : bool
        The pin was made by this drag (cancel removes it).
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
        self.rig = None
        self.index, self.created, self.targets, self.result = None, False, None, None

    def grab(self, obj, index: int, created: bool = False) -> None:
        """Drag pin ``index`` (``created``: this drag made it): open the rig (refusals name the culprit; a refused
        grab of a pin this drag made removes it again) and hold every pin where Blender draws it."""
        index = pin_index(obj, index)
        state = manipulation.check_pins(obj)
        rig = RigDrag(obj, self.controls)
        try:
            self.targets = rig.begin(state.pins())
        except ShapeSpaceError:
            if created:
                manipulation.remove_pin(obj, index)
            raise
        self.rig, self.index, self.created = rig, index, created

    def move(self, obj, depsgraph, world_point):
        """One mouse move: the grabbed pin follows ``world_point`` (3,), the others stay; the controls found are live
        on the rig (a failed move puts the last accepted ones back and raises)."""
        point = finite_point(world_point, "the drag position")
        targets = self.targets.copy()
        targets[self.index] = point
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
        """Put every channel back exactly as it was at mouse-down and remove a pin this drag made (nothing keyed)."""
        if self.rig is not None and self.rig.ev is not None:
            self.rig.cancel()
        if self.created and self.index is not None and self.index < len(manipulation.settings(obj).pins):
            manipulation.remove_pin(obj, self.index)
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
