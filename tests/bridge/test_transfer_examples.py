"""Transfer Shapes with examples (issue #22 §5; thesis 3.4.1, Li, Weise & Pauly 2010): target shape keys the
artist made, given as examples of the source's shapes, steer every transferred key.

Source FBHead (Live Link Face), target Face Cap's head with only five of its own keys kept as examples (jawOpen,
mouthSmile_L, eyeBlink_L, browInnerUp, mouthFunnel), the 26 named landmarks of each from
``tools/landmarks/<head>.json``.  Independent reference: Face Cap's artist's own keys for the other shapes, read
from the file before they are deleted — the held-out keys must come closer to them than the plain transfer's.
Through the panel's list and the operator, through ``transfer --examples FILE.json``, and bad examples refused by
name with the file unchanged.
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, draw_panel, evaluated, import_file
from shapespace.bridge import authoring, named_landmarks, shapekeys
from shapespace.core.authoring import named
from shapespace.core.result import Status
from shapespace.panels.authoring import SHAPESPACE_PT_transfer_shapes
from support import ROOT, shared

MARKS = os.path.join(ROOT, "tools", "landmarks")
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")
EXAMPLES = ("jawOpen", "mouthSmile_L", "eyeBlink_L", "browInnerUp", "mouthFunnel")


def _heads(keep=EXAMPLES):
    """(source FBHead, target Face Cap head with only the keys ``keep``, Face Cap's authored deltas by name)."""
    import_file(shared("llf_fbhead", "Live_Link_Face.blend"))
    import_file(shared("facecap", "facecap_decoded.glb"))
    src = bpy.data.objects["FBHead"]
    tgt = bpy.data.objects["Mesh_2"]
    tgt.data.shape_keys.animation_data_clear()
    model = shapekeys.read_blendshape_model(tgt)
    authored = {n: model.deltas[i] for i, n in enumerate(model.names)}
    for kb in list(tgt.data.shape_keys.key_blocks)[1:]:
        if kb.name not in keep:
            tgt.shape_key_remove(kb)
    for ob, tag in ((src, "fbhead"), (tgt, "facecap")):
        for name, vertex in named.load_head_file(os.path.join(MARKS, f"{tag}.json"), len(ob.data.vertices)).items():
            named_landmarks.place(ob, name, vertex)
    st = tgt.shapespace_authoring
    st.source, st.naming, st.unmatched_parts = src, "suffix", "move"
    assert authoring.use_named_landmarks(tgt, src) == len(named.NAMES)
    return src, tgt, authored


def _copy(tgt, name):
    """A copy of the target (mesh, keys, landmarks, settings) to transfer onto without examples."""
    ob = tgt.copy()
    ob.data = tgt.data.copy()
    ob.name = name
    bpy.context.scene.collection.objects.link(ob)
    ob.shapespace_authoring.examples.clear()
    return ob


def _key_coords(ob, names):
    blocks = ob.data.shape_keys.key_blocks
    out = {}
    for n in names:
        co = np.empty(3 * len(ob.data.vertices), np.float32)
        blocks[n].points.foreach_get("co", co)
        out[n] = co
    return out


def _held_out_error(ob, authored, held):
    """‖ΔT − ΔA‖ / ‖ΔA‖ jointly over ``held``, ΔT read from the keys Blender holds."""
    model = shapekeys.read_blendshape_model(ob)
    T = np.stack([model.deltas[model.index(n)] for n in held])
    A = np.stack([authored[n] for n in held])
    return float(np.linalg.norm(T - A) / np.linalg.norm(A))


def test_examples_listed_in_the_panel_steer_the_other_keys_and_are_kept(registered):
    src, tgt, authored = _heads()
    plain = _copy(tgt, "Plain")
    before = _key_coords(tgt, EXAMPLES)
    bpy.context.view_layer.objects.active = tgt
    for name in EXAMPLES:
        tgt.active_shape_key_index = tgt.data.shape_keys.key_blocks.find(name)
        assert bpy.ops.shapespace.add_transfer_example() == {"FINISHED"}
    assert [e.key for e in tgt.shapespace_authoring.examples] == list(EXAMPLES)
    log = draw_panel(SHAPESPACE_PT_transfer_shapes).log
    assert ("label", "Examples: 5") in log and ("list", "examples") in log
    assert {"shapespace.add_transfer_example", "shapespace.remove_transfer_example"} <= {
        name for kind, name in log if kind == "operator"}
    assert bpy.ops.shapespace.transfer_shapes() == {"FINISHED"}
    rep = authoring.transfer_shapes(src, plain, naming="suffix", existing="skip", unmatched_parts="move")
    assert sorted(rep.skipped) == sorted(EXAMPLES)                  # the plain run keeps them by policy
    # the examples are the artist's keys, bit for bit
    assert all(np.array_equal(before[n], co) for n, co in _key_coords(tgt, EXAMPLES).items())
    held = [n for n in authored if n not in EXAMPLES and n in tgt.data.shape_keys.key_blocks
            and np.abs(authored[n]).max() >= 0.05 * max(np.abs(a).max() for a in authored.values())]
    assert len(held) >= 40
    refined, unrefined = _held_out_error(tgt, authored, held), _held_out_error(plain, authored, held)
    print(f"\nheld-out keys vs Face Cap's own: plain {unrefined:.3f}, with 5 examples {refined:.3f}")
    assert refined < unrefined - 0.03
    # what Blender evaluates is the key written (a held-out key at 1)
    model = shapekeys.read_blendshape_model(tgt)
    names = shapekeys.slider_names(tgt)
    shapekeys.write_slider_values(tgt, names, [1.0 if n == "mouthClose" else 0.0 for n in names])
    assert np.abs(evaluated(tgt) - (model.neutral + model.deltas[model.index("mouthClose")])).max() < 1e-5


def test_the_report_names_the_examples_and_what_they_changed(registered):
    src, tgt, _ = _heads()
    rep = authoring.transfer_shapes(src, tgt, naming="suffix", unmatched_parts="move",
                                    examples=[(n, None) for n in EXAMPLES])
    assert sorted(rep.kept) == sorted(EXAMPLES) and not set(EXAMPLES) & set(rep.created)
    assert [e["key"] for e in rep.examples] == list(EXAMPLES)
    assert all(e["weights"] == {e["key"]: 1.0} for e in rep.examples)
    assert max(e["residual_after"] for e in rep.examples) < 1e-6 < min(e["residual_before"] for e in rep.examples)
    assert "eyeBlink_R" in rep.examples_changed and "mouthClose" in rep.examples_changed
    assert len(rep.keys) == len(rep.created)                       # every written key checked, no example
    payload = rep.to_json()
    assert payload["examples"][0]["key"] == "jawOpen" and payload["kept"]


def test_examples_that_contradict_each_other_make_a_warning(registered):
    """Two examples naming the same shape with different sculpts cannot both be reproduced: said by name,
    status WARNING (exit code 1 on the command line)."""
    src, tgt, _ = _heads(keep=("jawOpen", "mouthFunnel"))
    rep = authoring.transfer_shapes(src, tgt, naming="suffix", unmatched_parts="move",
                                    examples=[("jawOpen", None), ("mouthFunnel", {"jawOpen": 1.0})])
    assert rep.status == Status.WARNING and rep.exit_code() == 1
    assert any("example 'jawOpen' is reproduced within" in w for w in rep.warnings)


@pytest.mark.parametrize("examples, message", [
    ([("Nope", None)], "example 'Nope': 'Mesh_2' has no shape key of that name"),
    ([("Basis", None)], "example 'Basis' is the basis of 'Mesh_2'"),
    ([("jawOpen", {"NoShape": 1.0})], "example 'jawOpen': the source rig has no shape 'NoShape'"),
    ([("jawOpen", {"jawOpen": 0.0})], "example 'jawOpen': every weight is zero"),
    ([("jawOpen", {"jawOpen": float("nan")})], "example 'jawOpen': the weight of 'jawOpen' is not finite"),
    ([("jawOpen", {"jawOpen": 1e6})], "example 'jawOpen': the weight of 'jawOpen' is 1e+06: at most 10"),
    ([("jawOpen", None), ("jawOpen", None)], "example 'jawOpen' is listed twice"),
])
def test_bad_examples_are_refused_by_name_and_nothing_changes(registered, examples, message):
    src, tgt, _ = _heads()
    tgt.data.shape_keys.key_blocks[0].name = "Basis"
    before = blend_fingerprint()
    with pytest.raises(Exception, match=message.replace("(", r"\(").replace("+", r"\+")):
        authoring.transfer_shapes(src, tgt, naming="suffix", unmatched_parts="move", examples=examples)
    assert blend_fingerprint() == before


def test_a_sculpt_with_its_weights_in_the_panel_and_bad_weights_refused(registered):
    """An example not named after a source shape needs its weights (name=weight pairs in the panel's list); a
    weight that is no number is refused by the operator, naming it, and nothing changes."""
    src, tgt, _ = _heads(keep=("jawOpen", "mouthFunnel"))
    tgt.data.shape_keys.key_blocks["mouthFunnel"].name = "FunnelSculpt"
    bpy.context.view_layer.objects.active = tgt
    tgt.active_shape_key_index = tgt.data.shape_keys.key_blocks.find("FunnelSculpt")
    assert bpy.ops.shapespace.add_transfer_example() == {"FINISHED"}
    with pytest.raises(RuntimeError, match="is an example already"):
        bpy.ops.shapespace.add_transfer_example()
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="'FunnelSculpt' is not named after a shape of the source rig"):
        bpy.ops.shapespace.transfer_shapes()
    tgt.shapespace_authoring.examples[0].weights = "mouthFunnel=abc"
    with pytest.raises(RuntimeError, match="the weight of 'mouthFunnel' is not a number: 'abc'"):
        bpy.ops.shapespace.transfer_shapes()
    assert blend_fingerprint() == before
    tgt.shapespace_authoring.examples[0].weights = "mouthFunnel=1"
    tgt.shapespace_authoring.existing = "skip"                       # jawOpen is the artist's, not an example
    assert bpy.ops.shapespace.transfer_shapes() == {"FINISHED"}
    blocks = tgt.data.shape_keys.key_blocks
    assert "FunnelSculpt" in blocks and "mouthFunnel" in blocks     # the sculpt is no source name: both kept
    assert bpy.ops.shapespace.remove_transfer_example() == {"FINISHED"}
    assert len(tgt.shapespace_authoring.examples) == 0 and "FunnelSculpt" in blocks


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=600,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def test_command_line_examples_from_a_file_and_from_the_panel(registered, tmp_path):
    src, tgt, authored = _heads(keep=("jawOpen", "mouthFunnel"))
    tgt.name = "Head"
    src_path = str(tmp_path / "template.blend")
    bpy.ops.wm.save_as_mainfile(filepath=src_path, copy=True)
    mesh = src.data
    bpy.data.objects.remove(src)
    bpy.data.meshes.remove(mesh)
    for name in ("Mesh_0", "Mesh_1", "Mesh_3"):
        bpy.data.objects.remove(bpy.data.objects[name])
    tgt_path = str(tmp_path / "target.blend")
    bpy.ops.wm.save_as_mainfile(filepath=tgt_path)
    ex_path = tmp_path / "examples.json"
    ex_path.write_text(json.dumps({"version": 1, "examples": [{"key": "jawOpen"},
                                                              {"key": "mouthFunnel", "weights": {"mouthFunnel": 1}}]}))
    out = str(tmp_path / "rigged.blend")
    base = ["-b", tgt_path, "--command", "shapespace", "transfer", "--source-rig", f"{src_path}:FBHead",
            "--object", "Head", "--naming", "suffix"]
    code, stdout, stderr = _cli(*base, "--examples", str(ex_path), "--out", out)
    assert stdout, stderr
    rep = json.loads(stdout)
    assert code == (0 if rep["status"] == "ok" else 1), stderr
    assert "2 examples (" in stderr and [e["key"] for e in rep["examples"]] == ["jawOpen", "mouthFunnel"]
    assert sorted(rep["kept"]) == ["jawOpen", "mouthFunnel"] and rep["saved"] == out
    bpy.ops.wm.open_mainfile(filepath=out)
    head = bpy.data.objects["Head"]
    model = shapekeys.read_blendshape_model(head)
    assert np.array_equal(model.deltas[model.index("jawOpen")], authored["jawOpen"].astype(np.float32))
    # a damaged entry: one error line naming it, nothing saved; the file is an input, never an output
    ex_path.write_text(json.dumps({"version": 1, "examples": [{"key": "jawOpen", "weights": {"jawOpen": "x"}}]}))
    again = str(tmp_path / "again.blend")
    code, stdout, stderr = _cli(*base, "--examples", str(ex_path), "--out", again)
    errors = [ln for ln in stderr.splitlines() if ln.startswith("shapespace: error:")]
    assert code == 1 and stdout == "" and not os.path.exists(again)
    assert len(errors) == 1 and "examples.json.examples[0].weights.jawOpen: not a number" in errors[0]
    code, _, stderr = _cli(*base, "--examples", str(ex_path), "--out", str(ex_path), "--overwrite")
    assert code == 1 and "input" in stderr
    code, _, stderr = _cli(*base, "--examples", "examples.txt", "--out", again)
    assert code == 2 and "FILE.json of examples" in stderr
    # the panel's list, stored in the file, is the default
    bpy.ops.wm.open_mainfile(filepath=tgt_path)
    head = bpy.data.objects["Head"]
    head.shapespace_authoring.examples.add().key = "jawOpen"
    bpy.ops.wm.save_as_mainfile(filepath=tgt_path)
    code, stdout, stderr = _cli(*base, "--existing", "skip", "--dry-run")
    assert stdout, stderr
    rep = json.loads(stdout)
    assert "1 examples (the panel)" in stderr and rep["kept"] == ["jawOpen"]
    code, stdout, stderr = _cli(*base, "--examples", "none", "--existing", "skip", "--dry-run")
    assert json.loads(stdout)["examples"] == []


