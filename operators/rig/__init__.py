"""Operators: Shape-key rig tools: check, key sliders, in-betweens and combination shapes (thesis 3.3)."""
from .add_combination import SHAPESPACE_OT_add_combination
from .add_inbetween import SHAPESPACE_OT_add_inbetween
from .check_rig import SHAPESPACE_OT_check_rig
from .key_sliders import SHAPESPACE_OT_key_sliders

classes = (
    SHAPESPACE_OT_add_combination,
    SHAPESPACE_OT_add_inbetween,
    SHAPESPACE_OT_check_rig,
    SHAPESPACE_OT_key_sliders,
)
