"""Live capture in Blender (issue #14): receivers, the main-thread timer, bones and recorded takes.

- :mod:`.receivers` — a UDP socket and a background thread per source that only decodes datagrams into a
  mailbox (Live Link Face v6, iFacialMocap);
- :mod:`.facecap` — Face Cap's OSC stream through python-osc;
- :mod:`.rig` — the per-frame pipeline built once from the rigs (copy, learned matrix, geometric
  solve-through a template; head / neck / eye bones) and its writes;
- :mod:`.recording` — takes: actions keyed as frames arrive, their metadata, the offline clean-up passes;
- :mod:`.session` — start / stop / calibrate / record and the ``bpy.app.timers`` tick (the only module state
  is :data:`session.RUNTIME`).
"""
from . import recording, rig, session
from .recording import TAKE_PROP, is_take, play_take, remove_take, take_info, takes
from .session import (
                      RUNTIME,
                      SOURCES,
                      LiveStatus,
                      calibrate,
                      is_recording,
                      is_running,
                      record,
                      register,
                      start,
                      status,
                      stop,
                      stop_recording,
                      tick,
                      unregister,
)

__all__ = ["recording", "rig", "session", "TAKE_PROP", "is_take", "play_take", "remove_take", "take_info", "takes",
           "RUNTIME", "SOURCES", "LiveStatus", "calibrate", "is_recording", "is_running", "record", "register",
           "start", "status", "stop", "stop_recording", "tick", "unregister"]
