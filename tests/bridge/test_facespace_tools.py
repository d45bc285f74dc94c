"""Face-space tools in Blender (issue #6): conversions judged by Blender's own evaluation, diagnostics,
the face prior and its meter against an independent numpy Gaussian, shell vs linear in-betweens,
curve inpainting through the operator, pose-space confidence, and their bad input."""
import json
import os

import numpy as np
import pytest

from support import ASSETS
from blender_support import blend_fingerprint, bpy, evaluated, import_file, rel_error
from shapespace.bridge import actions, facespace, posespace, shapekeys

FACECAP = os.path.join(ASSETS, "facecap", "facecap_decoded.glb")


def _facecap(with_animation=True):
    import_file(FACECAP)
    ob = bpy.data.objects["Mesh_2"]
    bpy.context.view_layer.objects.active = ob
    if not with_animation:
        ob.data.shape_keys.animation_data.action = None
    return ob


def _set(ob, names, w):
    shapekeys.write_slider_values(ob, names, w)


# --------------------------------------------------------------------------- representations
def test_whole_face_copy_evaluates_like_the_rig_and_converts_back_exactly(registered):
    ob = _facecap(with_animation=False)
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True) == {"FINISHED"}
    wf = bpy.data.objects["Mesh_2_wholeface"]
    rng = np.random.default_rng(1)
    for _ in range(3):
        w = rng.uniform(0.0, 0.2, model.n_targets)          # Σw ≈ 5 > 1: the neutral weight goes negative
        _set(ob, model.names, w)
        _set(wf, model.names, w)
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
    ob = _facecap(with_animation=False)
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=False) == {"FINISHED"}
    wf = bpy.data.objects["Mesh_2_wholeface"]
    w = np.zeros(model.n_targets)
    w[model.index("jawOpen")] = 1.0                   # Σc = 2 with the Neutral weight fixed at 1
    _set(wf, model.names, w)
    want = model.neutral * 2 + model.deltas[model.index("jawOpen")]   # (Σc)·b0 + B w (thesis 3.7.3)
    assert rel_error(evaluated(wf), want, model.neutral) < 1e-5


def test_pca_copy_is_exact_and_converts_the_animation(registered):
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.convert_rig(form="PCA") == {"FINISHED"}
    pca = bpy.data.objects["Mesh_2_pca"]
    meta = json.loads(pca.data.shape_keys[facespace.REPRESENTATION_PROP])
    A, a = np.array(meta["A"]), np.array(meta["a"])
    names = [kb.name for kb in pca.data.shape_keys.key_blocks][1:]
    assert len(names) == 51                              # the rig's rank: tongueOut is empty
    ob.data.shape_keys.animation_data.action = None
    w = np.random.default_rng(2).uniform(0, 1, model.n_targets)
    _set(ob, model.names, w)
    _set(pca, names, A @ w + a)
    assert rel_error(evaluated(pca), evaluated(ob)) < 1e-5
    # PCA of the animation: the converted action replays the animation within the tolerance
    bpy.data.objects.remove(pca)
    ob.data.shape_keys.animation_data.action = _facecap_action(ob)
    assert bpy.ops.shapespace.convert_rig(form="PCA", from_animation=True, tolerance=0.002) == {"FINISHED"}
    pca = bpy.data.objects["Mesh_2_pca"]
    scene = bpy.context.scene
    worst = 0.0
    for f in (30, 90, 150, 210):
        scene.frame_set(f)
        worst = max(worst, float(np.linalg.norm(evaluated(pca) - evaluated(ob), axis=1).max()) / model.scale)
    assert worst <= 0.002 * 1.0001


def _facecap_action(ob):
    return next(a for a in bpy.data.actions if actions.shape_key_curves(ob, a))


