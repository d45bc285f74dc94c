import bpy
import numpy as np
from bpy_extras import view3d_utils

from ...bridge import manipulation, meshes, shapekeys
from ...core.manipulation import DragSession
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
            manipulation.check_pins(ob)
            self.prior = manipulation.prior_from_settings(ob, self.model)
            self.before = manipulation.current_sliders(ob)
            index = self._pick(ob, depsgraph, region, rv3d, mouse)
            self.created = index is None
            if self.created:
                origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, mouse)
                direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, mouse)
                hit = manipulation.surface_pin(ob, depsgraph, origin, direction)
                if hit is None:
                    return {"CANCELLED", "PASS_THROUGH"}
                pin, _ = hit
                index = manipulation.add_pin(ob, pin, None, self.stationary, model=self.model)
                if self.stationary:
                    return {"FINISHED"}
            manipulation.set_active_pin(ob, index)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.index = index
        self.start_target = manipulation.pin_target(ob, index)
        self.anchor_world = meshes.to_world(ob, manipulation.deformed_pin_positions(ob, depsgraph)[index][None])[0]
        self.solution = self.before[1].copy()
        self.session = DragSession()     # warm start of this drag's solves; dropped when the drag ends
        context.window_manager.modal_handler_add(self)
        context.workspace.status_text_set("Drag: move the pin · release to set · right-click/Esc to cancel")
        return {"RUNNING_MODAL"}

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
            self._restore(ob)
            return self._end(context, {"CANCELLED"})
        if event.type == "MOUSEMOVE":
            try:
                self._update(context, ob, (event.mouse_region_x, event.mouse_region_y))
            except ShapeSpaceError as exc:
                self.report({"ERROR"}, str(exc))
                self._restore(ob)
                return self._end(context, {"CANCELLED"})
            return {"RUNNING_MODAL"}
        if event.type == "LEFTMOUSE" and event.value == "RELEASE":
            if context.scene.tool_settings.use_keyframe_insert_auto:
                manipulation.key_changed(ob, self.before, self.solution, context.scene.frame_current)
            return self._end(context, {"FINISHED"})
        return {"RUNNING_MODAL"}

    def _end(self, context, status):
        self.session = None
        context.workspace.status_text_set(None)
        return status

    def _update(self, context, ob, mouse):
        region, rv3d = context.region, context.region_data
        world = view3d_utils.region_2d_to_location_3d(region, rv3d, mouse, self.anchor_world)
        depsgraph = context.evaluated_depsgraph_get()
        local = meshes.to_local(ob, np.array(world)[None])[0]
        manipulation.move_pin(ob, depsgraph, self.index, self.model, self.solution, local)
        result = manipulation.solve_pins(ob, x0=self.solution, model=self.model, prior=self.prior,
                                         w0=self.before[1], session=self.session)
        self.solution = result.weights
        context.area.header_text_set(f"ShapeSpace: largest pin error {result.residuals.max():.3g}")

    def _restore(self, ob):
        manipulation.undo_drag(ob, self.before, self.index, self.created, self.start_target)

    def cancel(self, context):
        self._restore(context.active_object)
        self.session = None
