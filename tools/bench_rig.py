"""Any-rig benchmark (issue #25): pin solves onto bone-, driver- and hybrid-driven heads, checked by Blender.

Rigs (built by ``tests/bridge/rigs.py`` from Blender's own parts on shared heads):

- ``hybrid``: facecap's head (2,694 vertices) + a weighted jaw bone hinged in front of the ears (a static head
  bone holds the rest of the weights) + six ARKit shape keys (8 channels);
- ``driver``: facecap's head driven by control bones and a custom property through drivers (nonlinear
  expressions, an in-between; 5 channels);
- ``rigify``: facecap's head with Rigify's own face (the human meta-rig cut to head and face, its face bones seated
  on the head's named landmarks ``tools/landmarks/facecap.json``, generated, automatic weights; 29 channels:
  quaternion jaw, lip/brow/lid/chin locations in 3D);
- ``hybrid_ict``: ICT FaceKit's head (26,719 vertices) + a weighted jaw bone + every one of its 57 shape keys
  that moves (59 channels);
- ``hybrid_ict150``: the same + 30 game-rig face bones with their location channels (149 channels) — the size the
  speed goal names (~150 channels on a 27k-vertex head); only its first use (``rig_first_use_*``,
  ``rig_check_s``, ``rig_eval_ms``) is measured.

Metrics per rig ``<rig>``:

- ``rig_drag_pin_err_max_<rig>``: random control poses inside the bounds are evaluated by Blender; 5–20 of their
  evaluated vertices (pins spread over the channels) are the targets of a drag from the rest pose; after the
  release the rig is evaluated again by the depsgraph; the largest pin distance over all poses, divided by the
  evaluated head's bounding-box diagonal.  Goal ≤ 1e-3.
  The drag is the pin-and-drag session (``bridge/rig/drag.py``, :class:`RigDrag`) as a user makes it: ``begin``
  on the pins at the rest pose, :data:`PATH_MOVES` mouse moves along the straight path from the pins to their
  targets (a real drag is a continuous mouse path, not one jump: a single jump from rest stopped in a local
  minimum of the driver rig's ``sin`` driver on 2 of 10 poses), then ``release`` (no keys) — which settles when
  the last move stopped short (moves defer Jacobian refreshes).  What is measured is what the user gets at
  release.
- ``rig_drag_overhead_ms_<rig>``: a drag toward a random pose's pins in 20 small mouse moves (each 1/20 of the
  way, every one a :meth:`RigDrag.move`, the first one computing the Jacobian); per move, the move's wall time
  minus Blender's own re-evaluation of the rig measured in the same loop (the previous controls written and
  evaluated untimed, then the move's controls written and the depsgraph updated, timed); the median of those
  paired differences, in ms.  Goal ≤ 3 ms.  ``rig_drag_move_ms_median_<rig>`` and
  ``rig_drag_reeval_ms_median_<rig>``: the medians of the two; ``rig_drag_settle_ms_<rig>``: the
  :meth:`RigDrag.settle` after the 20th move (the refresh work the moves deferred: what an idle moment or the
  release costs); ``rig_drag_overhead_cpu_ms_<rig>``: the same paired median in process CPU time (all of
  Blender's threads; less sensitive to a loaded machine than wall time).
- ``rig_first_use_s_<rig>``: wall time of the first Jacobian at the rest pose, median over repetitions: shape-key
  slider and bone channel columns analytic where they apply (linear-blend armature after the keys, bones without
  constraints but local limits, ``bridge/rig/analytic.py``; building that path — vertex groups, key deltas — is
  included), every other channel by finite differences (one depsgraph update per channel);
  ``rig_first_use_fd_s_<rig>`` the same Jacobian by finite differences only (what the first use cost before the
  analytic paths); ``rig_first_use_ms_per_channel_<rig>`` the first use per channel;
  ``rig_first_use_fd_columns_reason_<rig>`` why some columns are still finite differences (empty reason: none);
  ``rig_check_s_<rig>`` the refusal checks and natural-scale probe (two updates per channel).
- ``rig_solve_s_median_<rig>``: a whole recovery drag (begin — checks, probe — its moves and its release),
  median over poses;
  ``rig_eval_ms_<rig>``: one evaluation of the rig after a channel changed (write controls, depsgraph update,
  read), median.
- ``rig_solve_ok_frac_<rig>``: fraction of solves that reported OK.

Per-frame retarget onto the rig's controls (``bridge/rig/take.py``), for ``hybrid``, ``driver`` and ``rigify``:

- ``rig_retarget_self_rms_<rig>``: random smooth control curves (40 frames; 30 with ``--quick``) evaluated by
  Blender are the take (its surface at pins spread over the channels plus every 20th vertex); it is retargeted
  onto the same rig and keyed (key tolerance 1e-5 of the diagonal); the written actions are played by the
  depsgraph frame by frame and the RMS distance of the whole evaluated surface to the take's, over every vertex
  and frame, divided by the diagonal.  Goal ≤ 1e-3.  ``rig_retarget_evals_per_frame_<rig>``: rig evaluations per
  frame of that retarget.
- ``rig_live_total_ms_p50_<rig>`` / ``rig_live_total_ms_p99_<rig>`` (``hybrid``, ``driver``, ``rigify``): live
  solve-through onto the rig's stored controls (``bridge/rig/live.py``), end to end per packet as
  ``tools/bench_live.py`` measures it: the shipped Live Link Face recording (328 packets, repeated) decoded,
  calibrated, played through the face's keys, solved onto the controls within the per-frame budget, written, and
  the depsgraph evaluated (``view_layer.update``).  Goal p99 ≤ 16.7 ms.  ``rig_live_cpu_ms_p99_<rig>`` the same
  in the main thread's CPU time; ``rig_live_budget_<rig>`` the evaluations per frame fixed at Start,
  ``rig_live_evals_per_frame_<rig>`` those used, ``rig_live_budget_hit_frac_<rig>`` the fraction of frames that ran
  out of budget (the rig cannot follow the capture exactly: Rigify's bones are not the head's ARKit keys),
  ``rig_live_redisplay_frac_<rig>`` the fraction whose written controls Blender evaluated once more (the last
  evaluation was a refused trial or a Jacobian column refresh).  Wall time is at the mercy of the machine's load:
  ``rig_live_reeval_ms_p50_<rig>`` / ``rig_live_reeval_ms_p99_<rig>`` are Blender's own re-evaluation of each
  packet's control change measured in the same loop (the previous controls written and evaluated untimed, then the
  new ones written and the depsgraph updated, timed) — the floor of any frame that moves the rig.
  The packet's split, timed by Blender's ``depsgraph_update_pre`` / ``_post`` handlers:
  ``rig_live_blender_eval_ms_p50_<rig>`` / ``_p99_<rig>`` Blender's depsgraph evaluations inside the packet (wall),
  ``rig_live_own_ms_p50_<rig>`` / ``_p99_<rig>`` the rest (ShapeSpace's decode, targets, step, writes; wall),
  ``rig_live_own_cpu_ms_p99_<rig>`` the rest in main-thread CPU time, ``rig_live_depsgraph_updates_mean_<rig>`` /
  ``_max_<rig>`` Blender's evaluations per packet.  ``…_1core_<rig>`` (``rig_live_total_ms_p50/p99``,
  ``rig_live_blender_eval_ms_p99``, ``rig_live_reeval_ms_p50/p99``): one more pass over the packets with every
  thread of the process pinned to one core (Linux ``sched_setaffinity``; on a VM whose idle vCPUs are slow to
  wake, Blender's multithreaded evaluation can cost more on two cores than on one).
- ``rig_retarget_s_1640_rigify``: wall time of retargeting (solve, key reduction, keying) a 1,640-frame take of
  the Rigify face's own smooth curves.  Goal ≤ 60 s.  With ``--quick`` 160 frames are retargeted and the time
  scaled by 1640/160 (``rig_retarget_frames_measured_rigify`` and ``rig_retarget_s_1640_rigify_note`` say so).

Cross-rig (``bridge/rig/capture.py``), for ``hybrid`` (here: the jaw bone *instead of* ``jawOpen``, every other
ARKit key of the head a control) and ``rigify`` (its bench control set above):

- ``rig_cross_landmark_ratio_<rig>``: the shipped Live Link Face take (``assets/llf_fbhead``) retargeted onto the
  rig, played by Blender, its landmark error over the same take retargeted onto the head's shape-key version (the
  same head, its ARKit keys, the shape-key space-time route).  Both are measured against the performance itself:
  the take on the face it was captured with (FBHead, ``Live_Link_Face.blend``: the capture's weights on its keys,
  Eq. 3.1) — the question a retarget answers is how faithfully the target reproduces the actor's motion, and the
  shape-key head is the bar a rig should reach.  Landmarks: the peak vertex of each key both heads have, on each
  head (``core.retarget.peak_landmarks``); a landmark's motion is its displacement from rest in mm at a 30 cm head
  (``core.retarget.metrics.HEAD_MM``), FBHead's turned into the target's frame by the rotation that best aligns the
  two heads' rest landmarks (Umeyama); error: RMS over landmarks and frames.  Goal ≤ 1.2.  The key is the rig
  route's default (``perframe``, the CLI's with ``--controls``); ``rig_cross_rig_vs_shapekey_mm_<rig>`` is the
  rig's distance from the shape-key version (how much of the rig's error is the rig's own) and
  ``rig_cross_motion_mm_<rig>`` the RMS landmark motion of the take; ``rig_cross_worst_landmarks_<rig>_<route>``
  names the three landmarks (by their key) with the largest error.  ``rig_cross_landmark_mm_<rig>_<route>``,
  ``rig_cross_landmark_ratio_<rig>_<route>`` and ``rig_cross_s_<rig>_<route>`` for each route (``perframe``,
  ``spacetime``, ``cloning``); ``rig_cross_landmark_mm_shapekey_<rig>`` the reference.
  ``rig_cross_linear_ratio_<rig>`` is what the control set can express at all: the same ratio for the best bounded
  linear fit of the rig at rest (its Jacobian over every vertex; per frame the bounded least-squares fit of the
  controls to the same targets at the same vertex sample as the retarget, ``scipy.optimize.lsq_linear``) — a
  retarget near it is limited by the rig's controls, not by its solve; ``rig_cross_linear_sample_mm_<rig>`` that
  fit's RMS distance to the targets at the sample and ``rig_cross_sample_mm_<rig>_<route>`` the route's (played).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

import env
from bench_support import shared_data

FACECAP = "facecap/facecap_decoded.glb"
ICT = "ict_facekit/ict_facekit_expressions.glb"
LIVE_CSV = os.path.join(env.ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
#: Face bones added to the ICT hybrid for the ~150-channel rig (3 location channels each: 2 + 57 + 90 = 149).
FACE_BONES_150 = 30
#: Mouse moves of the recovery drag (``rig_drag_pin_err_max_<rig>``, module doc).
PATH_MOVES = 5


def _rigs(quick: bool) -> list:
    """(name, builder) of every rig whose head is available."""
    import rigs
    out = []
    facecap = shared_data(FACECAP, "facecap rigs")
    if facecap is not None:
        out += [("hybrid", lambda: rigs.hybrid_rig(facecap)), ("driver", lambda: rigs.driver_rig(facecap)),
                ("rigify", lambda: rigs.rigify_rig(facecap))]
    ict = shared_data(ICT, "ICT hybrid rig")
    if ict is not None:
        out.append(("hybrid_ict", lambda: rigs.hybrid_rig(ict, "ICTFace", keys=None, name="hybrid_ict")))
        out.append(("hybrid_ict150", lambda: rigs.hybrid_rig(ict, "ICTFace", keys=None, name="hybrid_ict150",
                                                             face_bones=FACE_BONES_150)))
    return out


def _measure(name: str, build, poses: int, reps: int) -> dict:
    import rigs
    from shapespace.bridge import rig as brig
    rig = build()
    rng = np.random.default_rng(25)
    c0 = brig.read_controls(rig.controls)
    diag = rigs.diagonal(rig.world_points())
    n = len(rig.controls)
    pins = rigs.pin_vertices(rig, int(np.clip(2 * n, 5, 20)), rng)
    first_use = _first_use(name, rig, pins, reps)
    errs, times, ok = [], [], 0
    for k in range(poses):
        print(f"bench rig: {name} pose {k + 1}/{poses}", file=sys.stderr)
        brig.apply_controls(rig.controls, rig.random_pose(rng))
        targets = rig.world_points()[pins]
        brig.apply_controls(rig.controls, c0)
        t0 = time.perf_counter()
        drag = brig.RigDrag(rig.mesh, rig.controls)
        start = drag.begin(pins)
        for m in range(1, PATH_MOVES + 1):
            drag.move(start + (targets - start) * m / PATH_MOVES)
        drag.release(autokey=False)
        times.append(time.perf_counter() - t0)
        ok += int(drag.result.status == 0)
        errs.append(float(np.linalg.norm(rig.world_points()[pins] - targets, axis=1).max() / diag))
        brig.apply_controls(rig.controls, c0)
    overhead, moves_ms, reeval_ms, settle_ms, overhead_cpu = _drag_overhead(rig, pins, rng)
    return {**first_use,
            f"rig_drag_pin_err_max_{name}": max(errs),
            f"rig_drag_overhead_ms_{name}": overhead,
            f"rig_drag_overhead_cpu_ms_{name}": overhead_cpu,
            f"rig_drag_move_ms_median_{name}": moves_ms,
            f"rig_drag_reeval_ms_median_{name}": reeval_ms,
            f"rig_drag_settle_ms_{name}": settle_ms,
            f"rig_solve_s_median_{name}": float(np.median(times)),
            f"rig_solve_ok_frac_{name}": ok / poses,
            f"rig_pins_{name}": int(len(pins))}


def _first_use(name: str, rig, pins, reps: int) -> dict:
    """``rig_first_use_s_<rig>`` and its companions (module doc), median over ``reps``."""
    from shapespace.bridge import rig as brig
    first, first_fd, check, evals = [], [], [], []
    for _ in range(reps):
        with brig.RigEvaluator(rig.mesh, rig.controls, pins, analytic=False) as ev:
            t0 = time.perf_counter()
            ev.jacobian(ev.c0)
            first_fd.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        with brig.RigEvaluator(rig.mesh, rig.controls, pins) as ev:
            t1 = time.perf_counter()
            ev.jacobian(ev.c0)
            t2 = time.perf_counter()
            reason = ev.analytic_reason
            c = ev.c0.copy()
            for k in range(6):                                    # alternate two poses: a real re-evaluation
                c[0] = ev.c0[0] + (ev.steps[0] if k % 2 else 0.0)
                t3 = time.perf_counter()
                ev.evaluate(c)
                evals.append(time.perf_counter() - t3)
        check.append(t1 - t0)
        first.append(t2 - t1)
    n = len(rig.controls)
    return {f"rig_first_use_s_{name}": float(np.median(first)),
            f"rig_first_use_fd_s_{name}": float(np.median(first_fd)),
            f"rig_first_use_ms_per_channel_{name}": float(np.median(first)) / n * 1e3,
            f"rig_first_use_fd_columns_reason_{name}": reason or "none: every column analytic",
            f"rig_check_s_{name}": float(np.median(check)),
            f"rig_eval_ms_{name}": float(np.median(evals)) * 1e3,
            f"rig_channels_{name}": n,
            f"rig_vertices_{name}": len(rig.mesh.data.vertices)}


def _measure_first_use(name: str, build, reps: int) -> dict:
    """First use only (module doc), for the ~150-channel rig."""
    import rigs
    rig = build()
    pins = rigs.pin_vertices(rig, 20, np.random.default_rng(25))
    print(f"bench rig: {name} first use ({len(rig.controls)} channels)", file=sys.stderr)
    return _first_use(name, rig, pins, reps)


def _drag_overhead(rig, pins, rng, moves: int = 20) -> tuple:
    """``rig_drag_overhead_ms_<rig>`` (module doc): (median paired difference, median move, median re-evaluation,
    the settle after the last move, median paired difference of process CPU time) in ms over ``moves`` mouse
    moves of a drag toward a random pose's pins."""
    import bpy

    from shapespace.bridge import rig as brig
    bindings = brig.bind(rig.controls)

    def write(c):
        for b, v in zip(bindings, c):
            b.set(v)

    c0 = brig.read_controls(rig.controls)
    brig.apply_controls(rig.controls, rig.random_pose(rng))
    targets = rig.world_points()[pins]
    brig.apply_controls(rig.controls, c0)
    drag = brig.RigDrag(rig.mesh, rig.controls)
    start = drag.begin(pins)
    diffs, move_t, reeval_t, cpu = [], [], [], []
    for k in range(1, moves + 1):
        before = drag.controls_now.copy()
        t0, c0_ = time.perf_counter(), time.process_time()
        drag.move(start + (targets - start) * k / moves)
        move_t.append(time.perf_counter() - t0)
        move_cpu = time.process_time() - c0_
        write(before)                                  # Blender's own re-evaluation of the same change
        bpy.context.view_layer.update()
        t0, c0_ = time.perf_counter(), time.process_time()
        write(drag.controls_now)
        bpy.context.evaluated_depsgraph_get().update()
        reeval_t.append(time.perf_counter() - t0)
        cpu.append(move_cpu - (time.process_time() - c0_))
        diffs.append(move_t[-1] - reeval_t[-1])
    t0 = time.perf_counter()
    drag.settle()
    settle = time.perf_counter() - t0
    drag.cancel()
    return (float(np.median(diffs)) * 1e3, float(np.median(move_t)) * 1e3, float(np.median(reeval_t)) * 1e3,
            settle * 1e3, float(np.median(cpu)) * 1e3)