def test_compression_report_matches_an_svd_of_blenders_frames(registered):
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    tol = 0.001
    assert bpy.ops.shapespace.compression_report(tolerance=tol) == {"FINISHED"}
    rep = facespace.stored(ob, facespace.ANALYSIS_PROP)["compression"]
    # independent reference: Blender's evaluated frames, numpy SVD, brute-force max vertex error
    action = _facecap_action(ob)
    first, last = actions.frame_range(action)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    X = []
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        X.append(evaluated(ob).ravel())
    X = np.array(X)
    Xc = X - X.mean(axis=0)
    U, s, Vt = np.linalg.svd(Xc, full_matrices=False)
    def err(m):
        R = Xc - (U[:, :m] * s[:m]) @ Vt[:m]
        return np.linalg.norm(R.reshape(len(frames), -1, 3), axis=2).max()
    m = rep["components"]
    assert err(m) <= tol * model.scale * (1 + 1e-4) and err(m - 1) > tol * model.scale * (1 - 1e-4)
    assert rep["targets"] == 52 and rep["ratio"] == pytest.approx(52 / m)


# --------------------------------------------------------------------------- diagnostics
def test_analyse_rig_image_pairs_empty_and_sparsity(registered, tmp_path):
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    # a duplicate target (scaled) must be reported as a near-duplicate pair
    pos = model.neutral + 0.5 * model.deltas[model.index("jawOpen")]
    shapekeys.add_shape_key(ob, "jawOpen_copy", pos)
    png = tmp_path / "coherence.png"
    assert bpy.ops.shapespace.analyse_rig(filepath=str(png)) == {"FINISHED"}
    rep = facespace.stored(ob, facespace.ANALYSIS_PROP)["coherence"]
    assert rep["empty_targets"] == ["tongueOut"]
    assert ["jawOpen", "jawOpen_copy"] == sorted(rep["similar_pairs"][0][:2])
    assert rep["similar_pairs"][0][2] == pytest.approx(1.0, abs=1e-6)
    img = bpy.data.images[rep["image"]]
    assert img.size[0] == img.size[1] >= 53 and png.stat().st_size > 0
    # the PNG is the image: read back through Blender and compare with the core's picture
    back = bpy.data.images.load(str(png))
    px = np.empty(back.size[0] * back.size[1] * 4, np.float32)
    back.pixels.foreach_get(px)
    mine = np.empty_like(px)
    img.pixels.foreach_get(mine)
    np.testing.assert_allclose(px, mine, atol=1 / 255)
    sp = rep["sparsity"]
    assert sp["blendshape"]["curve_small_fraction"] > sp["pca"]["curve_small_fraction"]   # Figs 3.14/3.15


# --------------------------------------------------------------------------- face prior (ch. 6)
def test_prior_meter_agrees_with_a_numpy_gaussian_and_flags_the_mean_face(registered):
    ob = _facecap()
    shapekeys.read_blendshape_model(ob)
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    g, names = facespace.prior(ob)
    # independent: Blender's own F-Curve evaluation at every frame, numpy covariance with the same ridge
    action = _facecap_action(ob)
    curves = actions.shape_key_curves(ob, action)
    first, last = actions.frame_range(action)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    W = np.array([[curves[n].evaluate(float(f)) for n in names] for f in frames])
    S = np.cov(W, rowvar=False) + g.ridge * np.eye(len(names))
    ob.data.shape_keys.animation_data.action = None
    w = W[40]
    _set(ob, names, w)
    d = w - W.mean(axis=0)
    assert facespace.meter(ob)["norm"] == pytest.approx(np.sqrt(d @ np.linalg.solve(S, d)), rel=1e-4)
    # the mean face is atypical in high dimensions: it lies far inside the shell
    _set(ob, names, np.clip(W.mean(axis=0), 0, 1))
    m = facespace.meter(ob)
    assert m["status"] == "too_average" and m["norm"] < 0.5 * m["shell_radius"]
    ob.data.shape_keys.animation_data.action = action
    assert bpy.ops.shapespace.find_implausible_frames(alpha=0.01) == {"FINISHED"}
    flagged = ob.shapespace_face.implausible
    assert len(flagged) < 0.5 * len(frames)
    assert bpy.ops.shapespace.go_to_frame(frame=flagged[0].frame) == {"FINISHED"}
    assert bpy.context.scene.frame_current == flagged[0].frame


