"""The live-capture session: receiver → main-thread timer → solve → sliders and bones (→ take).

Threads never touch Blender.  Everything that does runs on the main thread
from :func:`tick`, registered with ``bpy.app.timers``: it drains the
receiver's mailbox, runs every new frame through calibration and smoothing
(so the One-Euro filter sees each sample), keys the scene frames a recording
completes, and writes the newest frame's solution to the rig.

Module state is one explicit object, :data:`RUNTIME` (a :class:`LiveRuntime`):
the running session, if any, and the last status message.  It holds names and
numbers, never Blender datablocks (except the bound channels of a rig solved onto
its controls, :mod:`bridge.rig.live`, checked every frame); the target is looked up by name every tick
(undo-safe), and a timer that finds it deleted stops the session with a
message.  :func:`shutdown` (add-on unregister, a new file being opened) stops
everything: recording finished (the take so far kept), socket closed, thread
joined, timer removed.
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ...core.errors import ErrorCode
from ...core.live import SceneResampler, format_timecode
from ...core.result import ShapeSpaceError
from ..rig import live as rig_live
from . import recording
from .facecap import facecap_decoder
from .receivers import Mailbox, UdpReceiver, ifacialmocap_decoder, llf_decoder
from .rig import Pipeline, build_pipeline

__all__ = ["TICK_SECONDS", "STALL_SECONDS", "SOURCES", "LiveStatus", "LiveRuntime", "RUNTIME", "start", "stop",
           "calibrate", "record", "stop_recording", "status", "tick", "shutdown", "register", "unregister",
           "is_running", "is_recording"]

#: Timer interval: well under one 60 Hz frame, so a frame waits at most this long for the main thread.
TICK_SECONDS = 1.0 / 240.0
#: No datagram for this long: the status says the source stopped sending.
STALL_SECONDS = 1.0
#: Source type → (label, decoder factory).
SOURCES = {"LLF": ("Live Link Face", llf_decoder), "FACECAP": ("Face Cap", facecap_decoder),
           "IFACIALMOCAP": ("iFacialMocap", ifacialmocap_decoder)}
#: Each source's standard UDP port (used when the settings say port 0).
DEFAULT_PORTS = {"LLF": 11111, "FACECAP": 8080, "IFACIALMOCAP": 49983}
_REDRAW_SECONDS = 0.25
_TIMINGS = 600


@dataclass
class LiveStatus:
    """What the Live panel shows.

    Attributes
    ----------
    running : bool
    message : str
        The current state in words (waiting, receiving, stopped and why).
    source, target : str
    port : int
    packets_per_second : float
        Datagrams over the last second.
    last_frame_age : float or None
        Seconds since the last datagram.
    frames, malformed, late, dropped, skipped : int
        Accepted frames; undecodable datagrams; duplicated / reordered frames dropped; frames the source's
        counter shows lost on the way; frames never shown because a newer one arrived in the same tick.
    work_ms_p50, work_ms_p99 : float
        ShapeSpace's own work per applied frame (solve and writes), over the last 600 frames.
    latency_ms_p50 : float
        Receipt of a datagram to its frame written on the rig.
    recording : bool
    take : str
    take_frames : int
    calibrated : bool
    implausible : int
        Datagrams refused for a weight or angle beyond the plausibility limits (decoded, but absurd).
    error : str
        Why the last datagram was refused ('' for none).
    budget_hits : int
        Solving onto a rig's controls: frames whose budget of rig evaluations ran out before they converged.
    solver : str
        Solving onto a rig's controls: budget, evaluations per frame and budget hits in words ('' otherwise).
    """

    running: bool = False
    message: str = "stopped"
    source: str = ""
    target: str = ""
    port: int = 0
    packets_per_second: float = 0.0
    last_frame_age: float | None = None
    frames: int = 0
    malformed: int = 0
    late: int = 0
    dropped: int = 0
    skipped: int = 0
    work_ms_p50: float = float("nan")
    work_ms_p99: float = float("nan")
    latency_ms_p50: float = float("nan")
    recording: bool = False
    take: str = ""
    take_frames: int = 0
    calibrated: bool = False
    implausible: int = 0
    error: str = ""
    budget_hits: int = 0
    solver: str = ""


class _Session:
    """One running receiver and what it drives (names and numbers only)."""

    def __init__(self, label: str, port: int, receiver: UdpReceiver, mailbox: Mailbox, pipeline: Pipeline) -> None:
        self.label, self.port = label, port
        self.receiver, self.mailbox, self.pipeline = receiver, mailbox, pipeline
        self.latest_raw = None
        self.recorder = None
        self.resampler = None
        self.take_base = "Take"
        self.skipped = 0
        self.applied = 0
        self.work = deque(maxlen=_TIMINGS)
        self.latency = deque(maxlen=_TIMINGS)
        self.last_redraw = 0.0
        self.message = f"waiting for {label} on port {port}"

    def step(self) -> str:
        """One timer tick; returns '' or why the session must stop."""
        frames = self.mailbox.drain()
        if not frames:
            return self._idle()
        t0 = time.perf_counter()
        samples = []
        vector = None
        solved = None
        for f in frames:
            raw = f.vector()
            self.latest_raw = raw
            vector = self.pipeline.process(raw, f.time)
            if self.resampler is None:
                continue
            last = self.resampler.last_time
            if last is not None and f.time < last:
                solved = self._record(samples, vector) or solved
                samples = []
                self._end_take("the source's clock restarted: the take was ended")
            else:
                if self.resampler.is_jump(f.time):
                    solved = self._record(samples, vector) or solved
                    samples = []
                    self._next_take(f.time - last)
                if self.resampler is not None:
                    samples += self.resampler.push(f.time, vector)
        self.skipped += len(frames) - 1
        solved = self._record(samples, vector) or solved
        if solved is None:
            solved = self.pipeline.solve(vector)
        why = self.pipeline.write(*solved)
        if why:
            return why
        done = time.perf_counter()
        self.applied += 1
        self.work.append((done - t0) * 1e3)
        self.latency.append((time.monotonic() - frames[-1].arrival) * 1e3)
        if not self.message.startswith("the source's clock"):
            self.message = f"receiving from {frames[-1].subject or self.label}"
        self._redraw()
        return ""

    def _record(self, samples: list, vector) -> tuple | None:
        """Solve and key ``samples`` into the take; returns the solution of ``vector`` if one was among them."""
        if not samples or self.recorder is None:
            return None
        recorded, solved = [], None
        for frame, v in samples:
            sliders, bones = self.pipeline.solve(v)
            recorded.append((frame, sliders, bones))
            if np.array_equal(v, vector):
                solved = (sliders, bones)
        why = self.recorder.add(recorded)
        if why:
            self._end_take(why)
        return solved

    def _idle(self) -> str:
        if bpy.data.objects.get(self.pipeline.target) is None:
            return f"the target {self.pipeline.target!r} was deleted"
        snap = self.mailbox.snapshot()
        if snap["age"] is None:
            self.message = f"waiting for {self.label} on port {self.port}"
        elif snap["age"] > STALL_SECONDS:
            self.message = f"no data for {snap['age']:.0f} s: the source stopped sending"
        self._redraw()
        return ""

    def _redraw(self) -> None:
        now = time.monotonic()
        if now - self.last_redraw < _REDRAW_SECONDS:
            return
        self.last_redraw = now
        wm = bpy.context.window_manager
        for window in (wm.windows if wm is not None else ()):
            for area in window.screen.areas:
                if area.type == "VIEW_3D":
                    area.tag_redraw()

    def start_take(self, scene, name: str) -> str:
        rate = scene.render.fps / scene.render.fps_base
        self.take_base = name
        self.message = f"receiving from {self.label}"
        return self._open_take(rate, float(scene.frame_current))

    def _open_take(self, rate: float, start_frame: float) -> str:
        meta = dict(source=self.label, target=self.pipeline.target, method=self.pipeline.method,
                    start_timecode="", start_seconds=0.0, scene_fps=rate, start_frame=start_frame)
        make = getattr(self.pipeline, "take_recorder", recording.TakeRecorder)   # a rig's controls: its own keys
        self.recorder = make(self.pipeline, recording.unique_take_name(self.take_base), meta)
        self.resampler = SceneResampler(rate, start_frame)
        return self.recorder.action

    def _next_take(self, jump: float) -> None:
        """The source clock jumped forward: end the take (kept, unplayed) and go on in a new one from the next
        scene frame, without keying the gap (:meth:`core.live.SceneResampler.is_jump`)."""
        rate, frame = self.resampler.rate, self.resampler.next_frame
        ended = self._end_take(play=False)
        self._open_take(rate, frame)
        self.message = (f"the source's clock jumped {jump:.3g} s forward: take {ended!r} ended, "
                        f"recording goes on in {self.recorder.action!r} from frame {frame:g}")

    def _end_take(self, why: str = "", play: bool = True) -> str:
        rec, res = self.recorder, self.resampler
        self.recorder = self.resampler = None
        if rec is None:
            return ""
        if res is not None and res.start_time is not None:
            rec.meta.update(start_seconds=res.start_time, start_timecode=format_timecode(res.start_time))
        name = rec.finish(complete=not why, play=play)
        if why:
            self.message = why
        return name

    def stop(self) -> str:
        """Finish any take, stop the receiver; returns the finished take's name ('' for none)."""
        try:
            return self._end_take()
        finally:
            self.receiver.stop()
            settle = getattr(self.pipeline, "settle", None)    # a rig pipeline: the verified controls stay shown
            if settle is not None:
                settle()