def _self_take(rig, rng, frames: int) -> tuple:
    """A take made by the rig itself: (vertices, take surface (F, V, 3), frame numbers)."""
    import rigs
    values = rigs.smooth_take(rig, rng, frames)
    surface = rigs.take_surface(rig, values)
    return rigs.take_vertices(rig, rng), surface, np.arange(1, frames + 1)


def _measure_take(name: str, build, frames: int) -> dict:
    import rigs
    from shapespace.bridge import rig as brig
    rig = build()
    idx, surface, numbers = _self_take(rig, np.random.default_rng(31), frames)
    diag = rigs.diagonal(surface[0])
    print(f"bench rig: {name} self take, {frames} frames", file=sys.stderr)
    rep = brig.retarget_take(rig.mesh, rig.controls, idx, surface[:, idx], numbers, key_tolerance=1e-5 * diag)
    played = rigs.played_surface(rig, numbers)
    rms = float(np.sqrt(np.mean(np.sum((played - surface) ** 2, axis=-1)))) / diag
    return {f"rig_retarget_self_rms_{name}": rms, f"rig_retarget_evals_per_frame_{name}": rep.evaluations / frames,
            f"rig_retarget_self_status_{name}": rep.status.name.lower()}


def _measure_long_take(build, quick: bool) -> dict:
    """``rig_retarget_s_1640_rigify`` (module doc)."""
    import rigs
    from shapespace.bridge import rig as brig
    rig = build()
    frames = 160 if quick else 1640
    print(f"bench rig: rigify take of {frames} frames (evaluating it)", file=sys.stderr)
    idx, surface, numbers = _self_take(rig, np.random.default_rng(41), frames)
    diag = rigs.diagonal(surface[0])
    last = [0.0]

    def progress(fraction):
        if fraction - last[0] >= 0.1:
            last[0] = fraction
            print(f"bench rig: rigify take {fraction:.0%}", file=sys.stderr)

    t0 = time.perf_counter()
    rep = brig.retarget_take(rig.mesh, rig.controls, idx, surface[:, idx], numbers, key_tolerance=1e-5 * diag,
                             progress=progress)
    seconds = time.perf_counter() - t0
    out = {"rig_retarget_s_1640_rigify": seconds * 1640 / frames, "rig_retarget_frames_measured_rigify": frames,
           "rig_retarget_1640_status_rigify": rep.status.name.lower(),
           "rig_retarget_1640_rms_rigify": rep.rms / diag}
    if frames != 1640:
        out["rig_retarget_s_1640_rigify_note"] = (f"--quick: {frames} frames retargeted in {seconds:.2f} s, "
                                                  "scaled by 1640/{frames}".replace("{frames}", str(frames)))
    return out


