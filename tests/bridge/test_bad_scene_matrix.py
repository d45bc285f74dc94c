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

from support import ASSETS
from blender_support import blend_fingerprint, bpy

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")

#: operator name → keyword arguments for an EXEC_DEFAULT call (what a script would pass).
OPERATORS = {
    "check_rig": {}, "key_sliders": {},
    "add_inbetween": {"primary": "K0", "weight": 0.5}, "add_combination": {"first": "K0", "second": "K1"},
    "add_pin": {"vertices": (3, 0, 0)}, "remove_pin": {"index": 0}, "clear_pins": {},
    "solve_pins": {"pin": 0, "target": (0.0, 0.0, 1.0)},
    "psd_add_example": {}, "psd_apply_example": {}, "psd_remove_example": {}, "psd_update": {},
    "psd_bake": {"frame_start": 1, "frame_end": 2}, "psd_bake_cache": {"frame_start": 1, "frame_end": 2},
    "psd_move_example": {}, "psd_mirror_example": {}, "psd_add_target": {"data_path": '["x"]'},
    "psd_record_targets": {}, "psd_confidence": {},
    "retarget": {"filepath": CSV, "method": "copy"}, "discard_retarget": {},
    "set_mapping": {"source": "JawOpen", "target": "K0"}, "remove_mapping": {"source": "JawOpen"},
    "add_landmark": {"name": "chin", "vertex": 0}, "landmarks_from_shapes": {"source_object": "Other"},
    "suggest_key_poses": {"filepath": CSV},
    "analyse_rig": {}, "compression_report": {}, "convert_rig": {}, "make_convex": {},
    "fill_between": {"frame_start": 1, "frame_end": 3}, "find_implausible_frames": {}, "go_to_frame": {"frame": 2},
    "inpaint_gap": {"data_path": 'key_blocks["K0"].value', "frame_start": 2, "frame_end": 3},
    "learn_face_prior": {},
}


def _sphere(keys=3, name="Face"):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6)
    ob = bpy.context.active_object
    ob.name = name
    if keys:
        ob.shape_key_add(name="Basis")
        base = np.empty(len(ob.data.vertices) * 3, np.float32)
        ob.data.vertices.foreach_get("co", base)
        rng = np.random.default_rng(0)
        for k in range(keys):
            kb = ob.shape_key_add(name=f"K{k}")
            kb.data.foreach_set("co", (base + rng.normal(0, 0.05, base.size)).astype(np.float32))
    return ob


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


def _non_finite_count():
    bad = 0
    for ob in bpy.data.objects:
        if ob.type != "MESH" or ob.data.shape_keys is None:
            continue
        for kb in ob.data.shape_keys.key_blocks:
            co = np.empty(len(ob.data.vertices) * 3 if len(kb.data) == len(ob.data.vertices) else 0, np.float32)
            if co.size:
                kb.data.foreach_get("co", co)
            bad += int((~np.isfinite(co)).sum()) + int(not np.isfinite(kb.value))
    return bad


def _linked_state():
    out = []
    for ob in bpy.data.objects:
        if ob.library is None:
            continue
        pins = len(ob.shapespace.pins) if hasattr(ob, "shapespace") else 0
        keys = [(kb.name, kb.value) for kb in ob.data.shape_keys.key_blocks] if ob.data.shape_keys else []
        props = sorted(ob.data.shape_keys.keys()) if ob.data.shape_keys else []
        action = None
        if ob.data.shape_keys is not None and ob.data.shape_keys.animation_data is not None:
            action = getattr(ob.data.shape_keys.animation_data.action, "name", None)
        out.append((ob.name, pins, keys, props, action, len(ob.vertex_groups)))
    return out


def _classify(op_name, kwargs):
    before, nan_before, linked_before = blend_fingerprint(), _non_finite_count(), _linked_state()
    op = getattr(bpy.ops.shapespace, op_name)
    try:
        result = op("EXEC_DEFAULT", **kwargs)
        message = ""
    except RuntimeError as exc:
        result, message = None, str(exc)
    except TypeError as exc:                  # an operator property the test passed does not exist
        pytest.fail(f"{op_name}: {exc}")
    if "Traceback" in message or "Python:" in message:
        return "traceback", message
    if result is None and ".poll()" in message:
        return ("refused" if "context is incorrect" not in message else "refused_without_message"), message
    changed = blend_fingerprint() != before
    if result is None or result == {"CANCELLED"}:
        return ("cancelled" if not changed else "silent_change"), message
    if _non_finite_count() > nan_before:
        return "nan_written", message
    if _linked_state() != linked_before:
        return "linked_changed", message
    return "finished", message


@pytest.mark.parametrize("op_name", sorted(OPERATORS))
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_operator_in_bad_scene(registered, scene, op_name):
    SCENES[scene]()
    outcome, message = _classify(op_name, OPERATORS[op_name])
    OUTCOMES.append((scene, op_name, outcome))
    assert outcome in ("refused", "cancelled", "finished"), f"{scene} × {op_name}: {outcome}: {message}"
    if scene in ("edit_mode", "linked") and outcome == "finished":
        assert op_name in ("check_rig", "convert_rig", "go_to_frame", "analyse_rig", "compression_report"), \
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
