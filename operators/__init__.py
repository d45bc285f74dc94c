"""Operators: poll → read via the bridge → core → write via the bridge → report."""
import bpy

from .add_combination import SHAPESPACE_OT_add_combination
from .add_inbetween import SHAPESPACE_OT_add_inbetween
from .add_pin import SHAPESPACE_OT_add_pin
from .check_rig import SHAPESPACE_OT_check_rig
from .clear_pins import SHAPESPACE_OT_clear_pins
from .drag_pins import SHAPESPACE_OT_drag_pins
from .key_sliders import SHAPESPACE_OT_key_sliders
from .remove_pin import SHAPESPACE_OT_remove_pin
from .solve_pins import SHAPESPACE_OT_solve_pins

classes = (
    SHAPESPACE_OT_check_rig,
    SHAPESPACE_OT_key_sliders,
    SHAPESPACE_OT_add_pin,
    SHAPESPACE_OT_remove_pin,
    SHAPESPACE_OT_clear_pins,
    SHAPESPACE_OT_solve_pins,
    SHAPESPACE_OT_drag_pins,
    SHAPESPACE_OT_add_inbetween,
    SHAPESPACE_OT_add_combination,
)

register, unregister = bpy.utils.register_classes_factory(classes)
