"""Any face rig in Blender (issue #25): its channels as a control set, evaluated through the depsgraph."""
from .channels import (Binding, bind, bone_channel, bone_channels, control_set, property_channel,
                       shape_key_channel)
from .evaluate import RigEvaluator, apply_controls, read_controls, solve_pins

__all__ = ["Binding", "RigEvaluator", "apply_controls", "bind", "bone_channel", "bone_channels", "control_set",
           "property_channel", "read_controls", "shape_key_channel", "solve_pins"]
