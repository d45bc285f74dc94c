"""Sidebar panels (View3D ▸ Sidebar ▸ ShapeSpace)."""
import bpy

from .rig_panel import SHAPESPACE_PT_rig

classes = (SHAPESPACE_PT_rig,)

register, unregister = bpy.utils.register_classes_factory(classes)
