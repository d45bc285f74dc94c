"""Face-space conversions in Blender (bridge.facespace.conversions, thesis 3.7.3, 3.4.6): whole-face, delta
and PCA copies judged by Blender's own evaluation (the whole-face copy exact for any slider sum, on the shipped
Live Link Face take; PCA sliders within Blender's limits), Make Convex against a QP, and damaged copies named."""
import json
import os

import numpy as np
import pytest

from blender_support import bpy, classify_operator_call, evaluated, import_file, rel_error
from facespace_blender import (
    damage_keyframe,
    draw_face_panel,
    face_sphere,
    facecap,
    facecap_action,
    run_on_face,
    set_sliders,
)
from shapespace.bridge import actions, facespace, retarget, shapekeys
from shapespace.core.blendshape import bounding_box_diagonal
from support import ASSETS, shared


# --------------------------------------------------------------------------- representations
def test_whole_face_copy_evaluates_like_the_rig_and_converts_back_exactly(registered):
    ob = facecap(with_animation=False)
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True) == {"FINISHED"}
    wf = bpy.data.objects["Mesh_2_wholeface"]
    rng = np.random.default_rng(1)
    for _ in range(3):
        w = rng.uniform(0.0, 0.2, model.n_targets)          # Σw ≈ 5 > 1: the neutral weight goes negative
        set_sliders(ob, model.names, w)
        set_sliders(wf, model.names, w)
        assert rel_error(evaluated(wf), evaluated(ob)) < 1e-5
    # every key of the copy is a whole face: its stored positions are b0 + d_k (not deltas)
    kb = wf.data.shape_keys.key_blocks["jawOpen"]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    np.testing.assert_allclose(co.reshape(-1, 3), model.neutral + model.deltas[model.index("jawOpen")],
                               atol=1e-6 * model.scale)
    bpy.context.view_layer.objects.active = wf
    assert bpy.ops.shapespace.convert_rig(form="DELTA") == {"FINISHED"}
    back = bpy.data.objects["Mesh_2_wholeface_delta"]
    back_model = shapekeys.read_blendshape_model(back)
    assert back_model.names == model.names
    np.testing.assert_allclose(back_model.deltas, model.deltas, atol=1e-6 * model.scale)
    # the original rig's shapes were never touched (only its sliders were moved above, on purpose)
    assert np.array_equal(shapekeys.read_blendshape_model(ob).deltas, model.deltas)


def test_whole_face_without_convex_scales_the_head(registered):
    ob = facecap(with_animation=False)
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=False) == {"FINISHED"}
    wf = bpy.data.objects["Mesh_2_wholeface"]
    w = np.zeros(model.n_targets)
    w[model.index("jawOpen")] = 1.0                   # Σc = 2 with the Neutral weight fixed at 1
    set_sliders(wf, model.names, w)
    want = model.neutral * 2 + model.deltas[model.index("jawOpen")]   # (Σc)·b0 + B w (thesis 3.7.3)
    assert rel_error(evaluated(wf), want, model.neutral) < 1e-5


def test_pca_copy_is_exact_and_converts_the_animation(registered):
    ob = facecap()
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="PCA") == {"FINISHED"}
    pca = bpy.data.objects["Mesh_2_pca"]
    meta = json.loads(pca.data.shape_keys[facespace.REPRESENTATION_PROP])
    A, a = np.array(meta["A"]), np.array(meta["a"])
    names = [kb.name for kb in pca.data.shape_keys.key_blocks][1:]
    assert len(names) == 51                              # the rig's rank: tongueOut is empty
    ob.data.shape_keys.animation_data.action = None
    w = np.random.default_rng(2).uniform(0, 1, model.n_targets)
    set_sliders(ob, model.names, w)
    set_sliders(pca, names, A @ w + a)
    assert rel_error(evaluated(pca), evaluated(ob)) < 1e-5
    # PCA of the animation: the converted action replays the animation within the tolerance
    bpy.data.objects.remove(pca)
    ob.data.shape_keys.animation_data.action = facecap_action(ob)
    assert bpy.ops.shapespace.convert_rig(form="PCA", from_animation=True, tolerance=0.002) == {"FINISHED"}
    pca = bpy.data.objects["Mesh_2_pca"]
    scene = bpy.context.scene
    worst = 0.0
    for f in (30, 90, 150, 210):
        scene.frame_set(f)
        worst = max(worst, float(np.linalg.norm(evaluated(pca) - evaluated(ob), axis=1).max()) / model.scale)
    assert worst <= 0.002 * 1.0001


