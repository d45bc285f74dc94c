"""The face-space verbs' shared readers (bridge.facespace.readers): NaN coordinates, NaN keyframes and keys on NaN
frames refused naming the key, curve and frame, one-frame actions and meshes without vertices refused, and the
progress the long operators show (always ended)."""
import contextlib
import importlib

import numpy as np
import pytest

from blender_support import bpy
from facespace_blender import damage_keyframe, face_sphere, key_curve, run_on_face
from shapespace.bridge import actions, facespace


def test_a_one_frame_action(registered):
    ob = face_sphere(animated=False)
    ob.data.shape_keys.key_blocks["K0"].keyframe_insert("value", frame=1)
    for op_name in ("compression_report", "learn_face_prior"):
        outcome, message = run_on_face(op_name)
        assert outcome == "cancelled" and "spans 1 frame(s): this needs at least 2" in message, (op_name, message)
    assert run_on_face("analyse_rig")[0] == "finished"            # the rig's analysis needs no animation
    assert "sparsity" not in facespace.stored_analysis(ob)["coherence"]


# --------------------------------------------------------------------------- NaN keys, NaN keyframes, 0 vertices
@pytest.mark.parametrize("op_name,kwargs", [
    ("analyse_rig", {}), ("compression_report", {}), ("convert_rig", {"form": "PCA"}),
    ("convert_rig", {"form": "PCA", "from_animation": True}), ("convert_rig", {"form": "WHOLE_FACE"}),
    ("make_convex", {}), ("learn_face_prior", {})])
def test_a_nan_coordinate_is_refused_naming_the_key(registered, op_name, kwargs):
    ob = face_sphere()
    kb = ob.data.shape_keys.key_blocks["K1"]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[16] = np.nan
    kb.data.foreach_set("co", co)
    images = len(bpy.data.images)
    outcome, message = run_on_face(op_name, **kwargs)
    assert outcome == "cancelled", (outcome, message)
    assert "shape key 'K1'" in message and "non-finite" in message and "vertex 5" in message, message
    assert len(bpy.data.images) == images and "shapespace_analysis" not in ob.data.shape_keys


@pytest.mark.parametrize("op_name,kwargs", [
    ("analyse_rig", {}), ("compression_report", {}), ("convert_rig", {"form": "PCA", "from_animation": True}),
    ("learn_face_prior", {})])
def test_a_nan_keyframe_is_refused_naming_the_curve_and_frame(registered, op_name, kwargs):
    ob = face_sphere()
    damage_keyframe(ob)
    images, objects = len(bpy.data.images), len(bpy.data.objects)
    outcome, message = run_on_face(op_name, **kwargs)
    assert outcome == "cancelled", (outcome, message)
    assert 'key_blocks["K1"].value' in message and "frame 10" in message and "nan" in message, message
    assert (len(bpy.data.images), len(bpy.data.objects)) == (images, objects)
    assert "shapespace_face_prior" not in ob.data.shape_keys and "shapespace_analysis" not in ob.data.shape_keys


def test_a_keyframe_on_a_nan_frame_is_refused(registered):
    ob = face_sphere()
    fc = key_curve(ob, "K0")
    kp = fc.keyframe_points[4]
    kp.co = (float("nan"), 0.5)
    for op_name in ("analyse_rig", "learn_face_prior", "compression_report"):
        outcome, message = run_on_face(op_name)
        assert outcome == "cancelled" and 'key_blocks["K0"].value' in message and "non-finite frame" in message, \
            (op_name, message)
    outcome, message = run_on_face("inpaint_gap", data_path=actions.shape_key_path("K1"), frame_start=8, frame_end=12)
    assert outcome == "cancelled" and "non-finite frame" in message, message


def test_face_space_operators_refuse_a_mesh_without_vertices(registered):
    ob = bpy.data.objects.new("Face", bpy.data.meshes.new("Empty"))
    bpy.context.scene.collection.objects.link(ob)
    for name in ("Basis", "K0", "K1"):
        ob.shape_key_add(name=name)
    key = ob.data.shape_keys
    for f in (1, 10):
        key.key_blocks["K0"].value = f / 10
        key.key_blocks["K0"].keyframe_insert("value", frame=f)
    for op_name, kwargs in [("analyse_rig", {}), ("compression_report", {}), ("convert_rig", {"form": "PCA"}),
                            ("convert_rig", {"form": "WHOLE_FACE"}), ("make_convex", {}), ("learn_face_prior", {})]:
        outcome, message = run_on_face(op_name, **kwargs)
        assert outcome in ("refused", "cancelled") and "has no vertices" in message, (op_name, outcome, message)


# --------------------------------------------------------------------------- progress
@pytest.mark.parametrize("op_name,kwargs", [
    ("analyse_rig", {}), ("compression_report", {}), ("convert_rig", {"form": "PCA"}),
    ("convert_rig", {"form": "PCA", "from_animation": True}), ("learn_face_prior", {}),
    ("find_implausible_frames", {}), ("inpaint_gap", {"data_path": 'key_blocks["K0"].value', "frame_start": 5,
                                                      "frame_end": 9})])
def test_long_operators_show_progress_and_always_end_it(registered, monkeypatch, op_name, kwargs):
    from shapespace.operators.progress import window_progress
    seen, ended = [], []

    @contextlib.contextmanager
    def recorded(context, steps=100):
        with window_progress(context, steps):
            try:
                yield seen.append
            finally:
                ended.append(1)

    monkeypatch.setattr(importlib.import_module(f"shapespace.operators.facespace.{op_name}"), "window_progress",
                        recorded)
    face_sphere()
    if op_name == "find_implausible_frames":
        assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
        seen.clear()
        ended.clear()
    assert run_on_face(op_name, **kwargs)[0] == "finished"
    assert seen and seen[-1] == 1.0 and all(a <= b for a, b in zip(seen, seen[1:])), seen
    assert ended == [1]
    # a refusal ends the indicator too
    damage_keyframe(bpy.data.objects["Face"], "K1", 20)
    ended.clear()
    if not (op_name == "convert_rig" and not kwargs.get("from_animation")):     # the rig's span needs no curve
        assert run_on_face(op_name, **kwargs)[0] == "cancelled"
        assert ended == [1]
