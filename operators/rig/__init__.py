"""Operators: Shape-key rig tools: check, key sliders, in-betweens and combination shapes (thesis 3.3); symmetry
(mirror map, mirror / split / combine / update mirrored shapes)."""
from .add_combination import SHAPESPACE_OT_add_combination
from .add_inbetween import SHAPESPACE_OT_add_inbetween
from .build_mirror_map import SHAPESPACE_OT_build_mirror_map
from .check_rig import SHAPESPACE_OT_check_rig
from .combine_shapes import SHAPESPACE_OT_combine_shapes
from .key_sliders import SHAPESPACE_OT_key_sliders
from .mirror_shape import SHAPESPACE_OT_mirror_shape
from .split_shape import SHAPESPACE_OT_split_shape
from .update_mirrored import SHAPESPACE_OT_update_mirrored

classes = (
    SHAPESPACE_OT_add_combination,
    SHAPESPACE_OT_add_inbetween,
    SHAPESPACE_OT_check_rig,
    SHAPESPACE_OT_key_sliders,
    SHAPESPACE_OT_build_mirror_map,
    SHAPESPACE_OT_mirror_shape,
    SHAPESPACE_OT_split_shape,
    SHAPESPACE_OT_combine_shapes,
    SHAPESPACE_OT_update_mirrored,
)
