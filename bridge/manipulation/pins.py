"""Pins stored on a mesh (``Object.shapespace.pins``) and the verbs that write them.

A stored pin (:class:`SHAPESPACE_PG_pin`) has three vertex indices, three
barycentric weights padded with zeros, a target in shape-key space and a
stationary flag.  :func:`read_pin_state` reads all of them with four bulk
reads (no Python loop over the pins), as every mouse move and every redraw
does; every write of pins, pin targets and the active pin goes through the
verbs here.  :func:`overlay_points` is what the viewport overlay draws.

Mirrored pins (issue #13): a pin's ``mirror_of`` names its mirror pin (both ways; the pin itself for a pin on
the centre line; −1 for none; old files load with −1).  Mirror pins are found through the mesh's stored mirror
map (:mod:`..symmetry`): a surface point ``Σ bᵢ vᵢ`` mirrors to ``Σ bᵢ m(vᵢ)``, and a target in shape-key space
(the mesh's rest object space, where the map's plane ``x_axis = offset`` lives) mirrors to its reflection
across that plane (the pure geometry: :mod:`core.manipulation.geometry`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.blendshape import BlendshapeModel
from ...core.errors import ErrorCode
from ...core.manipulation import Pin, pin_positions
from ...core.manipulation.geometry import mirror_pin, pin_surface_positions, reflect_point
from ...core.result import ShapeSpaceError
from .. import symmetry
from .cache import RIGS, write_sliders
from .surface import deform_map, evaluated_vertices, finite_point, world_to_local

__all__ = ["PinState", "settings", "stored_pin", "read_pin_state", "read_pins", "check_pins", "pin_index", "add_pin",
           "remove_pin", "clear_pins", "store_pin", "set_pin_target", "set_active_pin", "pin_target", "undo_drag",
           "to_shape_space", "deformed_to_shape_space", "deformed_pin_positions", "SPACES", "mirror_links",
           "mirror_partner", "mirror_plane", "mirror_pins", "overlay_points"]

#: Spaces a caller's target can be given in (see :func:`to_shape_space`).
SPACES = ("WORLD", "LOCAL")


def settings(obj):
    """The object's pin-and-drag settings (``Object.shapespace``)."""
    return obj.shapespace


def stored_pin(vertices: Sequence[int], weights: Sequence[float]) -> Pin:
    """The :class:`Pin` of stored (or operator) fields: 3 vertices and 3 weights, unused trailing weights 0."""
    count = 3 if weights[2] != 0.0 else (2 if weights[1] != 0.0 else 1)
    return Pin(tuple(vertices[:count]), tuple(weights[:count]))


@dataclass
class PinState:
    """The stored pins as arrays (one bulk read each).

    Attributes
    ----------
    vertices : ndarray of int, shape (k, 3)
        Stored vertex indices (unused slots repeat the first vertex).
    weights : ndarray, shape (k, 3)
        Barycentric weights, unused slots 0.
    targets : ndarray, shape (k, 3)
        Targets in shape-key space.
    stationary : ndarray of bool, shape (k,)
    """

    vertices: np.ndarray
    weights: np.ndarray
    targets: np.ndarray
    stationary: np.ndarray

    def __len__(self) -> int:
        return len(self.stationary)

    def pins(self) -> list:
        """The :class:`Pin` of each stored pin (1–3 vertices, as :func:`stored_pin`)."""
        return [stored_pin(v, w) for v, w in zip(self.vertices.tolist(), self.weights.tolist())]

    def key(self) -> bytes:
        """The stored values as bytes (compare two states cheaply)."""
        return b"".join(a.tobytes() for a in (self.vertices, self.weights, self.targets, self.stationary))


def read_pin_state(obj) -> PinState:
    """The stored pins as a :class:`PinState` (four ``foreach_get`` reads)."""
    items = settings(obj).pins
    k = len(items)
    verts = np.empty(3 * k, dtype=np.int32)
    weights = np.empty(3 * k, dtype=np.float32)
    targets = np.empty(3 * k, dtype=np.float32)
    still = np.empty(k, dtype=bool)
    if k:
        items.foreach_get("vertices", verts)
        items.foreach_get("weights", weights)
        items.foreach_get("target", targets)
        items.foreach_get("stationary", still)
    return PinState(verts.reshape(k, 3).astype(np.int64), weights.reshape(k, 3).astype(np.float64),
                    targets.reshape(k, 3).astype(np.float64), still)


def read_pins(obj):
    """Pins and their targets (shape-key space), ``(list of Pin, (k, 3) array, stationary (k,))``."""
    state = read_pin_state(obj)
    return state.pins(), state.targets, state.stationary