def test_an_example_may_weight_a_shape_the_target_keeps_by_policy(registered):
    """Skip Existing keeps the artist's mouthClose; an example that weights it still explains itself with the
    transferred mouthClose (computed, not written), and the artist's key stays as it was."""
    src, tgt, _ = _heads(keep=("jawOpen", "mouthClose", "mouthFunnel"))
    before = _key_coords(tgt, ("mouthClose",))
    rep = authoring.transfer_shapes(src, tgt, naming="suffix", existing="skip", unmatched_parts="move",
                                    examples=[("mouthFunnel", {"mouthFunnel": 1.0, "mouthClose": 0.3})])
    assert "mouthClose" in rep.skipped and "mouthClose" not in rep.created + rep.examples_changed
    assert rep.examples[0]["residual_after"] < 1e-6
    assert np.array_equal(_key_coords(tgt, ("mouthClose",))["mouthClose"], before["mouthClose"])


def _refused(src, tgt, examples, message):
    before = blend_fingerprint()
    with pytest.raises(Exception, match=message):
        authoring.transfer_shapes(src, tgt, naming="suffix", existing="skip", unmatched_parts="move",
                                  examples=examples)
    assert blend_fingerprint() == before


def test_keys_that_do_not_hold_the_whole_shape_are_refused(registered):
    """From review: an example relative to another key, an in-between ShapeSpace drives (its key holds a
    correction), and a key equal to the basis were read as shapes (an in-between example rewrote jawOpen at
    0.49× with status ok; a relative one left its example 95 % off while reporting it reproduced)."""
    from shapespace.bridge import driven
    src, tgt, _ = _heads(keep=("jawOpen", "mouthFunnel", "mouthPucker", "mouthClose"))
    blocks = tgt.data.shape_keys.key_blocks
    blocks["mouthFunnel"].relative_key = blocks["jawOpen"]
    _refused(src, tgt, [("mouthFunnel", None)], "example 'mouthFunnel' of 'Mesh_2' is relative to 'jawOpen'")
    bpy.context.view_layer.objects.active = tgt
    tgt.active_shape_key_index = blocks.find("mouthFunnel")
    with pytest.raises(RuntimeError, match="is relative to 'jawOpen'"):
        bpy.ops.shapespace.add_transfer_example()
    driven.add_inbetween(tgt, "jawOpen", "mouthPucker", 0.5, name="jawHalf")
    _refused(src, tgt, [("jawHalf", {"jawOpen": 0.5})], "example 'jawHalf' of 'Mesh_2' is an in-between")
    co = np.empty(3 * len(tgt.data.vertices), np.float32)
    blocks[0].points.foreach_get("co", co)
    blocks["mouthClose"].points.foreach_set("co", co)
    _refused(src, tgt, [("mouthClose", None)], "example 'mouthClose' of 'Mesh_2' moves nothing")
    _refused(src, tgt, [("jawOpen", {"jawOpen": 0.001})], r"its largest weight \('jawOpen' = 0.001\) is below 0.05")


