"""Viewport overlay: pins (on the deformed surface) and their targets, drawn with the gpu module.

Every viewport redraw calls the draw handler, and every mouse move of a drag
redraws the viewport, so the overlay reads only what it draws: the stored pins
(bulk reads), Blender's evaluated positions of the pinned vertices and the
crazy-space map cached per pose (:func:`bridge.manipulation.overlay_points`) —
never the blendshape model or a copy of the mesh.

This module also installs the handlers that keep the rig cache
(:data:`bridge.manipulation.RIGS`) honest: a ``depsgraph_update_post`` handler
reporting edits of the cached meshes and keys, and ``load_post`` /
``undo_post`` / ``redo_post`` handlers emptying it.
"""
import bpy
import gpu
import numpy as np
from bpy.app.handlers import persistent
from gpu_extras.batch import batch_for_shader

from ..bridge import compat, manipulation, meshes
from ..bridge.rig import tool as rig_tool

PIN_COLOR = (1.0, 0.55, 0.0, 1.0)
STILL_COLOR = (0.2, 0.6, 1.0, 1.0)
TARGET_COLOR = (1.0, 1.0, 1.0, 1.0)


class DrawHandlers:
    """The draw handlers this add-on has added to the 3D Viewport, so they can all be removed again.

    Blender returns an opaque handle from ``SpaceView3D.draw_handler_add``;
    the add-on must hand the same handle back to ``draw_handler_remove`` on
    unregister, so the handles are the one piece of state the overlay keeps
    between ``register()`` and ``unregister()``.  A single module-level
    instance, :data:`HANDLERS`, holds them (registering twice adds a second
    handler; :meth:`remove_all` removes every one, newest first).
    """

    def __init__(self, region_type: str = "WINDOW", draw_type: str = "POST_VIEW"):
        self.region_type = region_type
        self.draw_type = draw_type
        self._handles = []

    def add(self, callback) -> None:
        """Register ``callback()`` to draw in every 3D Viewport."""
        self._handles.append(bpy.types.SpaceView3D.draw_handler_add(callback, (), self.region_type, self.draw_type))

    def remove_all(self) -> None:
        """Remove every handler added through :meth:`add`."""
        while self._handles:
            bpy.types.SpaceView3D.draw_handler_remove(self._handles.pop(), self.region_type)

    def __len__(self) -> int:
        return len(self._handles)


#: The overlay's viewport draw handlers (registered by :func:`register`, removed by :func:`unregister`).
HANDLERS = DrawHandlers()


def pin_world_points(obj, depsgraph):
    """World-space pin positions, target positions (both on the deformed surface) and stationary flags.

    On a face the Pin tool drags through its rig (:func:`bridge.rig.tool.uses_rig`) a pin is held where it is
    drawn (its stored target is in no rig's space): the target shown is the pin itself."""
    if rig_tool.uses_rig(obj):
        state = manipulation.read_pin_state(obj)
        world = meshes.to_world(obj, manipulation.deformed_pin_positions(obj, depsgraph, state))
        return world, world.copy(), state.stationary
    current, goal, still = manipulation.overlay_points(obj, depsgraph)
    return meshes.to_world(obj, current), meshes.to_world(obj, goal), still


def draw_pins(obj, depsgraph, point_size: float = 8.0) -> int:
    """Draw ``obj``'s pins with the current gpu matrices; return how many were drawn."""
    try:
        current, goal, still = pin_world_points(obj, depsgraph)
    except Exception:  # a stale pin (mesh edited): the panel reports it, the overlay stays quiet
        return 0
    if not len(current):
        return 0
    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    points = gpu.shader.from_builtin(compat.POINT_SHADER)
    gpu.state.point_size_set(point_size)
    gpu.state.depth_test_set("NONE")
    lines = np.empty((2 * len(current), 3), dtype=np.float32)
    lines[0::2], lines[1::2] = current, goal
    shader.bind()
    shader.uniform_float("color", TARGET_COLOR)
    batch_for_shader(shader, "LINES", {"pos": lines.tolist()}).draw(shader)
    points.bind()
    points.uniform_float("color", TARGET_COLOR)
    batch_for_shader(points, "POINTS", {"pos": goal.astype(np.float32).tolist()}).draw(points)
    for mask, color in ((~still, PIN_COLOR), (still, STILL_COLOR)):
        if mask.any():
            points.uniform_float("color", color)
            batch_for_shader(points, "POINTS", {"pos": current[mask].astype(np.float32).tolist()}).draw(points)
    gpu.state.point_size_set(1.0)
    return len(current)


def _draw_callback():
    context = bpy.context
    obj = context.active_object
    if obj is None or obj.type != "MESH" or not hasattr(obj, "shapespace") or not len(obj.shapespace.pins):
        return
    if obj.shapespace.mode == "SLIDERS":
        return
    draw_pins(obj, context.evaluated_depsgraph_get())


@persistent
def _on_depsgraph_update(_scene, depsgraph):
    manipulation.RIGS.on_depsgraph_update(depsgraph)


@persistent
def _on_reset(*_args):
    manipulation.RIGS.clear()


#: ``bpy.app.handlers`` lists and the rig-cache handler each gets.
_APP_HANDLERS = (("depsgraph_update_post", _on_depsgraph_update), ("load_post", _on_reset),
                 ("undo_post", _on_reset), ("redo_post", _on_reset))


def register():
    HANDLERS.add(_draw_callback)
    for name, fn in _APP_HANDLERS:
        getattr(bpy.app.handlers, name).append(fn)
    manipulation.RIGS.install()


def unregister():
    manipulation.RIGS.uninstall()
    for name, fn in _APP_HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn in handlers:
            handlers.remove(fn)
    HANDLERS.remove_all()
