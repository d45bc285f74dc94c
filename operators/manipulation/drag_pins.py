import bpy
import numpy as np
from bpy_extras import view3d_utils

from ...bridge import manipulation, meshes
from ...bridge.rig import tool
from ..reporting import FAILED, attempt
from ._polls import pin_face

PICK_RADIUS_PX = 12.0
REST_INTERVAL_S = 0.05     # while the mouse rests, a rig drag settles what its moves deferred at this rate


class SHAPESPACE_OT_drag_pins(bpy.types.Operator):
    """Click the face to pin a point and drag it; the sliders follow live.
Click near a pin to drag it, Shift-click to pin a point in place, right-click or Esc cancels the drag.
With Symmetric on, a new pin comes with its mirror pin and a pin's mirror follows it (cancel restores both).
On a face driven by its stored control set (bones, drivers, hybrids) the rig's controls follow and release keys the
changed channels (auto-key)"""

    bl_idname = "shapespace.drag_pins"
    bl_label = "Drag Pins"
    bl_options = {"REGISTER", "UNDO", "BLOCKING"}

    stationary: bpy.props.BoolProperty(name="Pin In Place", options={"SKIP_SAVE"})

    @classmethod
    def poll(cls, context):
        if pin_face(cls, context) is None:
            return False
        if context.area is None or context.area.type != "VIEW_3D":
            cls.poll_message_set("Use the ShapeSpace Pin tool in the 3D Viewport")
            return False
        return True

    def invoke(self, context, event):
        grabbed = attempt(self, self._grab, context, (event.mouse_region_x, event.mouse_region_y))
        if grabbed is FAILED:
            return {"CANCELLED"}
        if grabbed is not None:
            return grabbed
        context.window_manager.modal_handler_add(self)
        self._timer = context.window_manager.event_timer_add(REST_INTERVAL_S, window=context.window)
        context.workspace.status_text_set("Drag: move the pin · release to set · right-click/Esc to cancel")
        return {"RUNNING_MODAL"}

    def _grab(self, context, mouse):
        """Grab the pin under the mouse (one made there if none): ``None`` to start dragging, else the result."""
        ob = context.active_object
        region, rv3d = context.region, context.region_data
        depsgraph = context.evaluated_depsgraph_get()
        self.drag = tool.drag_for(ob)     # the linear rig from the cache (or the face's rig), the prior, the start
        index = self._pick(ob, depsgraph, region, rv3d, mouse)
        created = index is None
        if created:
            origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, mouse)
            direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, mouse)
            hit = manipulation.surface_pin(ob, depsgraph, origin, direction)
            if hit is None:
                return {"CANCELLED", "PASS_THROUGH"}
            pin, self.anchor_world = hit
            index = tool.add_pin(ob, self.drag, pin, self.stationary)
            if self.stationary:
                return {"FINISHED"}
        else:
            here = manipulation.deformed_pin_positions(ob, depsgraph)[index]
            self.anchor_world = meshes.to_world(ob, here[None])[0]
        manipulation.set_active_pin(ob, index)
        self.drag.grab(ob, index, created)
        return None

    def _pick(self, ob, depsgraph, region, rv3d, mouse):
        if not len(ob.shapespace.pins):
            return None
        world = meshes.to_world(ob, manipulation.deformed_pin_positions(ob, depsgraph))
        best, best_d = None, PICK_RADIUS_PX
        for j, p in enumerate(world):
            screen = view3d_utils.location_3d_to_region_2d(region, rv3d, p)
            if screen is not None:
                d = float(np.hypot(screen[0] - mouse[0], screen[1] - mouse[1]))
                if d < best_d:
                    best, best_d = j, d
        return best

    def modal(self, context, event):
        ob = context.active_object
        if event.type in {"RIGHTMOUSE", "ESC"} and event.value == "PRESS":
            self.drag.cancel(ob)
            return self._end(context, {"CANCELLED"})
        if event.type == "MOUSEMOVE":
            if attempt(self, self._update, context, ob, (event.mouse_region_x, event.mouse_region_y)) is FAILED:
                self.drag.cancel(ob)
                return self._end(context, {"CANCELLED"})
            return {"RUNNING_MODAL"}
        if event.type == "TIMER" and self.drag is not None:
            if attempt(self, self._rest, context, ob) is FAILED:
                self.drag.cancel(ob)
                return self._end(context, {"CANCELLED"})
            return {"RUNNING_MODAL"}
        if event.type == "LEFTMOUSE" and event.value == "RELEASE":
            autokey = context.scene.tool_settings.use_keyframe_insert_auto
            if attempt(self, tool.finish, self.drag, ob, context.scene.frame_current, autokey) is FAILED:
                self.drag.cancel(ob)
                return self._end(context, {"CANCELLED"})
            said = tool.report_text(self.drag)
            if said is not None and said[0] != "INFO":
                self.report({said[0]}, said[1])
            return self._end(context, {"FINISHED"})
        return {"RUNNING_MODAL"}

    def _end(self, context, status):
        self._remove_timer(context)
        self.drag = None
        context.workspace.status_text_set(None)
        if context.area is not None:
            context.area.header_text_set(None)
        return status

    def _update(self, context, ob, mouse):
        region, rv3d = context.region, context.region_data
        world = view3d_utils.region_2d_to_location_3d(region, rv3d, mouse, self.anchor_world)
        result = self.drag.move(ob, context.evaluated_depsgraph_get(), world)
        context.area.header_text_set(tool.status_line(self.drag, result))

    def _rest(self, context, ob):
        if tool.rest(self.drag, ob):
            context.area.header_text_set(tool.status_line(self.drag, self.drag.result))

    def _remove_timer(self, context):
        if getattr(self, "_timer", None) is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None

    def cancel(self, context):
        self._remove_timer(context)
        if getattr(self, "drag", None) is not None:
            self.drag.cancel(context.active_object)
        self.drag = None