def test_make_convex_projects_the_sliders_like_a_qp(registered):
    """Make Convex moves the sliders to the nearest point of {0 ≤ w ≤ 1 (and the slider range), Σw ≤ 1};
    reference: quadprog on the same projection."""
    import quadprog
    ob = facecap(with_animation=False)
    model = shapekeys.read_blendshape_model(ob)
    w = np.random.default_rng(5).uniform(0.0, 0.5, model.n_targets)
    set_sliders(ob, model.names, w)
    assert bpy.ops.shapespace.make_convex() == {"FINISHED"}
    got = shapekeys.read_slider_values(ob, model.names)
    n = model.n_targets
    # min ½‖x − w‖² s.t. x ≥ 0, −x ≥ −1, −Σx ≥ −1   (quadprog: Cᵀ x ≥ b)
    C = np.hstack([np.eye(n), -np.eye(n), -np.ones((n, 1))])
    b = np.concatenate([np.zeros(n), -np.ones(n), [-1.0]])
    ref = quadprog.solve_qp(np.eye(n), w, C, b)[0]
    np.testing.assert_allclose(got, ref, atol=1e-6)      # float32 slider storage
    assert got.sum() <= 1.0 + 1e-6


CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


# --------------------------------------------------------------------------- whole-face form, any slider sum
def test_whole_face_copy_plays_the_live_link_take_exactly_even_where_the_sliders_sum_past_eleven(registered):
    """36 of the 164 frames of the shipped take sum to more than 11: the Neutral weight 1 − Σw passes Blender's
    −10 slider limit.  Every frame of the copy, evaluated by Blender, matches the original rig."""
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    rep = retarget.retarget(ob, CSV, "copy")
    action = bpy.data.actions[rep["action"]]
    model = shapekeys.read_blendshape_model(ob)
    first, last = actions.frame_range(action)
    frames = np.arange(int(first), int(last) + 1)
    sums = actions.sample_shape_keys(ob, model.names, frames, action).sum(axis=1)
    assert frames.size == 164 and np.count_nonzero(sums > 11.0) >= 30

    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True) == {"FINISHED"}
    wf = bpy.data.objects["FBHead_wholeface"]
    actions.assign_action(wf.data.shape_keys, action)          # the same slider curves drive the copy
    diag = bounding_box_diagonal(model.neutral)
    scene = bpy.context.scene

    def worst_error(at):
        worst = 0.0
        for f in at:
            scene.frame_set(int(f))
            worst = max(worst, float(np.linalg.norm(evaluated(wf) - evaluated(ob), axis=1).max()) / diag)
        return worst

    assert worst_error(frames) <= 1e-5
    # every key ShapeSpace made (the Neutral shares and their drivers) survives save and reload
    path = os.path.join(bpy.app.tempdir or "/tmp", "ss_wholeface_take.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    ob, wf, scene = bpy.data.objects["FBHead"], bpy.data.objects["FBHead_wholeface"], bpy.context.scene
    assert worst_error(frames[np.argsort(-sums)[:5]]) <= 1e-5
    # and back to a delta rig: the original's shapes
    bpy.context.view_layer.objects.active = wf
    assert bpy.ops.shapespace.convert_rig(form="DELTA") == {"FINISHED"}
    back = shapekeys.read_blendshape_model(bpy.data.objects["FBHead_wholeface_delta"])
    assert back.names == model.names
    np.testing.assert_allclose(back.deltas, model.deltas, atol=1e-6 * model.scale)


@pytest.mark.parametrize("value", [10.0, -10.0])
def test_whole_face_copy_is_exact_at_the_ends_of_wide_slider_ranges(registered, value):
    """Sliders in [−10, 10]: the neutral weight 1 − Σw spans [−29, 31]; both ends are reproduced."""
    ob = face_sphere(keys=3, lo=-10.0, hi=10.0, animated=False)
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True) == {"FINISHED"}
    wf = bpy.data.objects["Face_wholeface"]
    w = np.full(model.n_targets, value)
    shapekeys.write_slider_values(ob, model.names, w)
    shapekeys.write_slider_values(wf, model.names, w)
    want = model.neutral + np.tensordot(w, model.deltas, axes=1)
    assert float(np.abs(evaluated(ob) - want).max()) / model.scale < 1e-5          # the rig itself
    assert float(np.abs(evaluated(wf) - want).max()) / model.scale <= 1e-5
    assert facespace.whole_face_issue(wf) is None