class _EvalClock:
    """Blender's own depsgraph evaluations, timed by its ``depsgraph_update_pre`` / ``_post`` handlers: their
    count, wall and main-thread CPU time since :meth:`reset` (what of a packet is Blender's, not ShapeSpace's)."""

    def __init__(self):
        self.count, self.wall, self.cpu, self._t = 0, 0.0, 0.0, None

    def reset(self):
        self.count, self.wall, self.cpu = 0, 0.0, 0.0

    def pre(self, *_):
        self._t = (time.perf_counter(), time.thread_time())

    def post(self, *_):
        if self._t is not None:
            self.count += 1
            self.wall += time.perf_counter() - self._t[0]
            self.cpu += time.thread_time() - self._t[1]
            self._t = None


def _pin_threads(cpus) -> set:
    """Pin every thread of this process (Blender's evaluation threads included) to ``cpus``; returns the previous
    set (Linux; ``set()`` elsewhere, nothing done)."""
    if not hasattr(os, "sched_setaffinity"):
        return set()
    before = os.sched_getaffinity(0)
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), cpus)
        except OSError:                                   # a thread that just ended
            pass
    return before


def _live_loop(pipe, rig, packets, reps, clock) -> dict:
    """Per packet: total (decode → solve → write → ``view_layer.update``), its main-thread CPU, Blender's
    evaluations in it (count, wall, CPU), and Blender's own re-evaluation of the same control change alone."""
    import bpy

    from shapespace.bridge import rig as brig
    from shapespace.core.live import decode_llf
    bindings = brig.bind(rig.controls)

    def write(c):
        for b, v in zip(bindings, c):
            b.set(v)

    layer = bpy.context.view_layer
    out = {k: [] for k in ("total", "cpu", "evals", "eval_ms", "eval_cpu", "reeval")}
    for _ in range(reps):
        for data in packets:
            before = brig.read_controls(rig.controls)
            clock.reset()
            c0, t0 = time.thread_time(), time.perf_counter()
            frame = decode_llf(data, time.monotonic())
            why = pipe.write(*pipe.solve(pipe.process(frame.vector(), frame.time)))
            layer.update()
            t1, c1 = time.perf_counter(), time.thread_time()
            assert not why, why
            out["total"].append((t1 - t0) * 1e3)
            out["cpu"].append((c1 - c0) * 1e3)
            out["evals"].append(clock.count)
            out["eval_ms"].append(clock.wall * 1e3)
            out["eval_cpu"].append(clock.cpu * 1e3)
            after = brig.read_controls(rig.controls)          # Blender's own re-evaluation of the same change
            write(before)
            layer.update()
            write(after)
            t2 = time.perf_counter()
            layer.update()
            out["reeval"].append((time.perf_counter() - t2) * 1e3)
    return {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}


