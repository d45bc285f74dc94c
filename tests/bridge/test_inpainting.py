"""Covariance inpainting (thesis 9.3) on a real mocap curve, against Blender's own interpolation."""
import numpy as np

from support import shared
from blender_support import bpy, import_file
from shapespace.bridge import actions
from shapespace.core import facespace as facestats

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
