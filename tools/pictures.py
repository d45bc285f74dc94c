"""README pictures of the pose-space workflow (issue #16) and of Transfer Shapes (issue #13), rendered headlessly
with Workbench.  tools/demo.py calls both; alone:

    python tools/pictures.py --out DIR [--transfer]      (the PNGs and DIR/pictures.json)

On CesiumMan's left elbow, bent to 1.8 rad, one example is sculpted (Blender's own Preserve Volume result at
that bend stands in for an artist's sculpt, so the pictures can be checked) and the skin weights of the
sculpted elbow vertices are then changed (each vertex's strongest bone loses half its weight, as a rigger
smoothing the elbow would).  Colour is each vertex's distance from the sculpt (blue 0, red ≥ 1 % of the
body size), so a stale corrective shows up red.

- ``reinvert_before_after.png``: the rest-space example as applied | after the re-weight (stale, flagged) |
  after **Re-invert**.
- ``post_deform.png``: linear blend skinning alone | the example applied as a post-deformation corrective
  (added after the Armature modifier by the generated Geometry Nodes modifier).
- ``transfer_side_by_side.png`` (:func:`transfer_pictures`): Face Cap's shapes onto FBHead's bare neutral.

Every mesh shown is Blender's own evaluation.  Writes the PNGs and returns the measured errors.
"""
from __future__ import annotations

import argparse
import os
import sys

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
import env  # noqa: E402

CESIUM = os.path.join(env.ROOT, "assets", "cesium_man", "CesiumMan.glb")
ELBOW = "Skeleton_arm_joint_L__3_"
BEND = 1.8
ERROR_ATTRIBUTE = "ShapeSpace Picture Error"
#: distance from the sculpt (fraction of the body size) drawn fully red
RED_AT = 0.01


def _load(bpy, np):
    """CesiumMan in its rest pose, the elbow bent, an SBE pose space of the elbow; (mesh, armature, sculpt)."""
    from shapespace.bridge import assets, meshes, skin
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(CESIUM, replace=False)
    ob, arm = bpy.data.objects["Cesium_Man"], bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        pb.location = (0.0, 0.0, 0.0)
    pb = arm.pose.bones[ELBOW]
    pb.rotation_quaternion = (np.cos(BEND / 2), 0.0, 0.0, np.sin(BEND / 2))
    bpy.context.view_layer.update()
    mod = skin.armature_modifiers(ob)[0]
    mod.use_deform_preserve_volume = True
    sculpt = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
    mod.use_deform_preserve_volume = False
    bpy.context.view_layer.update()
    st = ob.shapespace_psd
    st.method = "SBE"
    st.readers.add().source = ELBOW
    bpy.context.view_layer.objects.active = ob
    return ob, arm, sculpt


def _reweight(bpy, np, ob, vertices):
    """Each listed vertex skinned to two or more bones: its strongest bone loses half its weight."""
    count = 0
    for v in vertices:
        groups = ob.data.vertices[int(v)].groups
        if len(groups) > 1:
            g = max(groups, key=lambda g: g.weight)
            ob.vertex_groups[g.group].add([int(v)], g.weight * 0.5, "REPLACE")
            count += 1
    ob.data.update()
    bpy.context.view_layer.update()
    return count


def _error_colours(bpy, np, ob, sculpt, size):
    """Colour the evaluated mesh by its distance from the sculpt; the max distance (fraction of ``size``)."""
    from shapespace.bridge import meshes
    got = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
    d = np.linalg.norm(got - sculpt, axis=1) / size
    t = np.clip(d / RED_AT, 0.0, 1.0)
    rgba = np.stack([t, 0.2 * (1 - t), 1 - t, np.ones_like(t)], axis=1).astype(np.float32)
    me = ob.data
    attr = me.color_attributes.get(ERROR_ATTRIBUTE) or me.color_attributes.new(ERROR_ATTRIBUTE, "FLOAT_COLOR",
                                                                               "POINT")
    attr.data.foreach_set("color", rgba.ravel())
    me.color_attributes.active_color = attr
    me.update()
    bpy.context.view_layer.update()
    return float(d.max())


