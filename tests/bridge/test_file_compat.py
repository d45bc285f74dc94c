"""A .blend saved by ShapeSpace 0.1.0 still opens and works (issue #15).

``tests/data/shapespace_0_1_0.blend`` was made by the 0.1.0 add-on (commit e07c414) with
``tests/data/make_v010_fixture.py``; ``shapespace_0_1_0.json`` holds what 0.1.0 and Blender's depsgraph
produced from it (evaluated vertex fingerprints, operator results).  These tests open the file with the
*current* add-on and check, through operators and RNA only, that every piece of stored state still loads
and gives the same results: pins and the drag solve, in-between/combination drivers, the retarget
mapping override and Discard Result, the whole-face / PCA copies and the face prior, pose-space
examples (pose, pseudo pose, driven-target values) and Check Rig.

The storage tests at the end check that blobs the current add-on writes carry ``schema_version`` (through
``bridge/storage.py``) next to the version-0 blobs it reads, and that a plain open + save upgrades *every*
blob (the save_pre pass of ``bridge.storage.upgrade_file``).
"""
import json
import os
import re

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_support import draw_panel  # noqa: E402
from shapespace.bridge import posespace  # noqa: E402
from shapespace.bridge.posespace import stored as posespace_stored  # noqa: E402

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")
BLEND = os.path.join(DATA, "shapespace_0_1_0.blend")
with open(os.path.join(DATA, "shapespace_0_1_0.json")) as _fh:
    SIDE = json.load(_fh)
TOL = 1e-5            # of the bounding-box diagonal, for evaluated positions
SLIDER_TOL = 1e-5     # sliders are stored in single precision
KEY_BLOBS = ("shapespace_driven", "shapespace_mapping", "shapespace_last_retarget", "shapespace_representation",
             "shapespace_face_prior", "shapespace_analysis")
EXAMPLE_BLOBS = ("pose", "pseudo_pose", "target_values")

# ----------------------------------------------------------------------------------------- helpers
@pytest.fixture
def old_file(registered):
    """The 0.1.0 file, opened with the current add-on registered."""
    assert bpy.ops.wm.open_mainfile(filepath=BLEND) == {"FINISHED"}
    return bpy.data


def _activate(name):
    ob = bpy.data.objects[name]
    for o in bpy.context.view_layer.objects:
        o.select_set(o == ob)
    bpy.context.view_layer.objects.active = ob
    return ob


def _evaluated(ob) -> np.ndarray:
    """Blender's evaluated object-space vertex positions (depsgraph), float64 (p, 3)."""
    bpy.context.view_layer.update()
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    try:
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64)


def _assert_fingerprint(ob, vertices, want, what):
    co = _evaluated(ob)
    err = np.abs(co[vertices] - np.array(want["co"])).max() / want["diag"]
    assert err < TOL, f"{what}: evaluated positions differ from 0.1.0 by {err:.3g} of the size"
    np.testing.assert_allclose(co.mean(axis=0), want["mean"], atol=TOL * want["diag"], err_msg=what)
    np.testing.assert_allclose(np.sqrt((co ** 2).mean(axis=0)), want["rms"], atol=TOL * want["diag"], err_msg=what)


def _values(ob, names):
    blocks = ob.data.shape_keys.key_blocks
    return np.array([blocks[n].value for n in names])


def _set_values(ob, values: dict):
    blocks = ob.data.shape_keys.key_blocks
    for name, v in values.items():
        blocks[name].value = v


def _key_co(kb) -> np.ndarray:
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def _pin_position(co, pin) -> np.ndarray:
    return sum(w * co[v] for v, w in zip(pin.vertices, pin.weights))


def _set_pose(arm, pose: dict):
    for bone, q in pose.items():
        arm.pose.bones[bone].rotation_quaternion = q
    bpy.context.view_layer.update()


def _reports(text: str) -> list:
    """Operator reports Blender printed (``Info: …``, ``Warning: …``, ``Error: …``) in captured output."""
    return re.findall(r"^(Info|Warning|Error): (.*)$", text, re.MULTILINE)


def _fcurves(action):
    if "slots" not in bpy.types.Action.bl_rna.properties:
        return list(action.fcurves)
    return [fc for layer in action.layers for strip in layer.strips for bag in strip.channelbags
            for fc in bag.fcurves]


