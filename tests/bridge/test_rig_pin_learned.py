"""Issue #25 item 2: the Learned prior on a rig face's Pin tool (``bridge.rig.tool`` over ``RigDrag``).

The driver rig of ``rigs.py`` (facecap's head driven through drivers by bone locations, a bone rotation and a
custom property, every channel on the control armature) gets a prior action keying its channels over frames 1–40:
both smile controls move together, jaw, brow and blink follow their own curves.  Ground truth: the controls
Blender plays from that action (``frame_set``) for the sampling, the depsgraph-evaluated mesh for the pins, and a
Mahalanobis distance computed here from the action's F-curves (``FCurve.evaluate``) with numpy for the claim that a
Learned drag stays closer to the action's poses than a Direct one.
"""
import numpy as np
import pytest

import rigs
from blender_support import bpy
from shapespace.bridge import actions
from shapespace.bridge import rig as brig
from shapespace.bridge.rig import stored, tool
from shapespace.bridge.rig.drag import sample_action
from shapespace.core.manipulation import Pin
from support import shared
from test_rig import _assert_same_state, _state
from test_rig_drag import _fcurve_keys
from test_rig_pin_tool import _drag, _face, _pins_world

FRAMES = np.arange(1, 41, dtype=np.float64)


def _prior_action(rig, name="smiles"):
    """An action on the control armature keying every channel on frames 1–40 (module doc); not assigned."""
    arm = rig.armature
    t = (FRAMES - 1) / 39.0
    rng = np.random.default_rng(0)
    smile = 0.1 + 0.3 * (0.5 + 0.5 * np.sin(2 * np.pi * t))
    curves = {('pose.bones["ctl_jaw"].location', 1): 0.2 + 0.1 * np.sin(5 * t),
              ('pose.bones["ctl_smile_L"].location', 1): smile + 0.01 * rng.normal(size=t.size),
              ('pose.bones["ctl_smile_R"].location', 1): smile + 0.01 * rng.normal(size=t.size),
              ('pose.bones["ctl_brow"].rotation_euler', 0): 0.3 + 0.2 * np.cos(3 * t),
              ('["blink"]', 0): 0.5 + 0.4 * np.sin(7 * t)}
    before = actions.active_action(arm)
    action = actions.new_action(arm, name)
    for (path, index), values in curves.items():
        actions.write_curve(arm, path, FRAMES, values, index=index)
    arm.animation_data.action = before
    return action


def _learned_face(action, start=1, end=40):
    rig = _face("driver")
    st = rig.mesh.shapespace
    st.prior_action, st.prior_start, st.prior_end = action(rig) if callable(action) else action, start, end
    st.mode = "LEARNED"
    return rig


def _reference_prior(rig, action):
    """Mean and covariance of the controls over the action, from ``FCurve.evaluate`` (numpy only)."""
    table = {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(action, rig.armature)}
    cols = []
    for ch in rig.controls.channels:
        fc = table[(ch.path, max(ch.index, 0))]
        cols.append([fc.evaluate(f) for f in FRAMES])
    x = np.array(cols).T
    return x.mean(0), np.cov(x, rowvar=False)


def test_the_prior_is_sampled_from_the_action_as_blender_plays_it(registered):
    rig = _face("driver")
    action = _prior_action(rig)
    values, keyed = sample_action(rig.controls, action, FRAMES)
    assert keyed.all()
    arm = rig.armature
    actions.assign_action(arm, action)
    for k in (0, 7, 23, 39):
        bpy.context.scene.frame_set(int(FRAMES[k]))
        np.testing.assert_allclose(values[k], brig.read_controls(rig.controls), atol=1e-6)
    arm.animation_data.action = None


def _learned_and_direct(rig, v, target):
    """The same drag of a pin on vertex ``v`` to ``target`` in Learned then in Direct mode (each from the pose at
    mouse-down, the pins removed between): the controls each ends on, and the pin's distance to the target."""
    ob = rig.mesh
    c0 = brig.read_controls(rig.controls)
    out = []
    for mode in ("LEARNED", "DIRECT"):
        ob.shapespace.mode = mode
        drag = tool.drag_for(ob)
        drag = _drag(rig, tool.add_pin(ob, drag, Pin.at_vertex(v)), drag, target)
        assert (drag.rig.prior is not None) == (mode == "LEARNED")
        tool.finish(drag, ob, 1, autokey=False)
        out.append((brig.read_controls(rig.controls), float(np.linalg.norm(_pins_world(rig)[0] - target))))
        brig.apply_controls(rig.controls, c0)
        ob.shapespace.pins.clear()
    return out


