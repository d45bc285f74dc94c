"""Propose Controls as a job with progress and Esc (issue #25 item 5 in the UI).

The probe evaluates the rig through Blender's depsgraph, so the job runs on the main thread, stepped from the modal
timer (``bridge.rig.steps``).  As in ``test_retarget_progress_cancel.py`` the modal path is driven here step by step
through the bridge job functions its handler calls (no window in these tests; Esc is ``job.cancel()``, the timer
is ``job.step()``); the scripted operator call is the synchronous path.
"""
import numpy as np
import pytest

import rigs
from blender_support import blend_fingerprint, bpy
from shapespace.bridge.rig import proposal, steps, stored
from shapespace.core.progress import Cancelled
from support import shared
from test_rig import _state

BUILDERS = {"hybrid": rigs.hybrid_rig, "driver": rigs.driver_rig}


def _rig(name):
    rig = BUILDERS[name](shared(*rigs.FACECAP.split("/")))
    bpy.ops.object.select_all(action="DESELECT")
    rig.mesh.select_set(True)
    bpy.context.view_layer.objects.active = rig.mesh
    return rig


def _same(before, after):
    assert before[:4] == after[:4]
    np.testing.assert_array_equal(before[4], after[4])


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_stepped_proposal_finds_what_the_one_shot_proposal_finds(name):
    rig = _rig(name)
    before = _state(rig)
    report, chans = proposal.propose(rig.mesh, rig.armature)
    job = steps.start_proposal(rig.mesh, rig.armature)
    ticks = 0
    while not job.step(0.0):                                                   # one chunk per timer tick
        ticks += 1
        _same(before, _state(rig))                                             # between ticks: the rig at rest
    assert ticks >= 2
    got, got_chans = job.result()
    assert got.proposed == report.proposed and [c.name for c in got_chans] == [c.name for c in chans]
    assert got.skipped == report.skipped
    assert job.reported == sorted(job.reported) and job.reported[-1] == 1.0 and job.fraction == 1.0
    _same(before, _state(rig))
    assert stored.PROP not in rig.mesh                                          # computing wrote nothing


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_esc_mid_way_leaves_rig_and_file_exactly_as_before(name):
    rig = _rig(name)
    before, print_before = _state(rig), blend_fingerprint()
    job = steps.start_proposal(rig.mesh, rig.armature)                         # invoke
    while job.fraction < 0.3:
        assert not job.step(0.0)                                               # the timer ticks
    assert 0.3 <= job.fraction < 1.0 and not job.done
    job.cancel()                                                               # Esc
    assert job.done and job.cancelled
    with pytest.raises(Cancelled):
        steps.finish_proposal(job, rig.mesh, rig.armature)
    _same(before, _state(rig))
    assert blend_fingerprint() == print_before and stored.PROP not in rig.mesh


def test_modal_path_stores_what_the_scripted_call_stores(registered):
    rig = _rig("hybrid")
    job = steps.start_proposal(rig.mesh, rig.armature)
    while not job.step():
        pass
    report, added = steps.finish_proposal(job, rig.mesh, rig.armature)
    modal = stored.read(rig.mesh)
    assert [e.label for e in added] == [e.label for e in modal[1]] == report.proposed
    stored.clear(rig.mesh)
    assert bpy.ops.shapespace.propose_controls() == {"FINISHED"}               # EXEC_DEFAULT: in one go
    assert stored.read(rig.mesh) == modal
    stored.clear(rig.mesh)
    assert bpy.ops.shapespace.propose_controls("INVOKE_DEFAULT") == {"FINISHED"}   # no window: in one go
    assert stored.read(rig.mesh) == modal


def test_a_failure_in_a_step_is_reported_and_writes_nothing(registered):
    rig = _rig("driver")
    bpy.ops.object.mode_set(mode="EDIT")
    job = steps.start_proposal(rig.mesh, rig.armature)
    assert job.step() and job.done
    with pytest.raises(Exception, match="Edit Mode"):
        steps.finish_proposal(job, rig.mesh, rig.armature)
    bpy.ops.object.mode_set(mode="OBJECT")
    assert stored.PROP not in rig.mesh
