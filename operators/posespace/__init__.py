"""Operators: Pose-space correctives: PSD, Shape-by-Example, weighted PSD (thesis ch. 7-8)."""
from .add_example import SHAPESPACE_OT_psd_add_example
from .add_target import SHAPESPACE_OT_psd_add_target
from .apply_example import SHAPESPACE_OT_psd_apply_example
from .apply_post_deform import SHAPESPACE_OT_apply_post_deform
from .bake import SHAPESPACE_OT_psd_bake
from .bake_cache import SHAPESPACE_OT_psd_bake_cache
from .capture_final_shape import SHAPESPACE_OT_capture_final_shape
from .confidence import SHAPESPACE_OT_psd_confidence
from .mirror_example import SHAPESPACE_OT_psd_mirror_example
from .move_example import SHAPESPACE_OT_psd_move_example
from .push_sculpt_masked import SHAPESPACE_OT_push_sculpt_masked
from .record_targets import SHAPESPACE_OT_psd_record_targets
from .reinvert_all import SHAPESPACE_OT_reinvert_all
from .reinvert_example import SHAPESPACE_OT_reinvert_example
from .remove_example import SHAPESPACE_OT_psd_remove_example
from .update import SHAPESPACE_OT_psd_update

classes = (
    SHAPESPACE_OT_psd_add_example,
    SHAPESPACE_OT_psd_add_target,
    SHAPESPACE_OT_psd_apply_example,
    SHAPESPACE_OT_psd_bake,
    SHAPESPACE_OT_psd_bake_cache,
    SHAPESPACE_OT_psd_confidence,
    SHAPESPACE_OT_psd_mirror_example,
    SHAPESPACE_OT_psd_move_example,
    SHAPESPACE_OT_psd_record_targets,
    SHAPESPACE_OT_psd_remove_example,
    SHAPESPACE_OT_psd_update,
    SHAPESPACE_OT_capture_final_shape,
    SHAPESPACE_OT_reinvert_example,
    SHAPESPACE_OT_reinvert_all,
    SHAPESPACE_OT_push_sculpt_masked,
    SHAPESPACE_OT_apply_post_deform,
)