def test_whole_face_copy_of_a_27k_vertex_rig_with_every_slider_at_its_maximum(registered):
    """ICT FaceKit, 57 sliders all at 1: the neutral weight is −56, shared by six Neutral keys."""
    import_file(shared("ict_facekit", "ict_facekit_expressions.glb"))
    ob = next(o for o in bpy.data.objects if o.type == "MESH" and o.data.shape_keys)
    bpy.context.view_layer.objects.active = ob
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True) == {"FINISHED"}
    wf = bpy.data.objects[f"{ob.name}_wholeface"]
    assert json.loads(wf.data.shape_keys[facespace.REPRESENTATION_PROP])["neutral_keys"][-1] == "Neutral 6"
    diag = bounding_box_diagonal(model.neutral)
    for w in (model.slider_max, np.random.default_rng(4).uniform(0.0, 0.7, model.n_targets)):
        shapekeys.write_slider_values(ob, model.names, w)
        shapekeys.write_slider_values(wf, model.names, w)
        assert float(np.linalg.norm(evaluated(wf) - evaluated(ob), axis=1).max()) / diag <= 1e-5


def test_widened_ranges_on_a_whole_face_copy_are_not_silent(registered):
    face_sphere(keys=3, animated=False)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True) == {"FINISHED"}
    wf = bpy.data.objects["Face_wholeface"]
    assert facespace.whole_face_issue(wf) is None
    for name in ("K0", "K1", "K2"):
        wf.data.shape_keys.key_blocks[name].slider_max = 10.0
    assert "Neutral key(s) cannot follow" in facespace.whole_face_issue(wf)
    bpy.context.view_layer.objects.active = wf
    labels = draw_face_panel()
    assert any("cannot follow" in t for t in labels), labels


def test_a_slider_named_like_the_copys_own_keys_is_refused(registered):
    ob = face_sphere(keys=3, animated=False)
    ob.data.shape_keys.key_blocks["K1"].name = "Neutral"
    before = set(bpy.data.objects.keys())
    outcome, message = run_on_face("convert_rig", form="WHOLE_FACE")
    assert outcome == "cancelled" and "'Neutral'" in message and "rename it" in message
    assert set(bpy.data.objects.keys()) == before


# --------------------------------------------------------------------------- PCA of an animation, Blender's limits
def _replay_error(ob, copy, frames):
    """Worst vertex distance (× the head size) between the copy and the rig over ``frames``, both evaluated by
    Blender as they play their own actions."""
    scale = bounding_box_diagonal(shapekeys.read_blendshape_model(ob).neutral)
    worst = 0.0
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        worst = max(worst, float(np.linalg.norm(evaluated(copy) - evaluated(ob), axis=1).max()) / scale)
    return worst


def test_pca_of_an_animation_follows_what_blender_plays_when_a_curve_overshoots_its_slider(registered):
    """A curve at 3 on a [0, 1] slider: Blender shows 1, and so must the PCA copy."""
    ob = face_sphere()
    damage_keyframe(ob, "K1", 10, 3.0)
    assert bpy.ops.shapespace.convert_rig(form="PCA", from_animation=True, tolerance=1e-4) == {"FINISHED"}
    assert _replay_error(ob, bpy.data.objects["Face_pca"], range(1, 31)) <= 1e-4 * 1.001