def _measure_live(name: str, build, reps: int) -> dict:
    """``rig_live_*_<rig>`` (module doc)."""
    from types import SimpleNamespace

    import bpy

    import live_replay
    from shapespace.bridge.rig import live as rig_live
    from shapespace.bridge.rig import stored
    rig = build()
    stored.add_entries_of(rig.mesh, rig.armature.name, rig.controls.channels)
    settings = SimpleNamespace(source="LLF", armature=None, smoothing=False, mirror=False)
    pipe = rig_live.build_rig_pipeline(bpy.context.scene, settings, rig.mesh)
    packets = [d for _, d in live_replay.llf_packets(LIVE_CSV)]
    clock = _EvalClock()
    handlers = bpy.app.handlers
    handlers.depsgraph_update_pre.append(clock.pre)
    handlers.depsgraph_update_post.append(clock.post)
    print(f"bench rig: {name} live, {reps} × {len(packets)} packets", file=sys.stderr)
    try:
        m = _live_loop(pipe, rig, packets, reps, clock)
        stats = dict(pipe.stats)
        print(f"bench rig: {name} live, one core, {len(packets)} packets", file=sys.stderr)
        cpus = _pin_threads({min(os.sched_getaffinity(0))}) if hasattr(os, "sched_getaffinity") else set()
        try:
            one = _live_loop(pipe, rig, packets, 1, clock) if cpus else None
        finally:
            if cpus:
                _pin_threads(cpus)
    finally:
        handlers.depsgraph_update_pre.remove(clock.pre)
        handlers.depsgraph_update_post.remove(clock.post)

    def pct(v, q):
        return float(np.percentile(v, q))

    own = m["total"] - m["eval_ms"]
    out = {f"rig_live_total_ms_p50_{name}": pct(m["total"], 50),
           f"rig_live_total_ms_p99_{name}": pct(m["total"], 99),
           f"rig_live_cpu_ms_p99_{name}": pct(m["cpu"], 99),
           f"rig_live_blender_eval_ms_p50_{name}": pct(m["eval_ms"], 50),
           f"rig_live_blender_eval_ms_p99_{name}": pct(m["eval_ms"], 99),
           f"rig_live_own_ms_p50_{name}": pct(own, 50),
           f"rig_live_own_ms_p99_{name}": pct(own, 99),
           f"rig_live_own_cpu_ms_p99_{name}": pct(m["cpu"] - m["eval_cpu"], 99),
           f"rig_live_depsgraph_updates_mean_{name}": float(np.mean(m["evals"])),
           f"rig_live_depsgraph_updates_max_{name}": int(np.max(m["evals"])),
           f"rig_live_reeval_ms_p50_{name}": pct(m["reeval"], 50),
           f"rig_live_reeval_ms_p99_{name}": pct(m["reeval"], 99),
           f"rig_live_budget_{name}": pipe.budget,
           f"rig_live_evals_per_frame_{name}": stats["evaluations_mean"],
           f"rig_live_budget_hit_frac_{name}": stats["budget_hits"] / max(stats["frames"], 1),
           f"rig_live_redisplay_frac_{name}": stats["redisplays"] / max(stats["frames"], 1)}
    if one is not None:
        out.update({f"rig_live_total_ms_p50_1core_{name}": pct(one["total"], 50),
                    f"rig_live_total_ms_p99_1core_{name}": pct(one["total"], 99),
                    f"rig_live_blender_eval_ms_p99_1core_{name}": pct(one["eval_ms"], 99),
                    f"rig_live_reeval_ms_p50_1core_{name}": pct(one["reeval"], 50),
                    f"rig_live_reeval_ms_p99_1core_{name}": pct(one["reeval"], 99)})
    return out