def _camera(bpy, np, demo, ob, arm, size_px):
    from shapespace.bridge import meshes
    demo._setup_render(bpy, np, [ob], size_px)
    scene = bpy.context.scene
    scene.display.shading.color_type = "VERTEX"
    cam = scene.camera
    elbow = np.array(arm.matrix_world @ arm.pose.bones[ELBOW].head)
    body = meshes.to_world(ob, meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()))
    cam.data.ortho_scale = float(np.ptp(body, axis=0).max() * 0.45)
    cam.location = (float(elbow[0]), float(body[:, 1].min() - 5.0), float(elbow[2]))


def _shot(bpy, np, demo, ob, sculpt, size, path):
    err = _error_colours(bpy, np, ob, sculpt, size)
    return demo._render(bpy, path), err


def posespace_pictures(bpy, np, out_dir: str, size_px: int = 512) -> dict:
    """Render both pictures into ``out_dir``; the measured max distances from the sculpt (body-size fractions)."""
    import demo
    from shapespace.bridge import posespace
    from shapespace.bridge.posespace import finalshape, postdeform
    from shapespace.core.blendshape import bounding_box_diagonal
    tile = size_px // 2

    # (a) a rest-space example: applied, stale after the re-weight, re-inverted
    ob, arm, sculpt = _load(bpy, np)
    size = bounding_box_diagonal(sculpt)
    name = posespace.add_example(ob, make_sculpt_copy=False)
    posespace.apply_example(ob, name, sculpt)
    posespace.preview(ob)
    _camera(bpy, np, demo, ob, arm, tile)
    a_png, a_err = _shot(bpy, np, demo, ob, sculpt, size, os.path.join(out_dir, "reinvert_applied.png"))
    idx, _ = finalshape.final_shape_positions(ob, name)
    reweighted = _reweight(bpy, np, ob, idx)
    stale = [(n, message) for n, code, message in finalshape.stale_examples(ob) if code == "stale_example"]
    s_png, s_err = _shot(bpy, np, demo, ob, sculpt, size, os.path.join(out_dir, "reinvert_stale.png"))
    finalshape.reinvert_example(ob, name)
    posespace.preview(ob)
    r_png, r_err = _shot(bpy, np, demo, ob, sculpt, size, os.path.join(out_dir, "reinvert_done.png"))
    stale_after = [n for n, code, _ in finalshape.stale_examples(ob) if code == "stale_example"]
    grid_a = demo._grid(bpy, np, [a_png, s_png, r_png], os.path.join(out_dir, "reinvert_before_after.png"), 3)

    # (b) the same sculpt as a post-deformation corrective: LBS | applied
    ob, arm, sculpt = _load(bpy, np)
    name = posespace.add_example(ob, make_sculpt_copy=False)
    _camera(bpy, np, demo, ob, arm, tile)
    l_png, l_err = _shot(bpy, np, demo, ob, sculpt, size, os.path.join(out_dir, "postdeform_lbs.png"))
    postdeform.apply_post_deform(ob, name, sculpt)
    posespace.preview(ob)
    has_modifier = any(postdeform.is_post_deform_modifier(m) for m in ob.modifiers)
    p_png, p_err = _shot(bpy, np, demo, ob, sculpt, size, os.path.join(out_dir, "postdeform_applied.png"))
    grid_b = demo._grid(bpy, np, [l_png, p_png], os.path.join(out_dir, "post_deform.png"), 2)
    bpy.context.scene.display.shading.color_type = "SINGLE"
    return {"bend_rad": BEND, "sculpted_vertices": int(len(idx)), "reweighted_vertices": reweighted,
            "flagged_after_reweight": stale, "flagged_after_reinvert": stale_after,
            "max_error_rel": {"applied": a_err, "stale": s_err, "reinverted": r_err, "lbs": l_err,
                              "post_deform_applied": p_err},
            "post_deform_modifier": has_modifier,
            "renders": {"reinvert": grid_a, "post_deform": grid_b}}


FACECAP = os.path.join(env.ROOT, "assets", "facecap", "facecap_decoded.glb")
LLF = os.path.join(env.ROOT, "assets", "llf_fbhead", "Live_Link_Face.blend")
#: ARKit shapes shown side by side (canonical names: Face Cap says mouthSmile_L, FBHead MouthSmileLeft)
TRANSFER_SHAPES = ("jawOpen", "mouthSmileLeft", "eyeBlinkLeft")