def test_pca_sliders_of_a_rare_extreme_frame_stay_within_blenders_range(registered):
    """One spike in a long quiet take lies ~20 standard deviations out: its slider value would pass ±10."""
    ob = face_sphere(animated=False)
    key = ob.data.shape_keys
    actions.new_action(key, "quiet")
    frames = np.arange(1.0, 401.0)
    for k in range(3):
        w = 0.01 + 0.005 * np.sin(frames / (7.0 + k))
        if k == 0:
            w[200] = 1.0
        actions.write_curve(key, actions.shape_key_path(f"K{k}"), frames, w)
    assert bpy.ops.shapespace.convert_rig(form="PCA", from_animation=True, tolerance=1e-4) == {"FINISHED"}
    pca = bpy.data.objects["Face_pca"]
    values = [actions.read_curve(fc)[1] for fc in actions.shape_key_curves(pca).values()]
    assert max(np.abs(v).max() for v in values) <= 10.0
    assert _replay_error(ob, pca, [199, 201, 202, 300]) <= 1e-4 * 1.001


def test_pca_of_targets_that_move_nothing_is_refused(registered):
    ob = face_sphere()
    blocks = ob.data.shape_keys.key_blocks
    co = np.empty(len(blocks[0].data) * 3, np.float32)
    blocks[0].data.foreach_get("co", co)
    for kb in blocks[1:]:
        kb.data.foreach_set("co", co)
    for kwargs in ({"form": "PCA"}, {"form": "PCA", "from_animation": True}):
        outcome, message = run_on_face("convert_rig", **kwargs)
        assert outcome == "cancelled" and "no vertex: a PCA copy would have no sliders" in message, message


def test_a_nan_key_in_a_whole_face_copy_is_refused_when_converting_back(registered):
    face_sphere(animated=False)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE") == {"FINISHED"}
    wf = bpy.data.objects["Face_wholeface"]
    kb = wf.data.shape_keys.key_blocks["K2"]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[4] = np.inf
    kb.data.foreach_set("co", co)
    bpy.context.view_layer.objects.active = wf
    outcome, message = classify_operator_call("convert_rig", {"form": "DELTA"})
    assert outcome == "cancelled" and "shape key 'K2'" in message and "non-finite" in message, message


def test_a_whole_face_copy_with_damaged_or_missing_neutral_keys_is_named(registered):
    face_sphere(animated=False)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE") == {"FINISHED"}
    wf = bpy.data.objects["Face_wholeface"]
    key = wf.data.shape_keys
    good = json.loads(key[facespace.REPRESENTATION_PROP])
    bpy.context.view_layer.objects.active = wf
    key[facespace.REPRESENTATION_PROP] = json.dumps(dict(good, neutral_keys=[1, 2]))
    outcome, message = classify_operator_call("convert_rig", {"form": "DELTA"})
    assert outcome == "cancelled" and "damaged ShapeSpace data in Key 'Key" in message
    assert "▸ shapespace_representation: neutral_keys" in message, message
    assert any("shapespace_representation" in t for t in draw_face_panel())
    key[facespace.REPRESENTATION_PROP] = json.dumps(dict(good, neutral_keys=["Gone"]))
    outcome, message = classify_operator_call("convert_rig", {"form": "DELTA"})
    assert outcome == "cancelled" and "lost its key 'Gone'" in message, message
    # a 0.1.0 copy (one Neutral, no neutral_keys) whose Neutral key was deleted
    key[facespace.REPRESENTATION_PROP] = json.dumps({k: v for k, v in good.items() if k != "neutral_keys"})
    wf.active_shape_key_index = list(key.key_blocks.keys()).index("Neutral")
    wf.shape_key_remove(key.key_blocks["Neutral"])
    outcome, message = classify_operator_call("convert_rig", {"form": "DELTA"})
    assert outcome == "cancelled" and "lost its key 'Neutral'" in message, message
