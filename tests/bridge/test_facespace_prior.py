"""The face prior in Blender (bridge.facespace.prior, thesis ch. 6): the meter against an independent NumPy
Gaussian, regularised short animations, shell vs linear in-betweens, NaN keyframes with a learnt prior, and a
damaged prior named in one line everywhere."""
import json

import numpy as np
import pytest

from blender_support import bpy
from facespace_blender import (
    damage_keyframe,
    draw_face_panel,
    face_sphere,
    facecap,
    facecap_action,
    key_curve,
    run_on_face,
    set_sliders,
)
from shapespace.bridge import actions, facespace, shapekeys
from shapespace.core.result import ShapeSpaceError


# --------------------------------------------------------------------------- face prior (ch. 6)
def test_prior_meter_agrees_with_a_numpy_gaussian_and_flags_the_mean_face(registered):
    ob = facecap()
    shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    g, names = facespace.prior(ob)
    # independent: Blender's own F-Curve evaluation at every frame, numpy covariance with the same ridge
    action = facecap_action(ob)
    curves = actions.shape_key_curves(ob, action)
    first, last = actions.frame_range(action)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    W = np.array([[curves[n].evaluate(float(f)) for n in names] for f in frames])
    S = np.cov(W, rowvar=False) + g.ridge * np.eye(len(names))
    ob.data.shape_keys.animation_data.action = None
    w = W[40]
    set_sliders(ob, names, w)
    d = w - W.mean(axis=0)
    assert facespace.meter(ob).norm == pytest.approx(np.sqrt(d @ np.linalg.solve(S, d)), rel=1e-4)
    # the mean face is atypical in high dimensions: it lies far inside the shell
    set_sliders(ob, names, np.clip(W.mean(axis=0), 0, 1))
    m = facespace.meter(ob)
    assert m.plausibility == "too_average" and m.norm < 0.5 * m.shell_radius
    ob.data.shape_keys.animation_data.action = action
    assert bpy.ops.shapespace.find_implausible_frames(alpha=0.01) == {"FINISHED"}
    flagged = ob.shapespace_face.implausible
    assert len(flagged) < 0.5 * len(frames)
    assert bpy.ops.shapespace.go_to_frame(frame=flagged[0].frame) == {"FINISHED"}
    assert bpy.context.scene.frame_current == flagged[0].frame


def test_short_animation_prior_is_regularised_and_says_so(registered):
    ob = facecap()
    action = facecap_action(ob)
    key = ob.data.shape_keys
    short = action.copy()
    actions.assign_action(key, short)
    for fc in actions.shape_key_curves(ob, short).values():
        pts = fc.keyframe_points
        while len(pts) > 20:                          # 20 keys ≪ 52 sliders: singular covariance
            pts.remove(pts[-1])
    rep = facespace.learn_prior(ob)
    assert rep.regularised and "regularised" in rep.message


def test_shell_in_betweens_keep_the_norm_linear_ones_collapse(registered):
    ob = facecap()
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    g, names = facespace.prior(ob)
    key = ob.data.shape_keys
    action = facecap_action(ob)
    W = actions.sample_shape_keys(ob, names, [60.0, 200.0], action)
    z0, z1 = g.whiten(W[0]), g.whiten(W[1])
    for mode in ("SHELL", "LINEAR"):
        act = bpy.data.actions.new(f"fill_{mode}")
        actions.assign_action(key, act)
        for j, n in enumerate(names):
            actions.write_curve(key, actions.shape_key_path(n), [10.0, 30.0], W[:, j])
        bpy.context.scene.frame_set(20)
        assert bpy.ops.shapespace.fill_between(mode=mode) == {"FINISHED"}
        inner = np.arange(11.0, 30.0)
        Z = g.whiten(actions.sample_shape_keys(ob, names, inner, act))
        norms = np.linalg.norm(Z, axis=1)
        t = (inner - 10.0) / 20.0
        if mode == "SHELL":      # radius interpolated linearly, never collapsing
            np.testing.assert_allclose(norms, (1 - t) * np.linalg.norm(z0) + t * np.linalg.norm(z1), rtol=1e-5)
        else:                    # straight chord: analytic norm |(1−t) z0 + t z1|
            np.testing.assert_allclose(norms, np.linalg.norm((1 - t)[:, None] * z0 + t[:, None] * z1, axis=1),
                                       rtol=1e-5)
            assert norms[9] < min(np.linalg.norm(z0), np.linalg.norm(z1))
    with pytest.raises(RuntimeError, match="is not between two keys"):
        bpy.context.scene.frame_set(50)
        bpy.ops.shapespace.fill_between(mode="SHELL")