def test_short_animation_prior_is_regularised_and_says_so(registered):
    ob = _facecap()
    action = _facecap_action(ob)
    key = ob.data.shape_keys
    short = action.copy()
    actions.assign_action(key, short)
    for fc in actions.shape_key_curves(ob, short).values():
        pts = fc.keyframe_points
        while len(pts) > 20:                          # 20 keys ≪ 52 sliders: singular covariance
            pts.remove(pts[-1])
    rep = facespace.learn_prior(ob)
    assert rep["regularised"] and "regularised" in rep["message"]


def test_shell_in_betweens_keep_the_norm_linear_ones_collapse(registered):
    ob = _facecap()
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    g, names = facespace.prior(ob)
    key = ob.data.shape_keys
    action = _facecap_action(ob)
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
    _facecap()
    assert not bpy.ops.shapespace.fill_between.poll()
    assert not bpy.ops.shapespace.find_implausible_frames.poll()


# --------------------------------------------------------------------------- inpainting (9.3)
def test_inpaint_gap_on_a_shape_key_curve(registered):
    ob = _facecap()
    key = ob.data.shape_keys
    action = _facecap_action(ob)
    dense = bpy.data.actions.new("dense")
    names = shapekeys.read_blendshape_model(ob).names
    frames = np.arange(2.0, 268.0)
    W = actions.sample_shape_keys(ob, names, frames, action)
    actions.assign_action(key, dense)
    for j, n in enumerate(names):
        actions.write_curve(key, actions.shape_key_path(n), frames, W[:, j])
    path = actions.shape_key_path("jawOpen")
    j = names.index("jawOpen")
    assert bpy.ops.shapespace.inpaint_gap(data_path=path, index=0, frame_start=120, frame_end=131) == {"FINISHED"}
    fc = actions.shape_key_curves(ob, dense)["jawOpen"]
    kx, ky, _ = actions.read_curve(fc)
    np.testing.assert_array_equal(kx, frames)
    outside = (frames < 120) | (frames > 131)
    np.testing.assert_allclose(ky[outside], W[outside, j], atol=1e-7)          # known samples exact
    gap = ~outside
    err_ours = np.sqrt(np.mean((ky[gap] - W[gap, j]) ** 2))
    err_lin = np.sqrt(np.mean((np.interp(frames[gap], frames[outside], W[outside, j]) - W[gap, j]) ** 2))
    assert err_ours < err_lin
    # gap at the start of the curve: one-sided conditioning still fills it
    assert bpy.ops.shapespace.inpaint_gap(data_path=path, index=0, frame_start=2, frame_end=8) == {"FINISHED"}
    # bad input leaves the file unchanged
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="has no curve"):
        bpy.ops.shapespace.inpaint_gap(data_path='key_blocks["nope"].value', index=0, frame_start=5, frame_end=9)
    with pytest.raises(RuntimeError, match="outside the animation"):
        bpy.ops.shapespace.inpaint_gap(data_path=path, index=0, frame_start=500, frame_end=510)
    with pytest.raises(RuntimeError, match="ends .* before it starts"):
        bpy.ops.shapespace.inpaint_gap(data_path=path, index=0, frame_start=50, frame_end=40)
    assert blend_fingerprint() == before


def test_inpaint_constant_curve_stays_constant(registered):
    ob = _facecap()
    key = ob.data.shape_keys
    act = bpy.data.actions.new("flat")
    actions.assign_action(key, act)
    frames = np.arange(1.0, 61.0)
    actions.write_curve(key, actions.shape_key_path("jawOpen"), frames, np.full(frames.size, 0.25))
    actions.write_curve(key, actions.shape_key_path("eyeBlink_L"), frames, np.sin(frames / 5) * 0.4 + 0.5)
    assert bpy.ops.shapespace.inpaint_gap(data_path=actions.shape_key_path("jawOpen"), index=0,
                                          frame_start=20, frame_end=30) == {"FINISHED"}
    ky = actions.read_curve(actions.shape_key_curves(ob, act)["jawOpen"])[1]
    np.testing.assert_allclose(ky, 0.25, atol=1e-7)