class LiveRuntime:
    """The live capture of this Blender process: at most one running session and the last message.

    The one module-level instance is :data:`RUNTIME`; it is the only state the live bridge keeps between
    timer ticks and it never holds Blender datablocks.
    """

    def __init__(self) -> None:
        self.session = None
        self.message = "stopped"


RUNTIME = LiveRuntime()


def _timer():
    return tick()


def is_running() -> bool:
    return RUNTIME.session is not None


def is_recording() -> bool:
    return RUNTIME.session is not None and RUNTIME.session.recorder is not None


def _loopback(address: str) -> bool:
    """Whether ``address`` only reaches this computer (127.0.0.0/8, localhost, ::1)."""
    return address.startswith("127.") or address in ("localhost", "::1")


def network_refusal(address: str, online_access: bool, override: bool) -> str | None:
    """Why listening on ``address`` is refused, or None: beyond this computer it needs Blender's online access
    (``bpy.app.online_access``).  ``override`` (``bpy.app.online_access_override``): Blender was started with
    ``--offline-mode`` or ``--online-mode``, which overrule the preference, so the way out is to restart."""
    if _loopback(address) or online_access:
        return None
    if override:
        return ("Blender was started with --offline-mode: restart it without that option to receive from a "
                "phone, or listen on 127.0.0.1 only")
    return ("Blender's online access is off (Preferences ▸ System ▸ Network ▸ Allow Online Access): allow it to "
            "receive from a phone, or listen on 127.0.0.1 only")


