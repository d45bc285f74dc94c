"""Transfer Shapes progress and Esc cancel (issue #13): read on the main thread → register and transfer in a
worker → write on the main thread, the same modal job as Retarget (``operators.progress.JobModal``).

As in ``test_retarget_progress_cancel.py`` the modal path is driven step by step through the bridge job
functions its handler calls (no window in these tests: Esc is ``job.cancel()``, the timer is polling); the
scripted operator call (EXEC_DEFAULT, or INVOKE_DEFAULT without a window) is the synchronous path.
"""
import time

import pytest

from blender_support import blend_fingerprint, bpy, esc_mid_way, rel_error
from test_authoring_transfer import _expected, _fbhead_rig, _landmark_pairs, _place_landmarks, _retopologised, _values
from shapespace.bridge import authoring
from shapespace.core.progress import Cancelled
from shapespace.core.result import ShapeSpaceError


def _dense_target(src, name="Target", levels=2, **placement):
    """A keyless copy of ``src`` subdivided (``levels`` = 2: ~9× the vertices, so registration takes seconds and a
    cancel lands mid-way), rotated, scaled and moved; returns (object, transform)."""
    return _retopologised(src, "SUBSURF", {"levels": levels}, name=name, **placement)


def _scene(levels=2):
    src = _fbhead_rig()
    tgt, transform = _dense_target(src, levels=levels)
    sv, tv = _landmark_pairs(src, tgt, transform)
    _place_landmarks(src, tgt, sv, tv)
    return src, tgt


def _state(tgt):
    """What the fingerprint leaves out and a transfer could change: objects and meshes (the registration
    preview), the target's keys, groups and stored landmarks, the driven-key blob."""
    key = tgt.data.shape_keys
    return (sorted(bpy.data.objects.keys()), sorted(bpy.data.meshes.keys()), len(bpy.data.shape_keys),
            None if key is None else [kb.name for kb in key.key_blocks], [g.name for g in tgt.vertex_groups],
            authoring.landmark_list(tgt), None if key is None else key.get("shapespace_driven"),
            authoring.preview_object(tgt) is not None)


def test_esc_mid_way_leaves_the_file_exactly_as_before(registered):
    """Esc while the worker registers: the job stops at its next progress call and nothing is written — no
    shape key, no mask group, no half data; the registration preview the artist had is still there."""
    src, tgt = _scene()
    assert len(tgt.data.vertices) > 8 * len(src.data.vertices)
    bpy.context.view_layer.objects.active = tgt
    assert bpy.ops.shapespace.preview_registration() == {"FINISHED"}
    before, state = blend_fingerprint(), _state(tgt)
    assert tgt.data.shape_keys is None and state[-1]
    plan = authoring.read_transfer(src, tgt)                                     # invoke: main thread
    assert blend_fingerprint() == before and _state(tgt) == state              # reading changed nothing
    job = authoring.start_transfer_job(plan)
    assert esc_mid_way(job, 0.1, 300)
    assert 0.1 <= max(job.reported) < 0.6                                       # stopped inside the registration
    with pytest.raises(Cancelled):
        authoring.finish_transfer_job(job)
    assert blend_fingerprint() == before and _state(tgt) == state
    assert tgt.data.shape_keys is None and authoring.preview_object(tgt) is not None


def test_job_run_writes_what_the_core_computes_and_progress_reaches_one(registered):
    """The job driven to completion (the modal path) writes every key, and Blender's evaluation of them is the
    core's own registration + deformation transfer; the progress it reported rises monotonically to 1."""
    src, tgt = _scene(levels=1)
    rig, tm, _, full = _expected(src, tgt)
    job = authoring.start_transfer_job(authoring.read_transfer(src, tgt))
    while not job.done:                                                          # the timer ticks
        time.sleep(0.01)
    rep = authoring.finish_transfer_job(job)
    assert job.reported and all(b >= a for a, b in zip(job.reported, job.reported[1:]))
    assert job.reported[-1] == 1.0 and job.fraction == 1.0 and len(job.reported) > 10
    assert len(rep.created) == len(rig.names) and rep.landmarks == 12
    names = [kb.name for kb in tgt.data.shape_keys.key_blocks]
    assert set(rig.names) <= set(names) and len(names) == len(rig.names) + 1
    for name in ("JawOpen", "EyeBlinkLeft", "MouthSmileRight"):
        assert rel_error(_values(tgt, **{name: 1.0}), tm.neutral + full[name]) < 1e-5, name
    assert rel_error(_values(tgt, JawOpen=0.5), tm.neutral + full["JawOpen@0.5"]) < 1e-5


def test_target_changed_while_computing_is_refused_and_nothing_written(registered):
    src, tgt = _scene(levels=1)
    job = authoring.start_transfer_job(authoring.read_transfer(src, tgt))
    assert job.wait(300)
    tgt.data.vertices[0].co.x += 0.01                                            # the artist edits the target
    before, state = blend_fingerprint(), _state(tgt)
    with pytest.raises(ShapeSpaceError, match="changed while the transfer computed") as info:
        authoring.finish_transfer_job(job)
    assert info.value.code == "rig_changed"
    assert blend_fingerprint() == before and _state(tgt) == state


def test_a_cancelled_synchronous_transfer_writes_nothing(registered):
    """The scripted path: ``progress`` raising Cancelled (core.progress protocol) half-way through the shape
    solves stops the transfer before the write."""
    src, tgt = _scene(levels=1)
    before, state = blend_fingerprint(), _state(tgt)
    seen = []

    def progress(fraction):
        seen.append(fraction)
        if fraction >= 0.8:
            raise Cancelled()
    with pytest.raises(Cancelled):
        authoring.transfer_shapes(src, tgt, progress=progress)
    assert 0.8 <= seen[-1] < 1.0 and all(b >= a for a, b in zip(seen, seen[1:]))
    assert blend_fingerprint() == before and _state(tgt) == state


def test_invoke_without_a_window_runs_in_one_go(registered):
    """INVOKE_DEFAULT with no window (background, scripts) has no event loop to poll from: it runs like
    EXEC_DEFAULT and writes the keys at once."""
    src, tgt = _scene(levels=1)
    bpy.context.view_layer.objects.active = tgt
    assert bpy.ops.shapespace.transfer_shapes("INVOKE_DEFAULT") == {"FINISHED"}
    assert len(tgt.data.shape_keys.key_blocks) == len(authoring.read_source_rig(src).names) + 1
