"""Preview Registration in the background (issue #13; the same modal job as Transfer Shapes and Retarget): read
on the main thread → register in a worker → show the preview on the main thread; Esc leaves the file as it was.

As in ``test_authoring_transfer.py`` the modal path is driven through the bridge job functions its handler
calls (no window here: Esc is ``job.cancel()``).  The preview is checked against the core's own registration of
the same inputs (an independent call), not against numbers the preview code reports.
"""
import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, esc_mid_way
from shapespace.bridge import authoring
from shapespace.core import authoring as core
from shapespace.core.progress import Cancelled
from shapespace.core.result import ShapeSpaceError
from test_authoring_transfer import _scene, _state


def _preview_positions(tgt):
    ob = authoring.preview_object(tgt)
    co = np.empty(3 * len(ob.data.vertices), dtype=np.float32)
    ob.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def test_esc_mid_registration_leaves_the_file_and_the_old_preview_as_they_were(registered):
    src, tgt = _scene()
    bpy.context.view_layer.objects.active = tgt
    assert bpy.ops.shapespace.preview_registration() == {"FINISHED"}           # a preview the artist already has
    old = _preview_positions(tgt)
    before, state = blend_fingerprint(), _state(tgt)
    plan = authoring.read_preview(src, tgt)
    assert blend_fingerprint() == before and _state(tgt) == state              # reading changed nothing
    job = authoring.start_preview_job(plan)
    assert esc_mid_way(job, 0.1, 300)
    assert 0.1 <= max(job.reported) < 1.0
    with pytest.raises(Cancelled):
        authoring.finish_preview_job(job)
    assert blend_fingerprint() == before and _state(tgt) == state
    np.testing.assert_array_equal(_preview_positions(tgt), old)


def test_job_run_shows_the_core_registration(registered):
    src, tgt = _scene(levels=1)
    plan = authoring.read_preview(src, tgt)
    job = authoring.start_preview_job(plan)
    assert job.wait(300)
    ob, result = authoring.finish_preview_job(job)
    assert ob.parent == tgt and ob.display_type == "WIRE" and ob.hide_render
    assert job.reported[-1] == 1.0 and all(b >= a for a, b in zip(job.reported, job.reported[1:]))
    # the same registration computed independently from the same inputs
    rig, tm = authoring.read_source_rig(src), authoring.read_target(tgt)
    src_i, dst_i = authoring.landmark_pairs(tgt, src)
    pairs = core.landmarks_from_indices(rig.neutral, tm.neutral, src_i, dst_i)
    want = core.register(rig.neutral, rig.triangles, tm.neutral, tm.triangles, pairs).value.registered
    size = float(np.linalg.norm(np.ptp(tm.neutral, axis=0)))
    assert np.abs(_preview_positions(tgt) - want).max() <= 1e-6 * size             # float32 mesh coordinates


def test_target_changed_while_registering_is_refused_and_nothing_shown(registered):
    src, tgt = _scene(levels=1)
    plan = authoring.read_preview(src, tgt)
    job = authoring.start_preview_job(plan)
    assert job.wait(300)
    tgt.data.vertices[0].co.x += 0.01
    before, state = blend_fingerprint(), _state(tgt)
    with pytest.raises(ShapeSpaceError, match="changed while the registration computed") as info:
        authoring.finish_preview_job(job)
    assert info.value.code == "rig_changed"
    assert blend_fingerprint() == before and _state(tgt) == state and authoring.preview_object(tgt) is None


def test_invoke_without_a_window_runs_in_one_go(registered):
    src, tgt = _scene(levels=1)
    bpy.context.view_layer.objects.active = tgt
    assert bpy.ops.shapespace.preview_registration("INVOKE_DEFAULT") == {"FINISHED"}
    assert authoring.preview_object(tgt) is not None
