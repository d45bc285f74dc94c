"""Operators: Shape-key rig tools: check, key sliders, in-betweens and combination shapes (thesis 3.3); symmetry
(mirror map, mirror / split / combine / update mirrored shapes); control sets of any face rig (issue #25: propose,
add bones / properties, remove, enable, bounds, clear, mirror)."""
from .add_combination import SHAPESPACE_OT_add_combination
from .add_control_bones import SHAPESPACE_OT_add_control_bones
from .add_control_property import SHAPESPACE_OT_add_control_property
from .add_inbetween import SHAPESPACE_OT_add_inbetween
from .build_mirror_map import SHAPESPACE_OT_build_mirror_map
from .check_rig import SHAPESPACE_OT_check_rig
from .clear_controls import SHAPESPACE_OT_clear_controls
from .combine_shapes import SHAPESPACE_OT_combine_shapes
from .key_sliders import SHAPESPACE_OT_key_sliders
from .mirror_controls import SHAPESPACE_OT_mirror_controls
from .mirror_shape import SHAPESPACE_OT_mirror_shape
from .propose_controls import SHAPESPACE_OT_propose_controls
from .remove_control import SHAPESPACE_OT_remove_control
from .set_control_bounds import SHAPESPACE_OT_set_control_bounds
from .split_shape import SHAPESPACE_OT_split_shape
from .toggle_control import SHAPESPACE_OT_toggle_control
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
    SHAPESPACE_OT_propose_controls,
    SHAPESPACE_OT_add_control_bones,
    SHAPESPACE_OT_add_control_property,
    SHAPESPACE_OT_remove_control,
    SHAPESPACE_OT_toggle_control,
    SHAPESPACE_OT_set_control_bounds,
    SHAPESPACE_OT_clear_controls,
    SHAPESPACE_OT_mirror_controls,
)