LLF_CSV = os.path.join("llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
CROSS_ROUTES = ("perframe", "spacetime", "cloning")


def _cross_rigs(facecap: str) -> list:
    """(name, builder) of the cross-rig cases: the hybrid with its jaw bone *instead of* ``jawOpen`` (every other
    ARKit key a control) and the Rigify face (its bench control set); both on facecap's head, whose ARKit keys
    are the shape-key version."""
    import rigs

    def hybrid():
        ob = rigs.load_head(facecap)
        keys = [kb.name for kb in ob.data.shape_keys.key_blocks[1:]
                if kb.name != "jawOpen" and np.abs(rigs._shape_delta(ob, kb.name)).max() > 0]
        return rigs.hybrid_rig(facecap, keys=keys)

    return [("hybrid", hybrid), ("rigify", lambda: rigs.rigify_rig(facecap))]


def _played(rig, frames, lm) -> np.ndarray:
    import bpy
    out = []
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        out.append(rig.world_points()[lm])
    return np.stack(out)


def _source_face(path: str) -> tuple:
    """The take's own face: FBHead's rest (n, 3), key deltas (k, n, 3) in world space and canonical key names."""
    import bpy

    from shapespace.bridge import assets
    from shapespace.bridge.shapekeys import read_blendshape_model
    from shapespace.core.names import canonical_name
    assets.load(path)
    ob = bpy.data.objects["FBHead"]
    model = read_blendshape_model(ob)
    M = np.array(ob.matrix_world)
    rest = model.neutral @ M[:3, :3].T + M[:3, 3]
    return rest, model.deltas @ M[:3, :3].T, [canonical_name(n) for n in model.names]


def _cross_truth(source, rig, names, W) -> tuple:
    """Landmarks of the keys both heads have and the performance's landmark motion on its own face, in mm at a 30
    cm head turned into the target's frame: ``(target landmarks (m,), motion (F, m, 3), key index per landmark)``."""
    import rigs
    from shapespace.bridge.shapekeys import read_blendshape_model
    from shapespace.core.authoring.registration import similarity
    from shapespace.core.names import canonical_name
    from shapespace.core.retarget import peak_landmarks
    from shapespace.core.retarget.metrics import HEAD_MM
    s_rest, s_deltas, s_names = source
    model = read_blendshape_model(rig.mesh)
    both = [(s_names.index(canonical_name(n)), model.names.index(n), k) for k, n in enumerate(names)
            if canonical_name(n) in s_names]
    lm_s, lm_t, used = peak_landmarks(s_deltas, model.deltas, [(i, j) for i, j, _ in both])
    col = {(i, j): k for i, j, k in both}
    keys = np.array([col[p] for p in used])
    t_rest = rig.world_points()
    _, R, _ = similarity(s_rest[lm_s], t_rest[lm_t], scaling=False)
    motion = np.einsum("fk,kmx->fmx", W[:, [col[p] for p in col]], s_deltas[[i for i, _ in col]][:, lm_s])
    motion = (motion @ R.T) * (HEAD_MM / rigs.diagonal(s_rest))
    return lm_t, motion, keys


def _rms(d) -> float:
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=-1))))


