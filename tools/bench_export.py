"""Export benchmark (issue #12): round trips through Blender's own importers, and bake + export speed.

    python tools/bench.py export --json export.json [--quick]

Metrics:

- ``export_roundtrip_err_rel_<gltf|fbx|abc>_<retarget|inbetween|psd>`` and
  ``export_roundtrip_err_rel_abc_wpsd`` (also ``…_gltf_wpsd`` / ``…_fbx_wpsd``: the per-frame bake): export →
  re-import with Blender's importer → max over sampled frames of the max vertex distance to the source's
  evaluated mesh, relative to its bounding-box diagonal (goal ≤ 1e-5);
- ``export_s_<format>_retarget_1640``: bake + export of a 1,640-frame take (the shipped Live Link Face take
  retargeted onto FBHead, ten times over), seconds.

The scenarios (``RIGS``) are the ones ``tests/bridge/test_export_roundtrip.py`` proves.
"""
from __future__ import annotations

import math
import os
import tempfile
import time

import numpy as np

TOOLS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(TOOLS)
ASSETS = os.path.join(ROOT, "assets")
CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
FORMATS = ("gltf", "fbx", "abc")
EXT = {"gltf": ".glb", "fbx": ".fbx", "abc": ".abc"}


def _import(path):
    from shapespace.bridge import assets
    return assets.load(path, replace=False)


