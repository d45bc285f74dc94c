"""The "ShapeSpace Pin" tool in the 3D Viewport toolbar (Object Mode)."""
import bpy


class SHAPESPACE_TL_pin(bpy.types.WorkSpaceTool):
    bl_space_type = "VIEW_3D"
    bl_context_mode = "OBJECT"
    bl_idname = "shapespace.pin_tool"
    bl_label = "ShapeSpace Pin"
    bl_description = ("Click the face to pin a point and drag it; the shape-key sliders follow (on a face driven "
                      "by its stored control set, the rig's bones and properties; release keys them with auto-key).\n"
                      "Shift-click pins a point in place. With Symmetric on (Direct Manipulation panel) a "
                      "new pin also pins its mirror point and a pin's mirror follows it; cancel restores both")
    bl_icon = "ops.generic.cursor"
    bl_keymap = (
        ("shapespace.drag_pins", {"type": "LEFTMOUSE", "value": "PRESS"},
         {"properties": [("stationary", False)]}),
        ("shapespace.drag_pins", {"type": "LEFTMOUSE", "value": "PRESS", "shift": True},
         {"properties": [("stationary", True)]}),
    )


def register():
    bpy.utils.register_tool(SHAPESPACE_TL_pin, separator=True)


def unregister():
    bpy.utils.unregister_tool(SHAPESPACE_TL_pin)