def _linear_bound(rig, names, W) -> tuple:
    """The control set's best bounded linear fit to a capture's targets (``rig_cross_linear_ratio_<rig>``, module
    doc): ``(the retarget's vertex sample (p,), fitted displacement of every vertex from rest (F, V, 3))``."""
    from scipy.optimize import lsq_linear

    from shapespace.bridge import rig as brig
    from shapespace.bridge.rig.capture import sample_vertices
    mesh = rig.mesh
    n_v = len(mesh.data.vertices)
    idx = sample_vertices(mesh, names)
    with brig.RigEvaluator(mesh, rig.controls, np.arange(n_v)) as ev:
        lo, hi = ev.controls.solve_bounds(ev.c0)
        J = ev.jacobian(ev.c0)
        rest = ev.evaluate(ev.c0)
    d = brig.shape_key_targets(mesh, names, W, idx) - rest[idx]
    Js = J.reshape(n_v, 3, -1)[idx].reshape(-1, J.shape[1])
    C = np.stack([lsq_linear(Js, df.reshape(-1), bounds=(lo - ev.c0, hi - ev.c0)).x for df in d])
    return idx, np.einsum("ij,fj->fi", J, C).reshape(len(W), n_v, 3)


def _measure_cross(name: str, build, csv: str, source) -> dict:
    """``rig_cross_landmark_ratio_<rig>`` (module doc): landmark error in mm at a 30 cm head of the Live Link Face
    take retargeted onto the rig, over the same error of the take retargeted onto the head's shape keys, both
    against the take on its own face."""
    import rigs
    from shapespace.bridge import retarget as bret
    from shapespace.bridge import rig as brig
    from shapespace.core.retarget.metrics import HEAD_MM
    rig = build()
    mesh = rig.mesh
    names, frames, W, _ = brig.capture_weights(mesh, csv)
    lm, truth, keys = _cross_truth(source, rig, names, W)
    rest = rig.world_points()[lm]
    mm = HEAD_MM / rigs.diagonal(rig.world_points())

    def err(played, per_landmark=False):
        d = np.sum(((played - rest) * mm - truth) ** 2, axis=-1)
        return np.sqrt(d.mean(axis=0)) if per_landmark else float(np.sqrt(d.mean()))

    print(f"bench rig: {name} cross-rig, shape-key version ({len(frames)} frames)", file=sys.stderr)
    t0 = time.perf_counter()
    rep = bret.retarget(mesh, csv, "spacetime", extend_scene_range=False)
    shapekey = _played(rig, frames, lm)
    out = {f"rig_cross_shapekey_s_{name}": time.perf_counter() - t0,
           f"rig_cross_landmark_mm_shapekey_{name}": err(shapekey),
           f"rig_cross_motion_mm_{name}": float(np.sqrt(np.mean(np.sum(truth ** 2, axis=-1)))),
           f"rig_cross_landmarks_{name}": int(lm.size), f"rig_cross_frames_{name}": int(len(frames))}
    del rep
    mesh.data.shape_keys.animation_data_clear()
    for kb in mesh.data.shape_keys.key_blocks[1:]:
        kb.value = 0.0
    ref = out[f"rig_cross_landmark_mm_shapekey_{name}"]
    idx, fit = _linear_bound(rig, names, W)
    out[f"rig_cross_linear_ratio_{name}"] = err(fit[:, lm] + rest) / ref
    targets = brig.shape_key_targets(mesh, names, W, idx)
    out[f"rig_cross_linear_sample_mm_{name}"] = _rms(fit[:, idx] + rig.world_points()[idx] - targets) * mm
    for route in CROSS_ROUTES:
        print(f"bench rig: {name} cross-rig, {route}", file=sys.stderr)
        t0 = time.perf_counter()
        rep = brig.retarget_capture_onto_rig(mesh, rig.controls, csv, method=route)
        out[f"rig_cross_s_{name}_{route}"] = time.perf_counter() - t0
        played = _played(rig, frames, lm)
        per_lm = err(played, per_landmark=True)
        worst = np.argsort(-per_lm)[:3]
        out[f"rig_cross_worst_landmarks_{name}_{route}"] = "; ".join(
            f"{names[keys[i]]}: {per_lm[i]:.2f} mm" for i in worst)
        out[f"rig_cross_landmark_mm_{name}_{route}"] = err(played)
        out[f"rig_cross_landmark_ratio_{name}_{route}"] = err(played) / ref
        out[f"rig_cross_rig_vs_shapekey_mm_{name}_{route}"] = float(
            np.sqrt(np.mean(np.sum((played - shapekey) ** 2, axis=-1)))) * mm
        out[f"rig_cross_status_{name}_{route}"] = rep.status.name.lower()
        out[f"rig_cross_sample_mm_{name}_{route}"] = _rms(_played(rig, frames, idx) - targets) * mm
        brig.restore_previous(rep, rig.controls)
    out[f"rig_cross_landmark_ratio_{name}"] = out[f"rig_cross_landmark_ratio_{name}_perframe"]
    out[f"rig_cross_rig_vs_shapekey_mm_{name}"] = out[f"rig_cross_rig_vs_shapekey_mm_{name}_perframe"]
    return out