def check_pins(obj, state: PinState | None = None) -> PinState:
    """The stored pins; raise if one refers to a vertex the mesh no longer has."""
    state = read_pin_state(obj) if state is None else state
    p = len(obj.data.vertices)
    if len(state):
        far = state.vertices.max(axis=1)
        bad = np.flatnonzero(far >= p)
        if bad.size:
            j = int(bad[0])
            raise ShapeSpaceError(f"pin {j} refers to vertex {int(far[j])} but the mesh has {p}: clear the pins",
                                  ErrorCode.PIN)
    return state


def pin_index(obj, index: int) -> int:
    if not 0 <= index < len(settings(obj).pins):
        raise ShapeSpaceError(f"there is no pin {index}", ErrorCode.RANGE)
    return index


# ---------------------------------------------------------------------------- spaces
def deformed_to_shape_space(obj, depsgraph, pin: Pin, model: BlendshapeModel, weights, deformed_target,
                            shape_pos=None):
    """Map a target given on the deformed surface (object space) back to shape-key space.

    ``shape position at weights + Σ bᵢ Aᵢ⁻¹ (target − the pin where Blender shows it now)`` with the
    crazy-space matrices ``Aᵢ`` of the pin's vertices (:func:`~.surface.deform_map`, cached per pose): exact
    for linear deformers such as the Armature modifier.  ``shape_pos``: the pin's shape-key position at
    ``weights`` when the caller has it (a drag's pin rows).
    """
    dmap = deform_map(obj, depsgraph, pin.vertices)
    if dmap is None:
        return np.asarray(deformed_target, dtype=np.float64)
    if shape_pos is None:
        shape_pos = pin_positions(model, [pin], weights)[0]
    verts = np.asarray(pin.vertices, dtype=np.int64)
    bary = np.asarray(pin.weights, dtype=np.float64)
    now = bary @ evaluated_vertices(obj, depsgraph, verts)
    delta = np.asarray(deformed_target, dtype=np.float64) - now
    back = np.einsum("v,vij,j->i", bary, dmap.A_inv[dmap.rows(verts)], delta)
    return shape_pos + back


def to_shape_space(obj, depsgraph, pin: Pin, model: BlendshapeModel, target, space: str = "LOCAL",
                   weights=None) -> np.ndarray:
    """A target (3,) given in ``space`` (one of :data:`SPACES`) as a target in shape-key space.

    ``"WORLD"``: through the inverse of the object's world matrix (parents included), then back through the
    deform modifiers at the sliders ``weights`` (default ``model.values``) as a viewport drag does
    (:func:`deformed_to_shape_space`).  ``"LOCAL"``: unchanged.
    """
    target = finite_point(target, "the target")
    if space not in SPACES:
        raise ShapeSpaceError(f"space must be one of {', '.join(SPACES)}, got {space!r}", ErrorCode.METHOD)
    if space == "LOCAL":
        return target
    depsgraph = depsgraph if depsgraph is not None else bpy.context.evaluated_depsgraph_get()
    local = world_to_local(obj, target[None])[0]
    weights = model.values if weights is None else weights
    return finite_point(deformed_to_shape_space(obj, depsgraph, pin, model, weights, local),
                        "the target in shape-key space")


def deformed_pin_positions(obj, depsgraph, state: PinState | None = None) -> np.ndarray:
    """Current positions of the stored pins on the evaluated (deformed) surface, object space, (k, 3)."""
    state = check_pins(obj, state)
    if not len(state):
        return np.zeros((0, 3))
    verts = np.unique(state.vertices)
    return pin_surface_positions(state.vertices, state.weights, evaluated_vertices(obj, depsgraph, verts), verts)


def _overlay_goal(obj, depsgraph, state: PinState, verts: np.ndarray, ev: np.ndarray, current: np.ndarray):
    """Targets shown on the deformed surface: ``current + Σ bᵢ Aᵢ (target − shape-key position now)``."""
    dmap = deform_map(obj, depsgraph, verts, offsets=True)
    if dmap is None:
        return state.targets.copy()
    r = dmap.rows(verts)
    shape_v = np.einsum("mij,mj->mi", dmap.A_inv[r], ev - dmap.c[r])     # A s + c = deformed, per vertex
    rows = np.searchsorted(verts, state.vertices)
    shape_now = np.einsum("kc,kcx->kx", state.weights, shape_v[rows])
    delta = state.targets - shape_now
    return current + np.einsum("kc,kcij,kj->ki", state.weights, dmap.A[r][rows], delta)


