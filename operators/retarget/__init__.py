"""Operators: Retargeting / expression cloning (thesis 3.5, ch. 5)."""
from .add_landmark import SHAPESPACE_OT_add_landmark
from .discard_retarget import SHAPESPACE_OT_discard_retarget
from .landmarks_from_shapes import SHAPESPACE_OT_landmarks_from_shapes
from .remove_mapping import SHAPESPACE_OT_remove_mapping
from .retarget_controls import SHAPESPACE_OT_retarget_controls
from .run_retarget import SHAPESPACE_OT_retarget
from .set_mapping import SHAPESPACE_OT_set_mapping
from .suggest_key_poses import SHAPESPACE_OT_suggest_key_poses

classes = (
    SHAPESPACE_OT_add_landmark,
    SHAPESPACE_OT_discard_retarget,
    SHAPESPACE_OT_landmarks_from_shapes,
    SHAPESPACE_OT_remove_mapping,
    SHAPESPACE_OT_retarget,
    SHAPESPACE_OT_retarget_controls,
    SHAPESPACE_OT_set_mapping,
    SHAPESPACE_OT_suggest_key_poses,
)
