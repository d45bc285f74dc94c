"""Sidebar panels (View3D ▸ Sidebar ▸ ShapeSpace), one module per capability, registered in sidebar order."""
import bpy

from .authoring import SHAPESPACE_PT_transfer_shapes, SHAPESPACE_UL_transfer_examples, SHAPESPACE_UL_transfer_parts
from .controls import SHAPESPACE_PT_controls
from .export import SHAPESPACE_PT_export
from .facespace import SHAPESPACE_PT_face_space, SHAPESPACE_UL_flagged_frames
from .live import SHAPESPACE_PT_live, SHAPESPACE_UL_live_takes
from .manipulation import SHAPESPACE_PT_direct, SHAPESPACE_UL_pins
from .named_landmarks import SHAPESPACE_PT_named_landmarks
from .posespace import SHAPESPACE_PT_correctives, SHAPESPACE_UL_examples, SHAPESPACE_UL_readers
from .retarget import SHAPESPACE_PT_retarget
from .rig import SHAPESPACE_PT_rig

classes = (SHAPESPACE_PT_rig, SHAPESPACE_PT_controls, SHAPESPACE_UL_transfer_examples, SHAPESPACE_UL_transfer_parts,
           SHAPESPACE_PT_transfer_shapes,
           SHAPESPACE_PT_named_landmarks,
           SHAPESPACE_UL_pins,
           SHAPESPACE_PT_direct,
           SHAPESPACE_UL_examples,
           SHAPESPACE_UL_readers, SHAPESPACE_PT_correctives, SHAPESPACE_PT_retarget,
           SHAPESPACE_UL_flagged_frames, SHAPESPACE_PT_face_space, SHAPESPACE_UL_live_takes, SHAPESPACE_PT_live,
           SHAPESPACE_PT_export)

register, unregister = bpy.utils.register_classes_factory(classes)
