import bpy
import numpy as np
from bpy_extras import view3d_utils

from ...bridge import drag, meshes, shapekeys
from ...core.manipulation.solve import pin_positions
from ...core.result import ShapeSpaceError
from ..polls import pinnable_rig

PICK_RADIUS_PX = 12.0


class SHAPESPACE_OT_drag_pins(bpy.types.Operator):
    """Click the face to pin a point and drag it; the sliders follow live.
Click near a pin to drag it, Shift-click to pin a point in place, right-click or Esc cancels the drag"""

    bl_idname = "shapespace.drag_pins"
    bl_label = "Drag Pins"
    bl_options = {"REGISTER", "UNDO", "BLOCKING"}

    stationary: bpy.props.BoolProperty(name="Pin In Place", options={"SKIP_SAVE"})

    @classmethod
    def poll(cls, context):
        if pinnable_rig(cls, context) is None:
            return False
        if context.area is None or context.area.type != "VIEW_3D":
            cls.poll_message_set("Use the ShapeSpace Pin tool in the 3D Viewport")
            return False
        return True

    def invoke(self, context, event):
        ob = context.active_object
        region, rv3d = context.region, context.region_data
        mouse = (event.mouse_region_x, event.mouse_region_y)
        depsgraph = context.evaluated_depsgraph_get()
        try:
            self.model = shapekeys.read_blendshape_model(ob)
            drag.check_pins(ob)
            self.prior = drag.prior_from_settings(ob, self.model)
            self.before = drag.current_sliders(ob)
            index = self._pick(ob, depsgraph, region, rv3d, mouse)
            self.created = index is None
            if self.created:
                origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, mouse)
                direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, mouse)
                hit = drag.surface_pin(ob, depsgraph, origin, direction)
                if hit is None:
                    return {"CANCELLED", "PASS_THROUGH"}
                pin, _ = hit
                target = pin_positions(self.model, [pin], self.model.values)[0]
                index = drag.add_pin(ob, pin, target, self.stationary)
                if self.stationary:
                    return {"FINISHED"}
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.index = index
        st = ob.shapespace
        st.active_pin = index
        self.start_target = tuple(st.pins[index].target)
        self.anchor_world = meshes.to_world(ob, drag.deformed_pin_positions(ob, depsgraph)[index][None])[0]
        self.solution = self.before[1].copy()
        self.last = None
        context.window_manager.modal_handler_add(self)
        context.workspace.status_text_set("Drag: move the pin · release to set · right-click/Esc to cancel")
        return {"RUNNING_MODAL"}

    def _pick(self, ob, depsgraph, region, rv3d, mouse):
        if not len(ob.shapespace.pins):
            return None
        world = meshes.to_world(ob, drag.deformed_pin_positions(ob, depsgraph))
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
            self._restore(ob)
            context.workspace.status_text_set(None)
            return {"CANCELLED"}
        if event.type == "MOUSEMOVE":
            try:
                self._update(context, ob, (event.mouse_region_x, event.mouse_region_y))
            except ShapeSpaceError as exc:
                self.report({"ERROR"}, str(exc))
                self._restore(ob)
                context.workspace.status_text_set(None)
                return {"CANCELLED"}
            return {"RUNNING_MODAL"}
        if event.type == "LEFTMOUSE" and event.value == "RELEASE":
            if context.scene.tool_settings.use_keyframe_insert_auto:
                drag.key_changed(ob, self.before, self.solution, context.scene.frame_current)
            context.workspace.status_text_set(None)
            return {"FINISHED"}
        return {"RUNNING_MODAL"}

    def _update(self, context, ob, mouse):
        region, rv3d = context.region, context.region_data
        world = view3d_utils.region_2d_to_location_3d(region, rv3d, mouse, self.anchor_world)
        depsgraph = context.evaluated_depsgraph_get()
        local = meshes.to_local(ob, np.array(world)[None])[0]
        pins, _, _ = drag.read_pins(ob)
        target = drag.deformed_to_shape_space(ob, depsgraph, pins[self.index], self.model, self.solution, local)
        ob.shapespace.pins[self.index].target = target
        result = drag.solve_pins(ob, x0=self.solution, model=self.model, prior=self.prior, w0=self.before[1],
                                 warm=self.last)
        self.solution, self.last = result.weights, result
        context.area.header_text_set(f"ShapeSpace: largest pin error {result.residuals.max():.3g}")

    def _restore(self, ob):
        shapekeys.write_slider_values(ob, *self.before)
        st = ob.shapespace
        if self.created:
            st.pins.remove(self.index)
            st.active_pin = max(0, len(st.pins) - 1)
        else:
            st.pins[self.index].target = self.start_target

    def cancel(self, context):
        self._restore(context.active_object)
