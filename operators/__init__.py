"""Operators: poll → read via the bridge → core → write via the bridge → report."""
import bpy

from .add_combination import SHAPESPACE_OT_add_combination
from .add_inbetween import SHAPESPACE_OT_add_inbetween
from .add_landmark import SHAPESPACE_OT_add_landmark
from .add_pin import SHAPESPACE_OT_add_pin
from .check_rig import SHAPESPACE_OT_check_rig
from .clear_pins import SHAPESPACE_OT_clear_pins
from .discard_retarget import SHAPESPACE_OT_discard_retarget
from .drag_pins import SHAPESPACE_OT_drag_pins
from .analyse_rig import SHAPESPACE_OT_analyse_rig
from .compression_report import SHAPESPACE_OT_compression_report
from .convert_rig import SHAPESPACE_OT_convert_rig
from .fill_between import SHAPESPACE_OT_fill_between
from .find_implausible_frames import SHAPESPACE_OT_find_implausible_frames
from .go_to_frame import SHAPESPACE_OT_go_to_frame
from .inpaint_gap import SHAPESPACE_OT_inpaint_gap
from .learn_face_prior import SHAPESPACE_OT_learn_face_prior
from .psd_confidence import SHAPESPACE_OT_psd_confidence
from .key_sliders import SHAPESPACE_OT_key_sliders
from .landmarks_from_shapes import SHAPESPACE_OT_landmarks_from_shapes
from .psd_add_example import SHAPESPACE_OT_psd_add_example
from .psd_add_target import SHAPESPACE_OT_psd_add_target
from .psd_apply_example import SHAPESPACE_OT_psd_apply_example
from .psd_bake import SHAPESPACE_OT_psd_bake
from .psd_bake_cache import SHAPESPACE_OT_psd_bake_cache
from .psd_mirror_example import SHAPESPACE_OT_psd_mirror_example
from .psd_move_example import SHAPESPACE_OT_psd_move_example
from .psd_record_targets import SHAPESPACE_OT_psd_record_targets
from .psd_remove_example import SHAPESPACE_OT_psd_remove_example
from .psd_update import SHAPESPACE_OT_psd_update
from .make_convex import SHAPESPACE_OT_make_convex
from .remove_mapping import SHAPESPACE_OT_remove_mapping
from .remove_pin import SHAPESPACE_OT_remove_pin
from .retarget import SHAPESPACE_OT_retarget
from .set_mapping import SHAPESPACE_OT_set_mapping
from .solve_pins import SHAPESPACE_OT_solve_pins
from .suggest_key_poses import SHAPESPACE_OT_suggest_key_poses

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
    SHAPESPACE_OT_psd_add_example,
    SHAPESPACE_OT_psd_apply_example,
    SHAPESPACE_OT_psd_remove_example,
    SHAPESPACE_OT_psd_update,
    SHAPESPACE_OT_psd_bake,
    SHAPESPACE_OT_psd_bake_cache,
    SHAPESPACE_OT_psd_move_example,
    SHAPESPACE_OT_psd_mirror_example,
    SHAPESPACE_OT_psd_add_target,
    SHAPESPACE_OT_psd_record_targets,
    SHAPESPACE_OT_retarget,
    SHAPESPACE_OT_discard_retarget,
    SHAPESPACE_OT_set_mapping,
    SHAPESPACE_OT_remove_mapping,
    SHAPESPACE_OT_add_landmark,
    SHAPESPACE_OT_landmarks_from_shapes,
    SHAPESPACE_OT_suggest_key_poses,
    SHAPESPACE_OT_analyse_rig,
    SHAPESPACE_OT_compression_report,
    SHAPESPACE_OT_convert_rig,
    SHAPESPACE_OT_make_convex,
    SHAPESPACE_OT_fill_between,
    SHAPESPACE_OT_find_implausible_frames,
    SHAPESPACE_OT_go_to_frame,
    SHAPESPACE_OT_inpaint_gap,
    SHAPESPACE_OT_learn_face_prior,
    SHAPESPACE_OT_psd_confidence,
)

register, unregister = bpy.utils.register_classes_factory(classes)
