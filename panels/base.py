"""Where ShapeSpace panels live: View3D ▸ Sidebar ▸ ShapeSpace."""


class ShapeSpaceSidebar:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ShapeSpace"


def shape_key_mesh(context):
    """True when the active object is a mesh with shape keys (the face panels' poll)."""
    ob = context.active_object
    return ob is not None and ob.type == "MESH" and ob.data.shape_keys is not None


class ShapeKeyPanel(ShapeSpaceSidebar):
    """A closed-by-default sidebar panel for meshes with shape keys."""

    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return shape_key_mesh(context)