def _without_version(blob: dict) -> dict:
    return {k: v for k, v in blob.items() if k != "schema_version"}


def _draw_panels(context) -> dict:
    """``{panel idname: [label texts]}`` for every ShapeSpace sidebar panel whose poll passes."""
    drawn, classes, stack = {}, [], list(bpy.types.Panel.__subclasses__())
    while stack:
        cls = stack.pop()
        classes.append(cls)
        stack += cls.__subclasses__()
    for cls in classes:
        idname = getattr(cls, "bl_idname", "") or cls.__name__
        if not idname.startswith("SHAPESPACE_PT") or (hasattr(cls, "poll") and not cls.poll(context)):
            continue
        drawn[idname] = draw_panel(cls, context, strict=False, bl_idname=idname).labels
    return drawn


# ----------------------------------------------------------------------------------------- pins
def test_pins_are_listed_and_solve_pins_moves_the_pin_to_its_target(old_file):
    side = SIDE["Pinned"]
    ob = _activate("Pinned")
    st = ob.shapespace
    assert len(st.pins) == len(side["pins"])
    for pin, want in zip(st.pins, side["pins"]):
        assert list(pin.vertices) == want["vertices"] and pin.stationary == want["stationary"]
        np.testing.assert_allclose(pin.weights, want["weights"], atol=1e-7)
        np.testing.assert_allclose(pin.target, want["target"], atol=1e-7)
    s = side["settings"]
    assert (st.mode, st.prior_form, st.prior_start, st.prior_end, st.active_pin) == (
        s["mode"], s["prior_form"], s["prior_start"], s["prior_end"], s["active_pin"])
    assert st.alpha == pytest.approx(s["alpha"]) and st.mu == pytest.approx(s["mu"])
    assert st.prior_action is not None and st.prior_action.name == s["prior_action"]
    names = sorted(side["sliders"])
    saved = np.array([side["sliders"][n] for n in names])
    np.testing.assert_allclose(_values(ob, names), saved, atol=1e-7)

    solve = side["solve"]
    target = np.array(solve["target"])
    pin = st.pins[solve["pin"]]
    before = np.linalg.norm(_pin_position(_evaluated(ob), pin) - target)
    assert bpy.ops.shapespace.solve_pins(pin=solve["pin"], target=target) == {"FINISHED"}
    want = [solve["sliders"]["DIRECT"][n] for n in names]
    np.testing.assert_allclose(_values(ob, names), want, atol=SLIDER_TOL)
    np.testing.assert_allclose(pin.target, target, atol=1e-6)
    after = np.linalg.norm(_pin_position(_evaluated(ob), pin) - target)
    assert after < 0.5 * before, (before, after)       # the other pins hold it back a little (α, stationary)

    # learned mode trains its prior from the stored action and frame range
    st.mode = "LEARNED"
    _set_values(ob, dict(zip(names, saved)))
    assert bpy.ops.shapespace.solve_pins(pin=solve["pin"], target=target) == {"FINISHED"}
    want = [solve["sliders"]["LEARNED"][n] for n in names]
    np.testing.assert_allclose(_values(ob, names), want, atol=SLIDER_TOL)


def test_make_convex_on_the_old_rig(old_file):
    side = SIDE["Pinned"]["make_convex"]
    ob = _activate("Pinned")
    _set_values(ob, side["before"])
    assert bpy.ops.shapespace.make_convex() == {"FINISHED"}
    names = sorted(side["after"])
    np.testing.assert_allclose(_values(ob, names), [side["after"][n] for n in names], atol=SLIDER_TOL)


# ----------------------------------------------------------------------------------------- driven keys
def test_inbetween_and_combination_drivers_play_as_in_0_1_0(old_file):
    side = SIDE["Driven"]
    ob = _activate("Driven")
    key = ob.data.shape_keys
    assert _without_version(json.loads(key["shapespace_driven"])) == side["metadata"]
    drivers = {fc.data_path: fc.driver for fc in key.animation_data.drivers}
    assert set(drivers) == {'key_blocks["up@0.5"].value', 'key_blocks["up+wide"].value'}
    assert all(d.is_simple_expression for d in drivers.values())
    for state in side["states"]:
        _set_values(ob, state["sliders"])
        _assert_fingerprint(ob, side["vertices"], state, f"Driven at {state['sliders']}")