def retargeted_fbhead():
    """The shipped Live Link Face take retargeted onto FBHead (copy); the scene range stays 20–160 while the
    action runs 20–183.  Returns (mesh names, frame range to export or None)."""
    import bpy

    from shapespace.bridge import retarget
    _import(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    retarget.retarget(bpy.data.objects["FBHead"], CSV, "copy")
    return ["FBHead"], None


def _sculpt(ob, name, from_keys, extra, rng):
    from shapespace.bridge import shapekeys
    model = shapekeys.read_blendshape_model(ob)
    w = np.zeros(model.n_targets)
    for n, v in from_keys.items():
        w[model.index(n)] = v
    pos = model.evaluate(w)
    centre = pos[rng.integers(len(pos))]
    fall = np.exp(-np.sum((pos - centre) ** 2, axis=1) / (0.05 * model.scale) ** 2)
    shapekeys.add_shape_key(ob, name, pos + extra * model.scale * fall[:, None] * rng.normal(size=3))


def inbetween_rig():
    """Face Cap with an in-between of jawOpen and a smile × blink combination (native drivers), playing the
    Face Cap capture (frames 1–40)."""
    import bpy

    from shapespace.bridge import driven
    _import(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    rng = np.random.default_rng(0)
    _sculpt(ob, "jawHalf", {"jawOpen": 0.5}, 0.05, rng)
    driven.add_inbetween(ob, "jawOpen", "jawHalf", 0.5)
    _sculpt(ob, "smileBlink", {"mouthSmile_L": 1.0, "eyeBlink_L": 1.0}, 0.05, rng)
    driven.add_combination(ob, ["mouthSmile_L", "eyeBlink_L"], "smileBlink")
    return ["Mesh_2"], (1, 40)


def _qx(deg):
    return (math.cos(math.radians(deg) / 2), math.sin(math.radians(deg) / 2), 0.0, 0.0)


def cesium_correctives(method):
    """CesiumMan with three sculpted examples on one bone (30°, 45°, 60°), animated through them and beyond
    (120°: extrapolated weights leave [0, 1]); Live Preview on.  ``method``: PSD, SBE or WPSD."""
    import bpy

    from shapespace.bridge import meshes
    from shapespace.core.blendshape import bounding_box_diagonal
    _import(os.path.join(ASSETS, "cesium_man", "CesiumMan.glb"))
    ob, arm = bpy.data.objects["Cesium_Man"], bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.objects.active = ob
    st = ob.shapespace_psd
    st.method = method
    pb = arm.pose.bones[5]
    for i, q in enumerate([_qx(30), _qx(45), _qx(60)]):
        pb.rotation_quaternion = q
        bpy.context.view_layer.update()
        if bpy.ops.shapespace.psd_add_example() != {"FINISHED"}:
            raise RuntimeError("psd_add_example failed")
        copy = st.examples[i].sculpt
        co = meshes.vertex_positions(copy.data).astype(np.float64)
        rng = np.random.default_rng(30 + i)
        centre, size = co[rng.integers(len(co))], bounding_box_diagonal(co)
        fall = np.exp(-np.sum((co - centre) ** 2, axis=1) / (0.1 * size) ** 2)
        moved = co + 0.02 * size * fall[:, None] * rng.normal(size=3)
        copy.data.vertices.foreach_set("co", moved.astype(np.float32).ravel())
        copy.data.update()
        st.active_example = i
        if bpy.ops.shapespace.psd_apply_example() != {"FINISHED"}:
            raise RuntimeError("psd_apply_example failed")
    for f, q in ((1, (1, 0, 0, 0)), (8, _qx(30)), (16, _qx(45)), (24, _qx(120)), (32, _qx(60))):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    st.live_preview = True
    return ["Cesium_Man"], None


RIGS = {"retarget": retargeted_fbhead, "inbetween": inbetween_rig,
        "psd": lambda: cesium_correctives("SBE"), "wpsd": lambda: cesium_correctives("WPSD")}


def select_only(names) -> None:
    import bpy
    bpy.ops.object.select_all(action="DESELECT")
    for n in names:
        bpy.data.objects[n].select_set(True)


def roundtrip(case: str, fmt: str, folder: str, frames: int = 9) -> tuple:
    """Build ``case`` in an empty file, export it as ``fmt``, re-import it; (max error over the sampled frames
    and meshes, the export report)."""
    import bpy

    from shapespace.bridge.export import export
    from shapespace.bridge.export import roundtrip as rt
    from shapespace.core.export import sample_frames
    bpy.ops.wm.read_factory_settings(use_empty=True)
    names, frame_range = RIGS[case]()
    select_only(names)
    path = os.path.join(folder, f"{case}{EXT[fmt]}")
    rep = export(fmt, path, frame_range=frame_range)
    sampled = sample_frames(rep.frame_start, rep.frame_end, frames)
    source = rt.sample_positions(names, sampled)
    render = bpy.context.scene.render
    imported = rt.reimport(fmt, path, render.fps, render.fps_base)
    got = rt.imported_positions(names, imported, sampled)
    return max(float(e.max()) for e in rt.compare(source, got).values()), rep


def long_take(repeats: int = 10) -> list:
    """FBHead playing the retargeted take ``repeats`` times in a row (1,640 frames for 10), keyed every frame."""
    import bpy

    from shapespace.bridge import actions, retarget, shapekeys
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _import(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    rep = retarget.retarget(ob, CSV, "copy")
    act = bpy.data.actions[rep["action"]]
    start, end = (int(round(f)) for f in actions.frame_range(act))
    names = shapekeys.slider_names(ob)
    one = actions.sample_shape_keys(ob, names, np.arange(start, end + 1), act)
    values = np.tile(one, (repeats, 1))
    frames = np.arange(1, len(values) + 1)
    actions.key_shape_values(ob, names, frames, values, action_name="FBHead_long")
    select_only(["FBHead"])
    return frames


def speed(folder: str) -> dict:
    import bpy

    from shapespace.bridge.export import export
    out = {}
    for fmt in FORMATS:
        frames = long_take()
        t0 = time.perf_counter()
        rep = export(fmt, os.path.join(folder, f"long{EXT[fmt]}"))
        out[f"export_s_{fmt}_retarget_{len(frames)}"] = time.perf_counter() - t0
        assert rep.frames == len(frames), (rep.frames, len(frames))
        bpy.ops.wm.read_factory_settings(use_empty=True)
    return out


def run(quick: bool = False) -> dict:
    import package
    package.load(register=True)
    metrics = {}
    with tempfile.TemporaryDirectory(prefix="shapespace-bench-export-") as folder:
        for case in ("retarget", "inbetween", "psd", "wpsd"):
            for fmt in FORMATS:
                err, rep = roundtrip(case, fmt, folder, frames=5 if quick else 12)
                metrics[f"export_roundtrip_err_rel_{fmt}_{case}"] = err
                if case == "psd":
                    metrics[f"export_psd_split_keys_{fmt}"] = len(rep.baked[0].split)
        metrics.update(speed(folder))
    metrics["export_roundtrip_goal_met"] = int(all(v <= 1e-5 for k, v in metrics.items()
                                                   if k.startswith("export_roundtrip_err_rel_")))
    return metrics
