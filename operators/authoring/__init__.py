"""Operators: Rig authoring ▸ Transfer Shapes (model transfer, thesis 3.4.1)."""
from .add_landmark_pair import SHAPESPACE_OT_add_landmark_pair
from .clear_landmark_pairs import SHAPESPACE_OT_clear_landmark_pairs
from .clear_registration_preview import SHAPESPACE_OT_clear_registration_preview
from .named_landmarks import (
    SHAPESPACE_OT_clear_named_landmarks,
    SHAPESPACE_OT_mirror_named_landmarks,
    SHAPESPACE_OT_place_named_landmark,
    SHAPESPACE_OT_use_named_landmarks,
)
from .preview_registration import SHAPESPACE_OT_preview_registration
from .propose_landmarks import SHAPESPACE_OT_propose_landmarks
from .remove_landmark_pair import SHAPESPACE_OT_remove_landmark_pair
from .transfer_examples import SHAPESPACE_OT_add_transfer_example, SHAPESPACE_OT_remove_transfer_example
from .transfer_parts import SHAPESPACE_OT_find_transfer_parts, SHAPESPACE_OT_select_transfer_part
from .transfer_shapes import SHAPESPACE_OT_transfer_shapes

classes = (
    SHAPESPACE_OT_add_landmark_pair,
    SHAPESPACE_OT_clear_landmark_pairs,
    SHAPESPACE_OT_clear_registration_preview,
    SHAPESPACE_OT_preview_registration,
    SHAPESPACE_OT_propose_landmarks,
    SHAPESPACE_OT_remove_landmark_pair,
    SHAPESPACE_OT_transfer_shapes,
    SHAPESPACE_OT_add_transfer_example,
    SHAPESPACE_OT_remove_transfer_example,
    SHAPESPACE_OT_find_transfer_parts,
    SHAPESPACE_OT_select_transfer_part,
    SHAPESPACE_OT_place_named_landmark,
    SHAPESPACE_OT_mirror_named_landmarks,
    SHAPESPACE_OT_clear_named_landmarks,
    SHAPESPACE_OT_use_named_landmarks,
)
