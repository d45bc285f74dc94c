"""Reliability suite: every operator × every bad scene (issue #10 §4).

For each cell the operator must either
- be refused by its poll with a specific message (not Blender's generic "context is incorrect"), or
- end CANCELLED with a one-line report (no Python traceback) and leave the file exactly as before, or
- end FINISHED with a sound result: nothing finite became NaN, and linked (library) data is unchanged.

A session summary (cases / handled / tracebacks / silent changes) is printed at the end of the run.
"""
import os
import tempfile

import numpy as np
import pytest

from blender_support import NOT_CALLED, bpy, classify_operator_call, sphere_rig
from blender_support import OPERATOR_CALLS as OPERATORS


def _sphere(keys=3, name="Face"):
    return sphere_rig(keys, name)


def _activate(ob):
    bpy.context.view_layer.objects.active = ob
    if ob is not None:
        ob.select_set(True)


def scene_no_selection():
    _sphere()
    bpy.context.view_layer.objects.active = None
    for ob in bpy.context.view_layer.objects:
        ob.select_set(False)


def scene_non_mesh():
    bpy.ops.object.empty_add()
    _activate(bpy.context.active_object)


def scene_no_shape_keys():
    _activate(_sphere(keys=0))


def scene_nan_coordinates():
    ob = _sphere()
    kb = ob.data.shape_keys.key_blocks["K1"]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[9] = np.nan
    kb.data.foreach_set("co", co)
    _activate(ob)


def scene_edit_mode():
    ob = _sphere()
    _activate(ob)
    ob.active_shape_key_index = 2
    bpy.ops.object.mode_set(mode="EDIT")


def scene_linked():
    _sphere()
    path = os.path.join(tempfile.mkdtemp(prefix="ss-lib-"), "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with bpy.data.libraries.load(path, link=True) as (_, dst):
        dst.objects = ["Face"]
    ob = dst.objects[0]
    bpy.context.scene.collection.objects.link(ob)
    _activate(ob)


def scene_zero_vertices():
    me = bpy.data.meshes.new("Empty")
    ob = bpy.data.objects.new("Face", me)
    bpy.context.scene.collection.objects.link(ob)
    ob.shape_key_add(name="Basis")
    ob.shape_key_add(name="K0")
    ob.shape_key_add(name="K1")
    _activate(ob)
    ob.active_shape_key_index = 2


SCENES = {name[len("scene_"):]: fn for name, fn in globals().items() if name.startswith("scene_")}
OUTCOMES = []


@pytest.mark.parametrize("op_name", sorted(OPERATORS))
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_operator_in_bad_scene(registered, scene, op_name):
    SCENES[scene]()
    outcome, message = classify_operator_call(op_name, OPERATORS[op_name])
    OUTCOMES.append((scene, op_name, outcome))
    assert outcome in ("refused", "cancelled", "finished"), f"{scene} × {op_name}: {outcome}: {message}"
    if scene in ("edit_mode", "linked") and outcome == "finished":
        assert op_name in ("check_rig", "convert_rig", "go_to_frame", "analyse_rig", "compression_report",
                           "export_for_engines"), \
            f"{scene} × {op_name} finished: it must be refused ({message})"


def test_matrix_summary():
    """Print the counts for the record (runs after the matrix in file order)."""
    if not OUTCOMES:
        pytest.skip("matrix not run")
    counts = {}
    for _, _, outcome in OUTCOMES:
        counts[outcome] = counts.get(outcome, 0) + 1
    handled = sum(counts.get(k, 0) for k in ("refused", "cancelled", "finished"))
    print(f"\nbad-scene matrix: {len(OUTCOMES)} cases, {handled} handled, "
          f"{counts.get('traceback', 0)} tracebacks, {counts.get('silent_change', 0)} silent changes; {counts}")
    assert handled == len(OUTCOMES)


def test_every_operator_is_in_the_matrix_or_says_where_it_is_tested(registered):
    ids = {name for name in dir(bpy.ops.shapespace) if not name.startswith("_")}
    assert ids - set(OPERATORS) == set(NOT_CALLED) and not set(OPERATORS) - ids
