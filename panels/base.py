"""Where ShapeSpace panels live: View3D ▸ Sidebar ▸ ShapeSpace."""


class ShapeSpaceSidebar:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ShapeSpace"