def test_a_new_inbetween_joins_the_old_ones(old_file):
    """The current add-on extends 0.1.0's driven metadata: a quarter in-between re-knots the old half one."""
    side = SIDE["Driven"]
    ob = _activate("Driven")
    blocks = ob.data.shape_keys.key_blocks
    basis, up = _key_co(blocks["Basis"]), _key_co(blocks["up"])
    kb = ob.shape_key_add(name="upQuarter", from_mix=False)
    kb.data.foreach_set("co", (basis + 0.25 * (up - basis) + [0.0, 0.0, 0.02]).astype(np.float32).ravel())
    ob.active_shape_key_index = blocks.find("upQuarter")
    assert bpy.ops.shapespace.add_inbetween(primary="up", weight=0.25) == {"FINISHED"}
    meta = json.loads(ob.data.shape_keys["shapespace_driven"])
    assert set(meta["inbetweens"]) == {"up@0.5", "up@0.25"} and set(meta["combinations"]) == {"up+wide"}
    for state in side["states"]:        # at 0.5 and at 1 the quarter in-between is off, the old one unchanged
        if state["sliders"]["up"] in (0.5, 1.0):
            _set_values(ob, state["sliders"])
            _assert_fingerprint(ob, side["vertices"], state, f"Driven at {state['sliders']}")


# ----------------------------------------------------------------------------------------- retarget
def test_discard_restores_the_previous_action_and_the_override_still_maps(old_file):
    side = SIDE["Face"]
    ob = _activate("Face")
    key = ob.data.shape_keys
    scene = bpy.context.scene
    assert key.animation_data.action.name == side["result_action"]
    scene.frame_set(side["frame"])
    _assert_fingerprint(ob, side["vertices"], side["at_result"], "Face playing the retarget result")
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert key.animation_data.action.name == side["capture_action"]
    assert side["result_action"] not in bpy.data.actions
    assert "shapespace_last_retarget" not in key
    scene.frame_set(side["frame"])
    _assert_fingerprint(ob, side["vertices"], side["at_capture"], "Face playing its capture again")
    with pytest.raises(RuntimeError, match="Nothing retargeted"):
        bpy.ops.shapespace.discard_retarget()
    # the stored override jawOpen → mouthClose × 0.5 + 0.1 is honoured by a new retarget
    copy = side["copy_retarget"]
    assert bpy.ops.shapespace.retarget(action=side["capture_action"], method="copy") == {"FINISHED"}
    curves = {fc.data_path[len('key_blocks["'):-len('"].value')]: fc
              for fc in _fcurves(key.animation_data.action)}
    assert set(curves) == set(copy["curves"])
    for name, values in copy["curves"].items():
        np.testing.assert_allclose([curves[name].evaluate(f) for f in copy["frames"]], values, atol=1e-6,
                                   err_msg=name)
    report = json.loads(key["shapespace_last_retarget"])
    for field in ("method", "frames", "mapped_channels", "previous_action", "source"):
        assert report[field] == copy["report"][field], field


def test_panels_read_the_old_mapping_and_result(old_file):
    ob = _activate("Face")
    drawn = _draw_panels(bpy.context)
    labels = drawn["SHAPESPACE_PT_retarget"]
    assert any("jawOpen" in t and "mouthClose" in t for t in labels), labels
    assert any(t.startswith(SIDE["Face"]["result_action"]) for t in labels), labels
    assert not any("schema_version" in t for t in labels), labels
    assert "SHAPESPACE_PT_face_space" in drawn
    for name in ("Pinned", "Driven", "Face_wholeface", "Face_pca", "Limb"):
        _activate(name)
        for panel, labels in _draw_panels(bpy.context).items():
            assert not any("schema_version" in t for t in labels), (name, panel, labels)
    assert ob.shapespace_retarget.action.name == SIDE["Face"]["capture_action"]


