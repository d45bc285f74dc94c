"""Differences between supported Blender versions that are not about data (see actions.py for those)."""
import bpy

#: Built-in shader for round points: Blender 4.5+ has a dedicated one and deprecates drawing
#: points with UNIFORM_COLOR; 4.2 only has UNIFORM_COLOR.
POINT_SHADER = "POINT_UNIFORM_COLOR" if bpy.app.version >= (4, 5, 0) else "UNIFORM_COLOR"