def overlay_points(obj, depsgraph, state: PinState | None = None):
    """What the overlay draws: pins and targets on the evaluated surface (object space, (k, 3) each), and
    the stationary flags (k,).

    Read from Blender's evaluated mesh at the pinned vertices only, with the cached crazy-space map: no
    model read, no copy of the mesh (the model is needed only to rebuild the map after a pose change).
    """
    state = check_pins(obj, state)
    if not len(state):
        return np.zeros((0, 3)), np.zeros((0, 3)), state.stationary
    verts = np.unique(state.vertices)
    ev = evaluated_vertices(obj, depsgraph, verts)
    current = pin_surface_positions(state.vertices, state.weights, ev, verts)
    return current, _overlay_goal(obj, depsgraph, state, verts, ev, current), state.stationary


# ---------------------------------------------------------------------------- writes
def add_pin(obj, pin: Pin, target=None, stationary: bool = False, model: BlendshapeModel | None = None,
            space: str = "LOCAL", depsgraph=None, symmetric: bool | None = None) -> int:
    """Store a pin on the object, make it the active pin and return its index.

    ``target`` (3,) in ``space`` (:data:`SPACES`; ``"WORLD"`` needs ``depsgraph``); ``None`` pins the point
    where it is now (at the current sliders of ``model``, the cached model of ``obj`` when not given).
    ``symmetric`` (default: the object's *Symmetric* setting) also stores the mirror pin (:func:`mirror_pin`,
    through the stored mirror map) right after it, linked both ways, with the reflected target (or, without a
    target, where its point is now); a pin on the centre line is linked to itself.
    Nothing is stored when the pin, the rig, the target or the mirror map is refused.
    """
    p = len(obj.data.vertices)
    if any(v < 0 or v >= p for v in pin.vertices):
        raise ShapeSpaceError(f"pin vertex out of range 0..{p - 1}", ErrorCode.PIN)
    model = model or RIGS.model(obj)
    here = pin_positions(model, [pin], model.values)[0]      # checks the pin and the rig (finite)
    given = target is not None
    if target is None:
        target = finite_point(here, "the pin's position")
    else:
        target = to_shape_space(obj, depsgraph, pin, model, target, space)
    symmetric = settings(obj).symmetric if symmetric is None else bool(symmetric)
    twin = twin_target = None
    if symmetric:
        mmap = symmetry.load_map(obj)
        twin = mirror_pin(pin, mmap, "the new pin")
        if twin is not None:
            if given:
                twin_target = reflect_point(target, (mmap.axis, mmap.offset))
            else:
                twin_target = pin_positions(model, [twin], model.values)[0]
            twin_target = finite_point(twin_target, "the mirror pin's position")
    index = store_pin(obj, pin, target, stationary)
    if symmetric:
        if twin is None:
            settings(obj).pins[index].mirror_of = index
        else:
            other = store_pin(obj, twin, twin_target, stationary)
            settings(obj).pins[index].mirror_of = other
            settings(obj).pins[other].mirror_of = index
    settings(obj).active_pin = index
    return index


def store_pin(obj, pin: Pin, target, stationary: bool) -> int:
    """Append ``pin`` with ``target`` (3,) as stored (no checks, no mirror link, not made active); returns its
    index.  The verbs above check first; the Pin tool on a rig face (:mod:`bridge.rig.tool`) stores through it."""
    item = settings(obj).pins.add()
    v = list(pin.vertices) + [pin.vertices[0]] * (3 - len(pin.vertices))
    w = list(pin.weights) + [0.0] * (3 - len(pin.weights))
    item.vertices, item.weights = v, w
    item.target = tuple(float(x) for x in target)
    item.stationary = stationary
    item.mirror_of = -1
    return len(settings(obj).pins) - 1


def remove_pin(obj, index: int = -1) -> int:
    """Remove pin ``index`` (``-1``: the active pin); return the index removed.  Its mirror pin stays (unlinked)
    and the other pins' mirror links follow the renumbering."""
    st = settings(obj)
    index = pin_index(obj, st.active_pin if index < 0 else index)
    _remove(st, index)
    st.active_pin = min(st.active_pin, len(st.pins) - 1)
    return index


def _remove(st, index: int) -> None:
    """Remove pin ``index`` and renumber the mirror links (a link to it becomes −1)."""
    links = _links(st.pins)
    st.pins.remove(index)
    links = np.delete(links, index)
    links = np.where(links == index, -1, np.where(links > index, links - 1, links))
    if len(links):
        st.pins.foreach_set("mirror_of", links.astype(np.int32))


def clear_pins(obj) -> None:
    """Remove every pin of the object."""
    settings(obj).pins.clear()
    settings(obj).active_pin = 0


def set_pin_target(obj, index: int, target) -> None:
    """Move pin ``index``'s target (3,), shape-key space (refused when not finite)."""
    target = finite_point(target, f"the target of pin {index}")
    settings(obj).pins[pin_index(obj, index)].target = tuple(float(x) for x in target)