# ----------------------------------------------------------------------------------------- face space
def test_face_prior_and_flagged_frames_are_readable(old_file):
    side = SIDE["Face"]
    ob = _activate("Face")
    flagged = [[i.frame, i.reason] for i in ob.shapespace_face.implausible]
    assert flagged == side["implausible"]["frames"]
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}      # back to the capture the prior saw
    assert bpy.ops.shapespace.find_implausible_frames(alpha=side["implausible"]["alpha"]) == {"FINISHED"}
    assert [[i.frame, i.reason] for i in ob.shapespace_face.implausible] == side["implausible"]["frames"]


def test_whole_face_and_pca_copies_are_readable(old_file):
    side = SIDE["Face_wholeface"]
    whole = _activate("Face_wholeface")
    for state in side["states"]:
        _set_values(whole, state["sliders"])
        _assert_fingerprint(whole, side["vertices"], state, f"whole-face copy at {state['sliders']}")
    assert bpy.ops.shapespace.make_convex() == {"FINISHED"}
    before = set(bpy.data.objects.keys())
    assert bpy.ops.shapespace.convert_rig(form="DELTA") == {"FINISHED"}   # reads the representation blob
    (back,) = [bpy.data.objects[n] for n in bpy.data.objects.keys() if n not in before]
    face = bpy.data.objects["Face"]
    fb = face.data.shape_keys.key_blocks
    bb = back.data.shape_keys.key_blocks
    size = np.ptp(_key_co(fb[0]), axis=0).max()
    np.testing.assert_allclose(_key_co(bb[0]), _key_co(fb[0]), atol=1e-6 * size)
    for kb in fb[1:]:
        np.testing.assert_allclose(_key_co(bb[kb.name]), _key_co(kb), atol=1e-6 * size, err_msg=kb.name)
    _activate("Face_pca")
    with pytest.raises(RuntimeError, match="not a whole-face rig"):
        bpy.ops.shapespace.convert_rig(form="DELTA")


# ----------------------------------------------------------------------------------------- pose space
def test_update_correctives_reproduces_the_0_1_0_sculpts(old_file):
    side = SIDE["Limb"]
    ob = _activate("Limb")
    arm = bpy.data.objects["Armature"]
    st = ob.shapespace_psd
    assert [[r.kind, r.source, r.scale] for r in st.readers] == side["readers"]
    assert st.armature == arm and [t.data_path for t in st.targets] == ['["exertion"]']
    for ex, want in zip(st.examples, side["examples"]):
        assert ex.name == want["name"] and ex.sculpt.name == want["sculpt"]
    for name, state in side["states"].items():
        _set_pose(arm, state["pose"])
        arm["exertion"] = -1.0
        assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
        weights = [ob.data.shape_keys.key_blocks[n].value for n in state["weights"]]
        np.testing.assert_allclose(weights, list(state["weights"].values()), atol=SLIDER_TOL, err_msg=name)
        assert arm["exertion"] == pytest.approx(state["exertion"], abs=SLIDER_TOL), name
        _assert_fingerprint(ob, side["vertices"], state, f"Limb at {name}")
    # at the first example's pose the mesh is the sculpt (its posed copy, kept in the file)
    _set_pose(arm, side["states"]["ex1"]["pose"])
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    sculpt = st.examples[0].sculpt
    co = np.empty(len(sculpt.data.vertices) * 3, np.float32)
    sculpt.data.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)
    diag = side["states"]["ex1"]["diag"]
    assert np.abs(_evaluated(ob) - co).max() / diag < TOL
    assert np.abs(co[side["vertices"]] - np.array(side["sculpt_at_ex1"]["co"])).max() / diag < TOL
    assert bpy.ops.shapespace.psd_confidence(heat_map=False) == {"FINISHED"}
    assert ob.shapespace_face.confidence == pytest.approx(0.0, abs=1e-6)


def _trained_skin_weighted(ob) -> bool:
    """Update Correctives with Weighted PSD; whether the model it trained uses the skin-weighted distance only."""
    ob.shapespace_psd.method = "WPSD"
    _set_pose(bpy.data.objects["Armature"], SIDE["Limb"]["states"]["between"]["pose"])
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    deformer = posespace.cached_model(ob)[0]
    return deformer.method == "wpsd" and deformer.blend is None and deformer.pairs is None