def _session() -> _Session:
    if RUNTIME.session is None:
        raise ShapeSpaceError("live capture is not running: press Start first", ErrorCode.LIVE_STATE)
    return RUNTIME.session


def start(scene, target) -> LiveStatus:
    """Build the pipeline for ``target`` from ``scene.shapespace_live``, open the port, start the thread and
    the timer.  Everything is validated before the socket opens."""
    if RUNTIME.session is not None:
        raise ShapeSpaceError("live capture is already running: stop it first", ErrorCode.LIVE_STATE)
    settings = scene.shapespace_live
    label, make_decoder = SOURCES[settings.source]
    address = (settings.address or "0.0.0.0").strip()
    refusal = network_refusal(address, getattr(bpy.app, "online_access", True),
                              getattr(bpy.app, "online_access_override", False))
    if refusal:
        raise ShapeSpaceError(refusal, ErrorCode.NETWORK)
    build = rig_live.build_rig_pipeline if settings.method == rig_live.METHOD else build_pipeline
    pipeline = build(scene, settings, target)
    mailbox = Mailbox()
    port = settings.port or DEFAULT_PORTS[settings.source]
    receiver = UdpReceiver(address, port, make_decoder(), mailbox, label)
    receiver.start()
    RUNTIME.session = _Session(label, receiver.port, receiver, mailbox, pipeline)
    RUNTIME.message = f"listening for {label} on {address}:{receiver.port}"
    if not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=0.0)
    return status()


