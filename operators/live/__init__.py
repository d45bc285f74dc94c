"""Operators: live capture (issue #14) — start, stop, calibrate, record, stop recording, takes."""
from .calibrate import SHAPESPACE_OT_live_calibrate
from .play_take import SHAPESPACE_OT_live_play_take
from .record import SHAPESPACE_OT_live_record
from .remove_take import SHAPESPACE_OT_live_remove_take
from .start import SHAPESPACE_OT_live_start
from .stop import SHAPESPACE_OT_live_stop
from .stop_recording import SHAPESPACE_OT_live_stop_recording

classes = (
    SHAPESPACE_OT_live_start,
    SHAPESPACE_OT_live_stop,
    SHAPESPACE_OT_live_calibrate,
    SHAPESPACE_OT_live_record,
    SHAPESPACE_OT_live_stop_recording,
    SHAPESPACE_OT_live_play_take,
    SHAPESPACE_OT_live_remove_take,
)