def run(quick: bool = False) -> dict:
    import package
    sys.path.insert(0, os.path.join(env.ROOT, "tests"))
    sys.path.insert(0, os.path.join(env.ROOT, "tests", "bridge"))
    import conftest  # noqa: F401  (a throw-away Blender user folder)
    package.load()
    metrics = {}
    poses, reps = (3, 1) if quick else (10, 3)
    builders = dict(_rigs(quick))
    for name, build in builders.items():
        print(f"bench rig: building {name}", file=sys.stderr)
        if name == "hybrid_ict150":
            metrics.update(_measure_first_use(name, build, reps))
        else:
            metrics.update(_measure(name, build, poses, reps))
    for name in ("hybrid", "driver", "rigify"):
        if name in builders:
            metrics.update(_measure_take(name, builders[name], 30 if quick else 40))
    if "rigify" in builders:
        metrics.update(_measure_long_take(builders["rigify"], quick))
    for name in ("hybrid", "driver", "rigify"):
        if name in builders:
            metrics.update(_measure_live(name, builders[name], 1 if quick else 3))
    facecap, csv = shared_data(FACECAP, "cross-rig cases"), shared_data(LLF_CSV, "cross-rig cases")
    if facecap is not None and csv is not None:
        source = _source_face(os.path.join(env.ROOT, "assets", "llf_fbhead", "Live_Link_Face.blend"))
        for name, build in _cross_rigs(facecap):
            metrics.update(_measure_cross(name, build, csv, source))
    errs = [v for k, v in metrics.items() if k.startswith("rig_drag_pin_err_max_")]
    metrics["rig_drag_pin_err_goal_met"] = bool(errs) and max(errs) <= 1e-3
    return metrics
