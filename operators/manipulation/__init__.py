"""Operators: Pin-and-drag direct manipulation (thesis ch. 4)."""
from .add_pin import SHAPESPACE_OT_add_pin
from .clear_pins import SHAPESPACE_OT_clear_pins
from .drag_pins import SHAPESPACE_OT_drag_pins
from .mirror_pins import SHAPESPACE_OT_mirror_pins
from .remove_pin import SHAPESPACE_OT_remove_pin
from .solve_pins import SHAPESPACE_OT_solve_pins

classes = (
    SHAPESPACE_OT_add_pin,
    SHAPESPACE_OT_clear_pins,
    SHAPESPACE_OT_drag_pins,
    SHAPESPACE_OT_mirror_pins,
    SHAPESPACE_OT_remove_pin,
    SHAPESPACE_OT_solve_pins,
)
