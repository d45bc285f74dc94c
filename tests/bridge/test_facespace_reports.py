"""Face-space reports in Blender (bridge.facespace.reports, thesis 3.7): the compression report against an SVD of
Blender's frames, the rig analysis (coherence image, pairs, empty targets, sparsity), its PNG never written over
anything else, and a damaged stored analysis named by the panel and the operators."""
import json

import numpy as np
import pytest

from blender_support import bpy, evaluated
from facespace_blender import draw_face_panel, face_sphere, facecap, facecap_action, run_on_face
from shapespace.bridge import actions, facespace, shapekeys


def test_compression_report_matches_an_svd_of_blenders_frames(registered):
    ob = facecap()
    model = shapekeys.read_blendshape_model(ob)
    tol = 0.001
    assert bpy.ops.shapespace.compression_report(tolerance=tol) == {"FINISHED"}
    rep = facespace.stored(ob, facespace.ANALYSIS_PROP)["compression"]
    # independent reference: Blender's evaluated frames, numpy SVD, brute-force max vertex error
    action = facecap_action(ob)
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
    ob = facecap()
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


def test_analyse_rig_never_overwrites_what_is_not_its_png(registered, tmp_path):
    face_sphere()
    text = tmp_path / "notes.txt"
    text.write_text("keep me")
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    saved = blend.read_bytes()
    for path, why in [(text, "is not a PNG image"), (blend, "is a .blend file"), (tmp_path, "is a folder"),
                      (tmp_path / "missing" / "c.png", "does not exist")]:
        images = len(bpy.data.images)
        outcome, message = run_on_face("analyse_rig", filepath=str(path))
        assert outcome == "cancelled" and why in message, (path, outcome, message)
        assert len(bpy.data.images) == images and "shapespace_analysis" not in bpy.data.objects["Face"].data.shape_keys
    assert text.read_text() == "keep me" and blend.read_bytes() == saved
    png = tmp_path / "coherence.png"
    for _ in range(2):                                   # an existing PNG is the image of a previous run
        assert run_on_face("analyse_rig", filepath=str(png))[0] == "finished"
    assert png.read_bytes()[:4] == b"\x89PNG"


ANALYSIS_DAMAGE = {
    "components_text": {"compression": {"components": "x", "targets": 3, "tol": 0.1, "ratio": 1.0}},
    "compression_missing_tol": {"compression": {"components": 2, "targets": 3, "ratio": 1.5}},
    "image_number": {"coherence": {"image": 3, "mutual_coherence": 0.5, "empty_targets": [], "similar_pairs": []}},
    "pair_too_short": {"coherence": {"image": "x", "mutual_coherence": 0.5, "empty_targets": [],
                                     "similar_pairs": [["K0", 0.9]]}},
    "empty_target_number": {"coherence": {"image": "x", "mutual_coherence": 0.5, "empty_targets": [7],
                                          "similar_pairs": []}},
    "sparsity_without_pca": {"coherence": {"image": "x", "mutual_coherence": 0.5, "empty_targets": [],
                                           "similar_pairs": [], "sparsity": {"blendshape": {}}}},
}


@pytest.mark.parametrize("case", sorted(ANALYSIS_DAMAGE))
def test_a_damaged_analysis_is_named_by_the_panel_and_the_operators(registered, case):
    ob = face_sphere()
    blob = json.dumps(dict(ANALYSIS_DAMAGE[case], schema_version=1))
    ob.data.shape_keys[facespace.ANALYSIS_PROP] = blob
    where = "damaged ShapeSpace data in Key 'Key' ▸ shapespace_analysis"
    labels = draw_face_panel()
    assert any(t.startswith(where) for t in labels), labels
    images = len(bpy.data.images)
    for op_name in ("analyse_rig", "compression_report"):
        outcome, message = run_on_face(op_name)
        assert outcome == "cancelled" and where in message and "\n" not in message.strip(), (op_name, outcome, message)
    assert ob.data.shape_keys[facespace.ANALYSIS_PROP] == blob and len(bpy.data.images) == images
