"""Any face rig in Blender (issue #25): its channels as a control set, evaluated through the depsgraph."""
from .capture import capture_weights, retarget_capture_onto_rig, sample_vertices
from .channels import Binding, bind, bone_channel, bone_channels, control_set, property_channel, shape_key_channel
from .drag import RigDrag
from .evaluate import RigEvaluator, apply_controls, read_controls, solve_pins
from .live import RigLivePipeline, build_rig_pipeline
from .take import (
                   TakeOutcome,
                   compute_take,
                   rest_controls,
                   restore_previous,
                   retarget_take,
                   shape_key_targets,
                   write_take,
)

__all__ = ["Binding", "RigDrag", "RigEvaluator", "RigLivePipeline", "TakeOutcome", "apply_controls", "bind",
           "bone_channel", "bone_channels", "build_rig_pipeline", "capture_weights", "compute_take", "control_set",
           "property_channel", "read_controls", "rest_controls", "restore_previous", "retarget_capture_onto_rig",
           "retarget_take", "sample_vertices", "shape_key_channel", "shape_key_targets", "solve_pins", "write_take"]