def test_a_learned_drag_moves_like_the_actions_moves_not_like_a_direct_one(registered):
    """The move a Learned drag makes (from the pose at mouse-down) is one the action makes: the smile pair together."""
    rig = _learned_face(_prior_action)
    action = rig.mesh.shapespace.prior_action
    _mean, cov = _reference_prior(rig, action)
    c0 = brig.read_controls(rig.controls)
    rest = rig.world_points()
    diag = rigs.diagonal(rest)
    names = [ch.name for ch in rig.controls.channels]
    pose = c0.copy()
    i, j = names.index("ctl_smile_L location Y"), names.index("ctl_smile_R location Y")
    pose[i] = 0.35                                                           # the left smile alone
    brig.apply_controls(rig.controls, pose)
    posed = rig.world_points()
    brig.apply_controls(rig.controls, c0)
    v = int(np.argmax(np.linalg.norm(posed - rest, axis=1)))
    (learned, err_l), (direct, err_d) = _learned_and_direct(rig, v, posed[v])

    def mahalanobis(x):
        d = x - c0
        return float(np.sqrt(d @ np.linalg.solve(cov, d)))

    assert err_d / diag <= 1e-3                                              # Direct reaches the pin
    assert mahalanobis(learned) < 0.5 * mahalanobis(direct), (mahalanobis(learned), mahalanobis(direct))
    assert err_l / diag <= 0.05                                              # the prior gives way to the pin
    # the learned smile pair moves together, as in the action; the direct one moves the left alone
    assert abs(learned[i] - learned[j]) < 0.5 * abs(direct[i] - direct[j])
    assert _fcurve_keys(rig).keys() <= {(rig.armature.name, p, k) for p, k in [(fc.data_path, fc.array_index)
                                                                                for fc in actions.fcurves(action)]}


def _fourier_action(rig):
    """An action whose frames 1–40 make the brow and the blink move together, the smiles together, the jaw alone —
    and, by the discrete orthogonality of whole periods over the 40 frames, no covariance at all between the
    {brow, blink} pair and the others; every mean is far from the rest pose."""
    arm = rig.armature
    k = FRAMES - 1
    w = 2 * np.pi * k / FRAMES.size
    smile = 0.25 + 0.15 * np.sin(2 * w)
    curves = {('pose.bones["ctl_jaw"].location', 1): 0.2 + 0.1 * np.cos(w),
              ('pose.bones["ctl_smile_L"].location', 1): smile,
              ('pose.bones["ctl_smile_R"].location', 1): smile + 0.02 * np.cos(3 * w),
              ('pose.bones["ctl_brow"].rotation_euler', 0): 0.3 + 0.2 * np.sin(4 * w),
              ('["blink"]', 0): 0.5 + 0.3 * np.sin(4 * w) + 0.05 * np.cos(5 * w)}
    before = actions.active_action(arm)
    action = actions.new_action(arm, "fourier")
    for (path, index), values in curves.items():
        actions.write_curve(arm, path, FRAMES, values, index=index)
    arm.animation_data.action = before
    return action