def test_0_1_0_pose_spaces_keep_the_skin_weighted_distance(old_file, tmp_path):
    """Issue #26 item 18: new pose spaces default to Blended, but 0.1.0 stored no distance (Blender saves only
    values set): opened, the pose space keeps Skin Weighted, stored explicitly, trains with it, and so after a
    save and reopen."""
    ob = _activate("Limb")
    st = ob.shapespace_psd
    assert st.wpsd_distance == "SKIN" and st.is_property_set("wpsd_distance")
    assert _trained_skin_weighted(ob)
    path = str(tmp_path / "resaved.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    st = bpy.data.objects["Limb"].shapespace_psd
    assert st.wpsd_distance == "SKIN" and st.is_property_set("wpsd_distance")


def test_a_0_1_0_pose_space_appended_into_a_new_file_keeps_skin_weighted(registered, tmp_path):
    """Appending runs no load handler: the unset distance of a pose space with examples still reads as the
    0.1.0 one wherever ShapeSpace reads it, and the next save stores it."""
    assert bpy.ops.wm.read_homefile(use_empty=True) == {"FINISHED"}
    with bpy.data.libraries.load(BLEND, link=False) as (src, dst):
        dst.objects = ["Limb", "Armature"]
    for o in dst.objects:
        bpy.context.scene.collection.objects.link(o)
    ob = _activate("Limb")
    st = ob.shapespace_psd
    assert len(st.examples) and not st.is_property_set("wpsd_distance")
    assert posespace_stored.wpsd_distance(st) == "SKIN"
    assert _trained_skin_weighted(ob)
    path = str(tmp_path / "appended.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    st = bpy.data.objects["Limb"].shapespace_psd
    assert st.wpsd_distance == "SKIN" and st.is_property_set("wpsd_distance")


def test_old_examples_can_be_moved_back_and_extended(old_file):
    side = SIDE["Limb"]
    ob = _activate("Limb")
    arm = bpy.data.objects["Armature"]
    st = ob.shapespace_psd
    st.active_example = 1
    assert bpy.ops.shapespace.psd_move_example(reset=True) == {"FINISHED"}
    _set_pose(arm, side["states"]["ex2"]["pose"])
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert ob.data.shape_keys.key_blocks[st.examples[1].name].value == pytest.approx(1.0, abs=SLIDER_TOL)
    _set_pose(arm, side["states"]["between"]["pose"])
    assert bpy.ops.shapespace.psd_add_example(sculpt_copy=False) == {"FINISHED"}
    assert bpy.ops.shapespace.psd_record_targets() == {"FINISHED"}
    _set_pose(arm, side["states"]["ex1"]["pose"])
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert ob.data.shape_keys.key_blocks[st.examples[0].name].value == pytest.approx(1.0, abs=SLIDER_TOL)


# ----------------------------------------------------------------------------------------- check rig
@pytest.mark.parametrize("name", sorted(SIDE["check_rig"]))
def test_check_rig_finds_no_damage(old_file, capfd, name):
    _activate(name)
    capfd.readouterr()
    assert bpy.ops.shapespace.check_rig() == {"FINISHED"}
    out = capfd.readouterr()
    reports = _reports(out.out + out.err)
    assert reports, "no operator report captured"
    assert not [r for r in reports if r[0] != "Info"], reports
    assert any(name in text for _, text in reports), reports


# ----------------------------------------------------------------------------------------- storage
def _example_blobs(ob):
    return {(ex.name, attr): getattr(ex, attr) for ex in ob.shapespace_psd.examples for attr in EXAMPLE_BLOBS
            if getattr(ex, attr)}


def _key_blobs():
    return {(o.name, p): o.data.shape_keys[p] for o in bpy.data.objects if o.type == "MESH" and o.data.shape_keys
            for p in KEY_BLOBS if p in o.data.shape_keys}


def _versioned(text) -> bool:
    data = json.loads(text)
    return isinstance(data, dict) and isinstance(data.get("schema_version"), int) and data["schema_version"] >= 1


def test_the_file_holds_version_0_blobs(old_file):
    """Guard for the fixture itself: every blob is as 0.1.0 wrote it (no schema_version)."""
    blobs = _key_blobs()
    assert {p for _, p in blobs} == set(KEY_BLOBS)
    assert not [k for k, v in blobs.items() if _versioned(v)]
    examples = _example_blobs(bpy.data.objects["Limb"])
    assert {a for _, a in examples} == set(EXAMPLE_BLOBS)
    assert all(isinstance(json.loads(v), list) for v in examples.values())


def test_blobs_rewritten_by_the_current_add_on_carry_schema_version(old_file, tmp_path):
    """Every kind of blob, written once by the current add-on, is versioned after save and reopen — and the
    results read back the same."""
    ob = _activate("Driven")
    blocks = ob.data.shape_keys.key_blocks
    kb = ob.shape_key_add(name="upQuarter", from_mix=False)
    kb.data.foreach_set("co", _key_co(blocks["up"]).astype(np.float32).ravel() * 0.25
                        + _key_co(blocks["Basis"]).astype(np.float32).ravel() * 0.75)
    ob.active_shape_key_index = blocks.find("upQuarter")
    assert bpy.ops.shapespace.add_inbetween(primary="up", weight=0.25) == {"FINISHED"}
    _activate("Face")
    assert bpy.ops.shapespace.set_mapping(source="mouthSmileLeft", target="mouthSmileRight") == {"FINISHED"}
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert bpy.ops.shapespace.learn_face_prior() == {"FINISHED"}
    assert bpy.ops.shapespace.analyse_rig() == {"FINISHED"}
    assert bpy.ops.shapespace.retarget(action=SIDE["Face"]["capture_action"], method="copy") == {"FINISHED"}
    before = set(bpy.data.objects.keys())
    assert bpy.ops.shapespace.convert_rig(form="WHOLE_FACE") == {"FINISHED"}
    (whole,) = set(bpy.data.objects.keys()) - before
    limb = _activate("Limb")
    arm = bpy.data.objects["Armature"]
    _set_pose(arm, SIDE["Limb"]["states"]["between"]["pose"])
    limb.shapespace_psd.active_example = 1
    assert bpy.ops.shapespace.psd_move_example() == {"FINISHED"}
    assert bpy.ops.shapespace.psd_record_targets() == {"FINISHED"}
    assert bpy.ops.shapespace.psd_add_example(sculpt_copy=False) == {"FINISHED"}
    path = str(tmp_path / "resaved.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    blobs = _key_blobs()
    rewritten = [("Driven", "shapespace_driven"), ("Face", "shapespace_mapping"), ("Face", "shapespace_face_prior"),
                 ("Face", "shapespace_analysis"), ("Face", "shapespace_last_retarget"),
                 (whole, "shapespace_representation")]
    unversioned = [k for k in rewritten if not _versioned(blobs[k])]
    ex = {k: v for k, v in _example_blobs(bpy.data.objects["Limb"]).items()
          if k in {("PSD_02", "pseudo_pose"), ("PSD_02", "target_values"), ("PSD_03", "pose"),
                   ("PSD_03", "target_values")}}
    assert len(ex) == 4
    unversioned += [k for k, v in ex.items() if not _versioned(v)]
    assert not unversioned, f"written by the current add-on without schema_version: {unversioned}"
    # and everything still works on the mixed (version 0 and 1) file
    mapping = _without_version(json.loads(blobs[("Face", "shapespace_mapping")]))
    assert set(mapping) == {"jawOpen", "mouthSmileLeft"}
    limb = _activate("Limb")
    _set_pose(bpy.data.objects["Armature"], SIDE["Limb"]["states"]["ex1"]["pose"])
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    _activate("Face")
    assert bpy.ops.shapespace.find_implausible_frames() == {"FINISHED"}


def test_saving_with_the_current_add_on_upgrades_every_blob(old_file, tmp_path):
    """Open the 0.1.0 file, save it, reopen: every stored blob carries schema_version (the save_pre
    upgrade pass, bridge.storage.upgrade_file)."""
    path = str(tmp_path / "upgraded.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    stale = [k for k, v in _key_blobs().items() if not _versioned(v)]
    stale += [k for k, v in _example_blobs(bpy.data.objects["Limb"]).items() if not _versioned(v)]
    assert not stale, f"still version 0 after a save with the current add-on: {stale}"
