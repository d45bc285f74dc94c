"""Operators: Face-space tools (thesis 3.7, ch. 6, 9)."""
from .analyse_rig import SHAPESPACE_OT_analyse_rig
from .compression_report import SHAPESPACE_OT_compression_report
from .convert_rig import SHAPESPACE_OT_convert_rig
from .fill_between import SHAPESPACE_OT_fill_between
from .find_implausible_frames import SHAPESPACE_OT_find_implausible_frames
from .go_to_frame import SHAPESPACE_OT_go_to_frame
from .inpaint_gap import SHAPESPACE_OT_inpaint_gap
from .learn_face_prior import SHAPESPACE_OT_learn_face_prior
from .make_convex import SHAPESPACE_OT_make_convex

classes = (
    SHAPESPACE_OT_analyse_rig,
    SHAPESPACE_OT_compression_report,
    SHAPESPACE_OT_convert_rig,
    SHAPESPACE_OT_fill_between,
    SHAPESPACE_OT_find_implausible_frames,
    SHAPESPACE_OT_go_to_frame,
    SHAPESPACE_OT_inpaint_gap,
    SHAPESPACE_OT_learn_face_prior,
    SHAPESPACE_OT_make_convex,
)