def test_a_learned_drag_keeps_what_the_pin_does_not_need_and_moves_what_the_prior_ties_to_it(registered):
    """A brow pin dragged up: Direct moves the brow alone; Learned also moves the blink (tied to the brow in the
    action) by the amount the prior's quadratic ``(c − c0)ᵀ Σ⁻¹ (c − c0)`` says — the closed-form minimiser over
    the channels the pin does not see, ``Δ_o = −(Σ⁻¹)_oo⁻¹ (Σ⁻¹)_ob Δ_brow``, with Σ computed here from the
    action's F-curves and the natural scales' ridge — and leaves the jaw and the smiles (uncorrelated with the
    brow) exactly where they were at mouse-down, not at the action's mean."""
    rig = _learned_face(_fourier_action)
    action = rig.mesh.shapespace.prior_action
    _mean, cov = _reference_prior(rig, action)
    names = [ch.name for ch in rig.controls.channels]
    b, o = names.index("ctl_brow rotation X"), [names.index(n) for n in names if n != "ctl_brow rotation X"]
    tied = next(i for i, n in enumerate(names) if "blink" in n)
    free = [names.index(n) for n in ("ctl_jaw location Y", "ctl_smile_L location Y", "ctl_smile_R location Y")]
    assert np.abs(cov[np.ix_([b, tied], free)]).max() < 1e-9                # the action's own claim
    c0 = brig.read_controls(rig.controls)
    rest = rig.world_points()
    diag = rigs.diagonal(rest)
    pose = c0.copy()
    pose[b] += 0.05
    brig.apply_controls(rig.controls, pose)
    posed = rig.world_points()
    for k in o:                                                              # the brow pin sees the brow alone
        other = c0.copy()
        other[k] += 0.05
        brig.apply_controls(rig.controls, other)
        v = int(np.argmax(np.linalg.norm(posed - rest, axis=1)))
        assert np.linalg.norm(rig.world_points()[v] - rest[v]) < 1e-6 * diag, names[k]
    brig.apply_controls(rig.controls, c0)
    v = int(np.argmax(np.linalg.norm(posed - rest, axis=1)))
    ob = rig.mesh
    drag = tool.drag_for(ob)
    drag = _drag(rig, tool.add_pin(ob, drag, Pin.at_vertex(v)), drag, posed[v])
    ev = drag.rig.ev
    tool.finish(drag, ob, 1, autokey=False)
    learned = brig.read_controls(rig.controls)
    brig.apply_controls(rig.controls, c0)
    ob.shapespace.pins.clear()
    ob.shapespace.mode = "DIRECT"
    (direct, err_d), = [_learned_and_direct(rig, v, posed[v])[1]]
    assert err_d / diag <= 1e-3
    np.testing.assert_array_equal(direct[o], c0[o])                          # Direct: the brow alone
    # the prior's quadratic, written here: Σ + the ridge ε σ̄² u² / s² (σ̄²: mean non-zero variance in surface units)
    z = ev.controls.scale / (ev.diagonal / 30.0)
    var = np.linalg.eigvalsh(cov * np.outer(z, z))
    sigma2 = var[var > 1e-12 * var.max()].mean()
    P = np.linalg.inv(cov + np.diag(0.1 * sigma2 / z ** 2))
    d_b = learned[b] - c0[b]
    assert d_b > 0.5 * (pose[b] - c0[b])                                     # the pin moved the brow
    expect = -np.linalg.solve(P[np.ix_(o, o)], P[o, b]) * d_b
    np.testing.assert_allclose(learned[o] - c0[o], expect, atol=0.03 * abs(expect).max())
    assert learned[tied] - c0[tied] > 0.5 * d_b * cov[tied, b] / cov[b, b]   # the blink moves along
    np.testing.assert_allclose(learned[free], c0[free], atol=1e-6)           # the rest stays at mouse-down


def test_learned_release_keys_and_cancel_restores(registered):
    rig = _learned_face(_prior_action)
    ob = rig.mesh
    before = _state(rig)
    rest = rig.world_points()
    v = int(np.argmax(rest[:, 2]))
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(v))
    pins = len(ob.shapespace.pins)
    drag = _drag(rig, index, drag, rest[v] + 0.01 * rigs.diagonal(rest), moves=2)
    drag.cancel(ob)
    _assert_same_state(before, _state(rig))
    assert len(ob.shapespace.pins) == pins - 1


def _no_curves(rig):
    action = bpy.data.actions.new("elsewhere")
    ob = bpy.data.objects.new("Other", None)
    bpy.context.scene.collection.objects.link(ob)
    actions.assign_action(ob, action)
    actions.write_curve(ob, "location", FRAMES, FRAMES * 0.1, index=0)
    return action


def _flat(rig):
    action = _prior_action(rig, "flat")
    for fc in actions.fcurves(action, rig.armature):
        for k in fc.keyframe_points:
            k.co.y = k.handle_left.y = k.handle_right.y = 0.25
        fc.update()
    return action


@pytest.mark.parametrize("case, start, end, message", [
    (None, 1, 40, "learned mode needs a prior action"),
    (_no_curves, 1, 40, "keys none of"),
    (_prior_action, 5, 5, "at least 2 frames"),
    (_prior_action, 9, 3, "frame range is empty"),
    (_flat, 1, 40, "moves none of the control channels"),
])
def test_a_prior_that_cannot_train_is_refused_by_name_before_anything_changes(registered, case, start, end, message):
    rig = _learned_face(case if case is not None else None, start, end)
    ob = rig.mesh
    before = _state(rig)
    with pytest.raises(Exception) as exc:
        drag = tool.drag_for(ob)
        drag.grab(ob, tool.add_pin(ob, drag, Pin.at_vertex(0)), created=True)
    assert message in str(exc.value)
    if case is _no_curves:
        assert "'elsewhere'" in str(exc.value) and repr(ob.name) in str(exc.value)
    _assert_same_state(before, _state(rig))
    assert len(ob.shapespace.pins) == 0