def stop(message: str = "stopped") -> str:
    """Stop the session (a take being recorded is finished and kept); returns that take's name or ''."""
    s = RUNTIME.session
    RUNTIME.session = None
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)
    name = s.stop() if s is not None else ""
    RUNTIME.message = message + (f"; take {name!r} kept" if name and message != "stopped" else "")
    return name


def tick() -> float | None:
    """The timer: one step of the running session; returns the next interval, or None to stop the timer."""
    s = RUNTIME.session
    if s is None:
        return None
    try:
        why = s.step()
    except Exception as exc:  # noqa: BLE001 — a timer that raises is dropped silently by Blender: report it
        why = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ShapeSpaceError) else str(exc)
    if why:
        stop(f"live capture stopped: {why}")
        return None
    return TICK_SECONDS


def calibrate() -> None:
    """Make the newest received frame the actor's rest face and head pose."""
    s = _session()
    if s.latest_raw is None:
        raise ShapeSpaceError("no frame has been received yet: calibrate while the actor holds a neutral face",
                              ErrorCode.LIVE_STATE)
    s.pipeline.calibrate_to(s.latest_raw)


def record(scene, name: str = "Take") -> str:
    """Start recording a take (keys at the scene rate from the current frame); returns the take's name."""
    s = _session()
    if s.recorder is not None:
        raise ShapeSpaceError(f"already recording {s.recorder.action!r}", ErrorCode.LIVE_STATE)
    return s.start_take(scene, name)


def stop_recording(spacetime: bool = False, key_tolerance: float = 0.0) -> tuple:
    """Finish the take; optionally run the offline passes into ``<take> clean``.  Returns (take, clean or '')."""
    s = _session()
    if s.recorder is None:
        raise ShapeSpaceError("not recording", ErrorCode.LIVE_STATE)
    name = s._end_take()
    clean = ""
    if name and (spacetime or key_tolerance > 0):
        clean = recording.clean_take(name, spacetime, key_tolerance)
    return name, clean


def _percentile(values, q: float) -> float:
    return float(np.percentile(np.array(values), q)) if len(values) else float("nan")


def status() -> LiveStatus:
    """The current state for the panel (also when stopped: the last message)."""
    s = RUNTIME.session
    if s is None:
        return LiveStatus(message=RUNTIME.message)
    snap = s.mailbox.snapshot()
    rec = s.recorder
    return LiveStatus(True, s.message, s.label, s.pipeline.target, s.port, snap["rate"], snap["age"],
                      snap["frames"], snap["malformed"], snap["late"], snap["dropped"] + snap["overflow"], s.skipped,
                      _percentile(s.work, 50), _percentile(s.work, 99), _percentile(s.latency, 50),
                      rec is not None, rec.action if rec else "", rec.frames if rec else 0,
                      s.pipeline.neutral is not None, snap["implausible"], snap["error"],
                      getattr(s.pipeline, "budget_hits", 0), s.pipeline.counters() if hasattr(s.pipeline, "counters")
                      else "")


def shutdown(message: str = "stopped") -> None:
    """Stop everything (unregister, new file): take finished and kept, socket closed, thread joined, timer off."""
    if RUNTIME.session is not None or bpy.app.timers.is_registered(_timer):
        stop(message)


@persistent
def _before_load(*_):
    shutdown("stopped: another file was opened")


def register() -> None:
    if _before_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_before_load)


def unregister() -> None:
    shutdown("stopped: ShapeSpace was disabled")
    if _before_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_before_load)
