"""Covariance inpainting (bridge.facespace.inpainting, thesis 9.3): on a real mocap curve against Blender's own
interpolation, through the operator on shape-key curves (every key outside the gap kept), and NaN keys in and
around the gap."""
import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, import_file
from facespace_blender import damage_keyframe, face_sphere, facecap, facecap_action, key_curve, run_on_face
from shapespace.bridge import actions, shapekeys
from shapespace.core import facespace as facestats
from support import shared


# --------------------------------------------------------------------------- inpainting (9.3)
def test_inpaint_gap_on_a_shape_key_curve(registered):
    ob = facecap()
    key = ob.data.shape_keys
    action = facecap_action(ob)
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
    ob = facecap()
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


def test_inpaint_leaves_every_key_outside_the_gap_as_it_was(registered):
    ob = facecap()
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


def test_inpaint_repairs_nan_keys_in_the_gap_and_names_one_outside(registered):
    ob = face_sphere()
    damage_keyframe(ob, "K1", 10)
    path = actions.shape_key_path("K1")
    outcome, message = run_on_face("inpaint_gap", data_path=path, frame_start=8, frame_end=12)
    assert outcome == "finished", message
    assert np.isfinite(actions.read_curve(key_curve(ob, "K1"))[1]).all()
    damage_keyframe(ob, "K1", 25)
    outcome, message = run_on_face("inpaint_gap", data_path=path, frame_start=8, frame_end=12)
    assert outcome == "cancelled" and 'key_blocks["K1"].value' in message and "frame 25" in message, message
    # a damaged context curve is named too (unless the other curves are left out)
    damage_keyframe(ob, "K1", 25, 0.5)
    damage_keyframe(ob, "K0", 3)
    outcome, message = run_on_face("inpaint_gap", data_path=path, frame_start=8, frame_end=12)
    assert outcome == "cancelled" and 'key_blocks["K0"].value' in message and "frame 3" in message, message
    assert run_on_face("inpaint_gap", data_path=path, frame_start=8, frame_end=12,
                       use_other_channels=False)[0] == "finished"


GAP = 20


def _walk():
    """CMU 131_01 (120 fps walk): the armature, its action and {(path, index): F-Curve}."""
    import_file(shared("cmu_mocap", "131_01.bvh"))
    arm = next(ob for ob in bpy.data.objects if ob.type == "ARMATURE")
    action = actions.active_action(arm)
    return arm, action, {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(action, arm)}


def _rot(curves, bone, i):
    return curves[(actions.bone_path(bone, "rotation_euler"), i)]


def _legs(arm, curves):
    """Left knee flexion (the rotation_euler channel with the largest range) first, then both hips'
    three Euler channels and the right knee's flexion; radians, one row per BVH frame."""
    def flexion(bone):
        return max(range(3), key=lambda i: np.ptp(actions.read_curve(_rot(curves, bone, i))[1]))
    knee_axis = flexion("LeftKnee")
    hips = [_rot(curves, h, i) for h in ("LeftHip", "RightHip") for i in range(3)]
    chans = [_rot(curves, "LeftKnee", knee_axis)] + hips + [_rot(curves, "RightKnee", flexion("RightKnee"))]
    frames = actions.read_curve(chans[0])[0]
    np.testing.assert_array_equal(frames, np.arange(1, frames.size + 1))   # one key per BVH frame
    return knee_axis, frames, np.column_stack([actions.read_curve(fc)[1] for fc in chans])


def _blender_across_gap(arm, action, path, index, gap_frames, bezier):
    """Delete the keys inside the gap on a copy of the action and let Blender evaluate the curve."""
    copy = action.copy()
    try:
        fc = next(f for f in actions.fcurves(copy, arm) if f.data_path == path and f.array_index == index)
        if bezier:
            for kp in fc.keyframe_points:
                kp.interpolation = "BEZIER"
        kx = actions.read_curve(fc)[0]
        for i in np.flatnonzero((kx >= gap_frames[0]) & (kx <= gap_frames[-1]))[::-1]:
            fc.keyframe_points.remove(fc.keyframe_points[int(i)])
        fc.update()
        return np.array([fc.evaluate(float(f)) for f in gap_frames])
    finally:
        bpy.data.actions.remove(copy)


def _gap_starts(T, n=6):
    rng = np.random.default_rng(0)
    return np.sort(rng.choice(np.arange(2 * GAP, T - 3 * GAP), size=n, replace=False))


def test_multichannel_inpainting_beats_blender_bezier_on_held_out_knee_gaps():
    arm, action, curves = _walk()
    axis, frames, X = _legs(arm, curves)
    path = actions.bone_path("LeftKnee", "rotation_euler")
    ours, blender = [], []
    for s in _gap_starts(len(frames)):
        truth = X[s:s + GAP, 0]
        known = np.ones(X.shape, dtype=bool)
        known[s:s + GAP, 0] = False                       # only the knee is missing; hips and other knee known
        filled = facestats.inpaint_curve(X, known).value[s:s + GAP, 0]
        bez = _blender_across_gap(arm, action, path, axis, frames[s:s + GAP], bezier=True)
        ours.append(np.sqrt(np.mean((filled - truth) ** 2)))
        blender.append(np.sqrt(np.mean((bez - truth) ** 2)))
    ours_deg, blender_deg = np.degrees(np.mean(ours)), np.degrees(np.mean(blender))
    assert ours_deg < blender_deg, f"ours {ours_deg:.3f}° vs Blender Bézier {blender_deg:.3f}° RMS"


def test_blender_across_a_gap_in_the_imported_linear_curve_is_linear_fill():
    """The BVH importer keys LINEAR interpolation, so Blender's gap interpolation of the imported curve
    is the straight line (the ``linear`` reference of the bench)."""
    arm, action, curves = _walk()
    axis, frames, X = _legs(arm, curves)
    s = _gap_starts(len(frames))[0]
    known = np.ones(len(frames), dtype=bool)
    known[s:s + GAP] = False
    got = _blender_across_gap(arm, action, actions.bone_path("LeftKnee", "rotation_euler"), axis,
                              frames[s:s + GAP], bezier=False)
    np.testing.assert_allclose(got, facestats.linear_fill(X[:, 0], known)[s:s + GAP], atol=1e-6)


def test_inpainting_reproduces_known_samples_exactly():
    arm, action, curves = _walk()
    _, frames, X = _legs(arm, curves)
    starts = _gap_starts(len(frames), n=3)
    known = np.ones(X.shape, dtype=bool)
    for s in starts:
        known[s:s + GAP, 0] = False
    known[starts[1]:starts[1] + 5, 3] = False            # a second channel with its own hole
    multi = facestats.inpaint_curve(X, known).value
    np.testing.assert_allclose(multi[known], X[known], rtol=0, atol=1e-9)
    assert np.isfinite(multi).all()
    single = facestats.inpaint_curve(X[:, 0], known[:, 0]).value
    np.testing.assert_allclose(single[known[:, 0]], X[known[:, 0], 0], rtol=0, atol=1e-9)
    assert np.isfinite(single).all()