def _nan_key(rig):
    action = _prior_action(rig, "broken")
    fc = next(fc for fc in actions.fcurves(action, rig.armature) if "ctl_brow" in fc.data_path)
    k = fc.keyframe_points[10]
    k.co.y = k.handle_left.y = k.handle_right.y = float("nan")
    return action


def test_a_non_finite_key_in_the_prior_action_is_refused_by_name(registered):
    rig = _learned_face(_nan_key)
    ob = rig.mesh
    before = _state(rig)
    with pytest.raises(Exception) as exc:
        tool.drag_for(ob)
    assert "'broken'" in str(exc.value) and "'ctl_brow rotation X'" in str(exc.value), str(exc.value)
    _assert_same_state(before, _state(rig))


@pytest.mark.skipif(not actions.LAYERED, reason="one action for two datablocks needs slots (Blender 4.4+)")
def test_one_slotted_action_keys_the_bones_and_the_shape_keys_of_a_hybrid_face(registered):
    rig = _face("hybrid")
    key = rig.mesh.data.shape_keys
    t = (FRAMES - 1) / 39.0
    action = actions.new_action(key, "both")
    actions.write_curve(key, 'key_blocks["mouthSmile_L"].value', FRAMES, 0.5 + 0.4 * np.sin(3 * t))
    actions.assign_action(rig.armature, action)
    actions.write_curve(rig.armature, 'pose.bones["jaw"].rotation_euler', FRAMES, 0.2 * np.cos(2 * t), index=0)
    assert len(action.slots) == 2
    values, keyed = sample_action(rig.controls, action, FRAMES)
    names = [ch.name for ch in rig.controls.channels]
    assert {names[i] for i in np.flatnonzero(keyed)} == {"jaw rotation X", "key mouthSmile_L"}
    for k in (0, 13, 39):
        bpy.context.scene.frame_set(int(FRAMES[k]))
        np.testing.assert_allclose(values[k], brig.read_controls(rig.controls), atol=1e-6)


@pytest.mark.rigify
def test_a_non_finite_quaternion_key_in_the_prior_action_is_refused_naming_action_channel_and_frame(registered):
    """Rigify's face (a control bone in QUATERNION mode): a NaN key on its w curve is refused by the action, the
    channel and the first frame Blender's curve is not finite at, before anything changes."""
    rig = rigs.rigify_rig(shared(*rigs.FACECAP.split("/")))
    stored.add_entries_of(rig.mesh, rig.armature.name, rig.controls.channels)
    ch = rig.controls.channels[0]
    assert ch.rotation_mode == "QUATERNION"
    arm = rig.armature
    before = actions.active_action(arm)
    action = actions.new_action(arm, "broken quaternion")
    for k, values in enumerate((np.ones(FRAMES.size), 0.1 * np.sin(FRAMES), np.zeros(FRAMES.size),
                                np.zeros(FRAMES.size))):
        actions.write_curve(arm, ch.path, FRAMES, values, index=k)
    fc = next(fc for fc in actions.fcurves(action, arm) if fc.data_path == ch.path and fc.array_index == 0)
    for key in fc.keyframe_points:
        key.interpolation = "BEZIER"                     # sampled by FCurve.evaluate, as Blender plays it
    key = fc.keyframe_points[10]
    key.co.y = key.handle_left.y = key.handle_right.y = float("nan")
    first = next(int(f) for f in FRAMES if not np.isfinite(fc.evaluate(f)))   # as Blender plays the curve
    arm.animation_data.action = before
    st = rig.mesh.shapespace
    st.prior_action, st.prior_start, st.prior_end, st.mode = action, 1, 40, "LEARNED"
    state = _state(rig)
    with pytest.raises(Exception) as exc:
        tool.drag_for(rig.mesh)
    message = str(exc.value)
    assert "'broken quaternion'" in message and repr(ch.name) in message and f"frame {first}:" in message, message
    _assert_same_state(state, _state(rig))