def test_an_example_in_the_source_naming_is_kept_not_duplicated(registered):
    src, tgt, _ = _heads(keep=("jawOpen",))
    tgt.data.shape_keys.key_blocks["jawOpen"].name = "JawOpen"           # FBHead's own name for it
    rep = authoring.transfer_shapes(src, tgt, naming="suffix", unmatched_parts="move", examples=[("JawOpen", None)])
    assert rep.kept == ["JawOpen"] and "jawOpen" not in tgt.data.shape_keys.key_blocks


@pytest.mark.parametrize("text, message", [
    ('{"version": 1, "examples": [{"key": "jawOpen", "weigths": {"jawOpen": 0.5}}]}',
     r"examples\[0\]: unknown field 'weigths'"),
    ('{"version": 1, "examples": [{"key": "jawOpen", "weights": {"jawOpen": 0.5, "jawOpen": 0}}]}',
     "'jawOpen' is given twice in one object"),
    ('{"version": true, "examples": []}', "expected"),
    ('{"version": 1, "examples": [{"key": "jawOpen", "weights": {"jawOpen": 1' + "0" * 400 + '}}]}',
     r"examples\[0\].weights.jawOpen is too large"),
    ('{"version": 1, "examples": [{"key": 3}]}', r"examples\[0\]: give the example's shape key"),
    ('{"version": 1, "examples": [], "extra": 1}', "expected"),
])
def test_a_damaged_example_file_is_refused_naming_the_entry(registered, tmp_path, text, message):
    path = tmp_path / "examples.json"
    path.write_text(text)
    with pytest.raises(Exception, match=message):
        authoring.load_example_file(str(path))


def test_an_example_sculpted_while_the_transfer_computes_makes_it_refuse_to_write(registered):
    """The examples are read before the background computation: an example changed before the write would
    leave keys refined to a shape that is no longer there — refused, nothing written."""
    from shapespace.core.result import ShapeSpaceError
    src, tgt, _ = _heads(keep=("jawOpen",))
    plan = authoring.read_transfer(src, tgt, naming="suffix", unmatched_parts="move", examples=[("jawOpen", None)])
    outcome = authoring.compute_transfer(plan)
    co = np.empty(3 * len(tgt.data.vertices), np.float32)
    kb = tgt.data.shape_keys.key_blocks["jawOpen"]
    kb.points.foreach_get("co", co)
    co[:3] += 0.01
    kb.points.foreach_set("co", co)
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="changed while the transfer computed"):
        authoring.write_transfer(outcome)
    assert blend_fingerprint() == before