def transfer_pictures(bpy, np, out_dir: str, size_px: int = 512) -> dict:
    """Transfer Shapes from the Face Cap head onto FBHead's neutral stripped of its keys, and render per shape:
    the source shape | the target neutral | the transferred shape | FBHead's own (artist-made) shape.

    The landmarks are proposed from geometry (the stripped head has no shapes), as for a new head.
    Writes ``transfer_side_by_side.png`` (one row per shape of :data:`TRANSFER_SHAPES`).
    """
    import demo
    from shapespace.bridge import assets, authoring, shapekeys
    from shapespace.core import names as arkit
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(LLF)
    fbhead = bpy.data.objects["FBHead"]
    assets.load(FACECAP, replace=False)
    source = bpy.data.objects["Mesh_2"]
    for ob in (source, fbhead):
        key = ob.data.shape_keys
        if key.animation_data is not None:
            key.animation_data.action = None
    target = fbhead.copy()
    target.data = fbhead.data.copy()
    target.name = target.data.name = "FBHead_new"
    bpy.context.scene.collection.objects.link(target)
    target.animation_data_clear()
    target.shape_key_clear()
    target.vertex_groups.clear()
    authoring.clear_landmarks(target)
    proposed = authoring.propose_landmarks(source, target, "auto")
    report = authoring.transfer_shapes(source, target, naming="arkit")
    facecap_parts = [o for o in bpy.data.objects if o.type == "MESH" and o.name.startswith("Mesh_")]
    tile = size_px // 2
    paths = []

    def shot(objects, path):
        for o in bpy.data.objects:
            o.hide_render = o not in objects
        for cam in [o for o in bpy.data.objects if o.type == "CAMERA"]:
            bpy.data.objects.remove(cam)
        demo._setup_render(bpy, np, objects, tile)
        return demo._render(bpy, path)

    def only(ob, shape):
        """Only the slider of ARKit shape ``shape`` at 1 ('' for none), whatever the mesh's naming."""
        names = shapekeys.slider_names(ob)
        found = [n for n in names if arkit.canonical_name(n) == shape]
        if shape and len(found) != 1:
            raise RuntimeError(f"{ob.name} has no single slider for {shape!r}")
        shapekeys.write_slider_values(ob, names, [1.0 if n in found else 0.0 for n in names])
        bpy.context.view_layer.update()

    for shape in TRANSFER_SHAPES:
        stem = os.path.join(out_dir, f"transfer_{shape}")
        only(source, shape)
        paths.append(shot(facecap_parts, f"{stem}_source.png"))
        only(target, "")
        paths.append(shot([target], f"{stem}_neutral.png"))
        only(target, shape)
        paths.append(shot([target], f"{stem}_transferred.png"))
        only(fbhead, shape)
        paths.append(shot([fbhead], f"{stem}_authored.png"))
    grid = demo._grid(bpy, np, paths, os.path.join(out_dir, "transfer_side_by_side.png"), 4)
    return {"shapes": list(TRANSFER_SHAPES), "landmarks": int(proposed.value),
            "landmark_status": str(proposed.status), "created": len(report.created),
            "registration_residual_mm": report.registration_residual_mm,
            "registration_status": report.registration_status.name.lower(), "seconds": round(report.seconds, 2),
            "render": grid}


def main(argv) -> int:
    ap = argparse.ArgumentParser(description="Render the README's pose-space pictures.")
    ap.add_argument("--out", required=True, help="output folder for the PNGs")
    ap.add_argument("--size", type=int, default=512, help="render size of the demo (tiles are half of it)")
    ap.add_argument("--transfer", action="store_true", help="also render the Transfer Shapes side-by-side picture")
    args = ap.parse_args(argv)
    env.reexec_in("bpy50", os.path.abspath(__file__), argv)
    import json

    import bpy
    import numpy as np

    import package
    pkg = package.load(register=True)
    try:
        os.makedirs(os.path.abspath(args.out), exist_ok=True)
        report = posespace_pictures(bpy, np, os.path.abspath(args.out), args.size)
        if args.transfer:
            report["transfer"] = transfer_pictures(bpy, np, os.path.abspath(args.out), args.size)
    finally:
        pkg.unregister()
    path = os.path.join(os.path.abspath(args.out), "pictures.json")
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(report, fh, indent=2)
    print(f"pictures: wrote {path} and the PNGs it lists")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
