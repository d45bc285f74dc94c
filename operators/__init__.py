"""Operators: poll → read via the bridge → core → write via the bridge → report."""
import bpy

from .check_rig import SHAPESPACE_OT_check_rig
from .key_sliders import SHAPESPACE_OT_key_sliders

classes = (
    SHAPESPACE_OT_check_rig,
    SHAPESPACE_OT_key_sliders,
)

register, unregister = bpy.utils.register_classes_factory(classes)