def test_fill_without_prior_is_refused_by_poll(registered):
    facecap()
    assert not bpy.ops.shapespace.fill_between.poll()
    assert not bpy.ops.shapespace.find_implausible_frames.poll()


def test_nan_keyframes_with_a_learnt_prior(registered):
    ob = face_sphere()
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    damage_keyframe(ob, "K2", 12, float("inf"))
    outcome, message = run_on_face("find_implausible_frames")
    assert outcome == "cancelled" and 'key_blocks["K2"].value' in message and "frame 12" in message, message
    # a fill replaces the keys between its ends: a damaged key there is what it repairs
    assert run_on_face("fill_between", frame_start=10, frame_end=14)[0] == "finished"
    assert np.isfinite(actions.read_curve(key_curve(ob, "K2"))[1]).all()
    # a damaged end is refused, naming it
    damage_keyframe(ob, "K0", 20)
    outcome, message = run_on_face("fill_between", frame_start=20, frame_end=25)
    assert outcome == "cancelled" and 'key_blocks["K0"].value' in message and "frame 20" in message, message


def _prior_blob(ob):
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    return json.loads(ob.data.shape_keys[facespace.PRIOR_PROP])


def _bad_priors(good):
    n = len(good["names"])
    eye = np.eye(n).tolist()
    return {
        "three_names": dict(good, names=good["names"][:3]),
        "mean_too_long": dict(good, mean=good["mean"] + [0.0]),
        "eigvecs_wrong_shape": dict(good, eigvecs=[row[:-1] for row in good["eigvecs"]]),
        "eigvecs_ragged": dict(good, eigvecs=good["eigvecs"][:-1] + [[1.0]]),
        "eigvecs_not_orthonormal": dict(good, eigvecs=(2 * np.array(eye)).tolist()),
        "eigvals_zero": dict(good, eigvals=[0.0] * n),
        "mean_null": dict(good, mean=[None] + good["mean"][1:]),
        "mean_strings": dict(good, mean=["a"] * n),
        "names_numbers": dict(good, names=list(range(n))),
        "names_repeated": dict(good, names=[good["names"][0]] * n),
        "dimension_negative": dict(good, dimension=-1.0),
        "dimension_too_big": dict(good, dimension=n + 5.0),
        "ridge_negative": dict(good, ridge=-1.0),
    }


@pytest.mark.parametrize("case", sorted(_bad_priors({"names": ["a", "b", "c", "d"], "mean": [0.0] * 4,
                                                      "eigvecs": np.eye(4).tolist(), "eigvals": [1.0] * 4})))
def test_a_damaged_prior_is_named_in_one_line_everywhere(registered, case):
    ob = face_sphere(keys=6)
    good = _prior_blob(ob)
    ob.data.shape_keys[facespace.PRIOR_PROP] = json.dumps(_bad_priors(good)[case])
    where = "damaged ShapeSpace data in Key 'Key' ▸ shapespace_face_prior"
    with pytest.raises(ShapeSpaceError, match=where) as err:
        facespace.meter(ob)
    assert err.value.code == "corrupt_metadata" and "\n" not in str(err.value)
    for op_name, kwargs in [("find_implausible_frames", {}), ("fill_between", {"frame_start": 2, "frame_end": 9})]:
        outcome, message = run_on_face(op_name, **kwargs)
        assert outcome == "cancelled" and where in message, (op_name, outcome, message)
    labels = draw_face_panel()
    assert any(t.startswith(where) for t in labels), labels