def set_active_pin(obj, index: int) -> None:
    """Make pin ``index`` the active one (the list's selection)."""
    settings(obj).active_pin = pin_index(obj, index)


def pin_target(obj, index: int) -> tuple:
    """Pin ``index``'s target, shape-key space."""
    return tuple(settings(obj).pins[pin_index(obj, index)].target)


def undo_drag(obj, before, index: int, created: bool, start_target, mirror: tuple | None = None) -> None:
    """Put back what a cancelled drag changed.

    ``before`` is ``(names, values)`` of the sliders when the drag started; the
    pin the drag created is removed, the pin it moved gets ``start_target`` back.
    ``mirror`` is ``(index, start target)`` of the dragged pin's mirror pin when it moved along (a symmetric
    drag): it is removed with a pin the drag created, otherwise its target is put back too.
    """
    write_sliders(obj, *before)
    st = settings(obj)
    if index >= len(st.pins):
        return
    j = mirror[0] if mirror is not None and 0 <= mirror[0] < len(st.pins) and mirror[0] != index else None
    if created:
        for i in sorted({index} | ({j} if j is not None else set()), reverse=True):
            _remove(st, i)
        st.active_pin = max(0, len(st.pins) - 1)
    else:
        st.pins[index].target = start_target
        if j is not None:
            st.pins[j].target = mirror[1]


# ---------------------------------------------------------------------------- mirrored pins
def _links(items) -> np.ndarray:
    links = np.empty(len(items), dtype=np.int32)
    if len(items):
        items.foreach_get("mirror_of", links)
    return links.astype(np.int64)


def mirror_links(obj) -> np.ndarray:
    """Each stored pin's mirror pin, int64 (k,): its own index on the centre line, −1 for none (a damaged link,
    out of range, reads as −1)."""
    links = _links(settings(obj).pins)
    links[(links < -1) | (links >= len(links))] = -1
    return links


def mirror_partner(obj, index: int) -> int:
    """Pin ``index``'s mirror pin (−1: none; ``index``: on the centre line)."""
    links = mirror_links(obj)
    return int(links[index]) if 0 <= index < len(links) else -1


def mirror_plane(obj) -> tuple:
    """``(axis, offset)`` of the object's stored mirror map (refused when there is none or it is stale)."""
    mmap = symmetry.load_map(obj)
    return mmap.axis, mmap.offset


def mirror_pins(obj, model: BlendshapeModel | None = None) -> dict:
    """Give every pin without a mirror link its mirror pin (the Mirror Pins operator).

    A pin whose mirror point already carries an unlinked pin is linked to it; a pin on the centre line is linked
    to itself; otherwise a mirror pin is added with the reflected target and the same stationary flag.  Every
    pin is checked before anything is written (refused: no map, a stale map, an unmapped vertex).

    Returns
    -------
    dict
        ``{"added": int, "linked": int, "centre": int}``.
    """
    mmap = symmetry.load_map(obj)
    plane = (mmap.axis, mmap.offset)
    state = check_pins(obj)
    pins = state.pins()
    links = mirror_links(obj)
    model = model or RIGS.model(obj)
    keys = {(p.vertices, tuple(round(b, 6) for b in p.weights)): j for j, p in enumerate(pins) if links[j] < 0}
    plan = []                                   # (pin, ("centre" | "link" | "add"), other pin or new Pin, target)
    claimed = set()
    for j, pin in enumerate(pins):
        if links[j] >= 0 or j in claimed:
            continue
        twin = mirror_pin(pin, mmap, f"pin {j}")
        if twin is None:
            plan.append((j, "centre", None, None))
            continue
        other = keys.get((twin.vertices, tuple(round(b, 6) for b in twin.weights)))
        if other is not None and other != j and other not in claimed:
            claimed.update((j, other))
            plan.append((j, "link", other, None))
            continue
        target = finite_point(reflect_point(state.targets[j], plane), f"the mirror of pin {j}'s target")
        pin_positions(model, [twin], model.values)              # checks the mirror pin against the rig
        plan.append((j, "add", twin, target))
    st = settings(obj)
    counts = {"added": 0, "linked": 0, "centre": 0}
    for j, kind, other, target in plan:
        if kind == "centre":
            st.pins[j].mirror_of = j
            counts["centre"] += 1
        elif kind == "link":
            st.pins[j].mirror_of, st.pins[other].mirror_of = other, j
            counts["linked"] += 2
        else:
            new = store_pin(obj, other, target, bool(state.stationary[j]))
            st.pins[j].mirror_of, st.pins[new].mirror_of = new, j
            counts["added"] += 1
    return counts