# --------------------------------------------------------------------------- pose-space confidence
def test_pose_space_confidence_is_zero_at_examples_and_grows_between(registered):
    import_file(os.path.join(ASSETS, "cesium_man", "CesiumMan.glb"))
    ob = next(o for o in bpy.data.objects if o.type == "MESH")
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    bpy.context.view_layer.objects.active = ob
    bone = next(b for b in arm.pose.bones if "arm" in b.name.lower() or "elbow" in b.name.lower())
    bone.rotation_mode = "XYZ"
    for angle in (1.2, 0.0):
        bone.rotation_euler = (angle, 0.0, 0.0)
        bpy.context.view_layer.update()
        assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    bone.rotation_euler = (0.0, 0.0, 0.0)
    bpy.context.view_layer.update()
    assert bpy.ops.shapespace.psd_confidence(heat_map=True) == {"FINISHED"}
    at_example = ob.shapespace_face.confidence
    bone.rotation_euler = (0.6, 0.0, 0.0)
    bpy.context.view_layer.update()
    assert bpy.ops.shapespace.psd_confidence(heat_map=True) == {"FINISHED"}
    between = ob.shapespace_face.confidence
    assert at_example < 1e-6 < between < 1.0
    attr = ob.data.color_attributes[posespace.CONFIDENCE_ATTRIBUTE]
    assert len(attr.data) == len(ob.data.vertices)


def test_inpaint_leaves_every_key_outside_the_gap_as_it_was(registered):
    ob = _facecap()
    key = ob.data.shape_keys
    act = bpy.data.actions.new("handles")
    actions.assign_action(key, act)
    frames = np.arange(1.0, 121.0)
    fc = actions.write_curve(key, actions.shape_key_path("jawOpen"), frames, 0.5 + 0.4 * np.sin(frames / 7.0),
                             interpolation="BEZIER")
    actions.write_curve(key, actions.shape_key_path("eyeBlink_L"), frames, 0.5 + 0.4 * np.sin(frames / 7.0 + 0.3))
    for kp in list(fc.keyframe_points)[::9]:                     # hand-edited handles on some keys
        kp.handle_left_type = kp.handle_right_type = "FREE"
        kp.handle_right = (kp.co[0] + 0.4, kp.co[1] + 0.05)
    fc.update()

    def snapshot():
        return {round(kp.co[0]): (tuple(kp.co), tuple(kp.handle_left), tuple(kp.handle_right), kp.interpolation,
                                  kp.handle_left_type) for kp in fc.keyframe_points}
    before = snapshot()
    assert bpy.ops.shapespace.inpaint_gap(data_path=actions.shape_key_path("jawOpen"), index=0,
                                          frame_start=50, frame_end=60) == {"FINISHED"}
    after = snapshot()
    outside = [f for f in before if f < 49 or f > 61]          # neighbours' auto handles may follow the fill
    for f in outside:
        co, hl, hr, interp, htype = before[f]
        assert after[f][0] == co and after[f][3:] == (interp, htype)
        if htype == "FREE":     # hand-edited handles stay exactly; automatic ones are Blender's to recompute
            assert after[f][1:3] == (hl, hr)
    assert sorted(after) == sorted(before)


def test_make_convex_projects_the_sliders_like_a_qp(registered):
    """Make Convex moves the sliders to the nearest point of {0 ≤ w ≤ 1 (and the slider range), Σw ≤ 1};
    reference: quadprog on the same projection."""
    import quadprog
    ob = _facecap(with_animation=False)
    model = shapekeys.read_blendshape_model(ob)
    w = np.random.default_rng(5).uniform(0.0, 0.5, model.n_targets)
    _set(ob, model.names, w)
    assert bpy.ops.shapespace.make_convex() == {"FINISHED"}
    got = shapekeys.read_slider_values(ob, model.names)
    n = model.n_targets
    # min ½‖x − w‖² s.t. x ≥ 0, −x ≥ −1, −Σx ≥ −1   (quadprog: Cᵀ x ≥ b)
    C = np.hstack([np.eye(n), -np.eye(n), -np.ones((n, 1))])
    b = np.concatenate([np.zeros(n), -np.ones(n), [-1.0]])
    ref = quadprog.solve_qp(np.eye(n), w, C, b)[0]
    np.testing.assert_allclose(got, ref, atol=1e-6)      # float32 slider storage
    assert got.sum() <= 1.0 + 1e-6
