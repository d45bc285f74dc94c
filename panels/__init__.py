"""Sidebar panels (View3D ▸ Sidebar ▸ ShapeSpace)."""
import bpy

from .face_panel import SHAPESPACE_PT_face_space, SHAPESPACE_UL_flagged_frames
from .direct_panel import SHAPESPACE_PT_direct, SHAPESPACE_UL_pins
from .psd_panel import SHAPESPACE_PT_correctives, SHAPESPACE_UL_examples, SHAPESPACE_UL_readers
from .retarget_panel import SHAPESPACE_PT_retarget
from .rig_panel import SHAPESPACE_PT_rig

classes = (SHAPESPACE_PT_rig, SHAPESPACE_UL_pins, SHAPESPACE_PT_direct, SHAPESPACE_UL_examples,
           SHAPESPACE_UL_readers, SHAPESPACE_PT_correctives, SHAPESPACE_PT_retarget,
           SHAPESPACE_UL_flagged_frames, SHAPESPACE_PT_face_space)

register, unregister = bpy.utils.register_classes_factory(classes)
