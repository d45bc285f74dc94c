"""ShapeSpace demo on the bundled real assets (headless).

    python tools/demo.py --out DIR

Imports the vendored Face Cap head (52 ARKit shape keys and a real iPhone
capture) with Blender's glTF importer, reads it through the bridge, checks
that ShapeSpace's blendshape model reproduces Blender's own evaluated mesh at
the captured frames, renders Workbench PNGs of the neutral and a captured
frame (and the pose-space and Transfer Shapes pictures of tools/pictures.py),
and writes ``DIR/demo.blend`` and ``DIR/report.json``.  Creates ``.venv/bpy50``
on first use (tools/env.py).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
import env  # noqa: E402

FACECAP = os.path.join(env.ROOT, "assets", "facecap", "facecap_decoded.glb")
CESIUM = os.path.join(env.ROOT, "assets", "cesium_man", "CesiumMan.glb")
HEAD = "Mesh_2"


def _setup_render(bpy, np, objects, size):
    from shapespace.bridge import meshes
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.image_settings.file_format = "PNG"
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "SINGLE"
    pts = np.concatenate([meshes.to_world(ob, meshes.vertex_positions(ob.data)) for ob in objects])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    cam_data = bpy.data.cameras.new("DemoCamera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = float(max(hi[0] - lo[0], hi[2] - lo[2]) * 1.15)
    cam = bpy.data.objects.new("DemoCamera", cam_data)
    scene.collection.objects.link(cam)
    centre = (lo + hi) / 2
    cam.location = (float(centre[0]), float(lo[1] - 2.0 * (hi[1] - lo[1]) - 1.0), float(centre[2]))
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    cam_data.clip_end = float(10 * np.linalg.norm(hi - lo) + 10)
    scene.camera = cam


def _render(bpy, path):
    bpy.context.scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    return path


def _paint_pins(bpy, np, png, points_world, colors, radii):
    """Draw pins into a rendered PNG (Workbench renders have no overlays)."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector
    scene = bpy.context.scene
    img = bpy.data.images.load(png)
    w, h = img.size
    px = np.array(img.pixels[:], dtype=np.float32).reshape(h, w, 4)
    yy, xx = np.mgrid[0:h, 0:w]
    for p, col, radius in zip(points_world, colors, radii):
        uv = world_to_camera_view(scene, scene.camera, Vector(p))
        cx, cy = uv.x * w, uv.y * h
        disk = (xx - cx) ** 2 + (yy - cy) ** 2
        px[disk <= radius ** 2] = (0, 0, 0, 1)
        px[disk <= (radius - 1.5) ** 2] = col
    img.pixels[:] = px.ravel()
    img.filepath_raw = png
    img.file_format = "PNG"
    img.save()
    bpy.data.images.remove(img)


def _drag_demo(bpy, np, head, model, action, peak, out_dir, drags=5):
    """Pose the neutral face toward the captured frame with a few simulated pin drags."""
    from shapespace.bridge import actions, meshes, shapekeys
    goal_w = actions.sample_shape_keys(head, model.names, [float(peak)], action=action)[0]
    goal = model.evaluate(goal_w)
    key = head.data.shape_keys
    key.animation_data.action = None
    shapekeys.write_slider_values(head, model.names, np.zeros(model.n_targets))
    bpy.context.view_layer.objects.active = head
    head.shapespace.pins.clear()
    errors = []
    for _ in range(drags):
        current = shapekeys.read_blendshape_model(head).evaluate()
        err = np.linalg.norm(current - goal, axis=1)
        errors.append(float(err.max() / model.scale))
        v = int(np.argmax(err))
        bpy.ops.shapespace.add_pin(vertices=(v, 0, 0), weights=(1, 0, 0))
        index = len(head.shapespace.pins) - 1
        result = bpy.ops.shapespace.solve_pins(pin=index, target=tuple(goal[v]))
        if result != {"FINISHED"}:
            raise RuntimeError("the drag solve failed")
    after = shapekeys.read_blendshape_model(head).evaluate()
    errors.append(float(np.linalg.norm(after - goal, axis=1).max() / model.scale))
    pin_vertices = [p.vertices[0] for p in head.shapespace.pins]
    pins_world = meshes.to_world(head, after[pin_vertices])
    targets_world = meshes.to_world(head, goal[pin_vertices])
    after_png = _render(bpy, os.path.join(out_dir, "drag_after.png"))
    # targets (white, larger) under the pins (orange): a reached target shows as a white ring
    _paint_pins(bpy, np, after_png, list(targets_world) + list(pins_world),
                [(1.0, 1.0, 1.0, 1.0)] * drags + [(1.0, 0.55, 0.0, 1.0)] * drags, [7] * drags + [4.5] * drags)
    shapekeys.write_slider_values(head, model.names, np.zeros(model.n_targets))
    before_png = _render(bpy, os.path.join(out_dir, "drag_before.png"))
    _paint_pins(bpy, np, before_png, list(targets_world), [(1.0, 1.0, 1.0, 1.0)] * drags, [7] * drags)
    actions.assign_action(key, action)
    return {"drags": drags, "target_frame": peak, "max_error_rel_after_each_drag": errors,
            "sliders_in_target": int(np.sum(goal_w > 0.01)),
            "renders": {"before": before_png, "after": after_png}}


ELBOW = "Skeleton_arm_joint_L__3_"


def _bend(bpy, np, arm, angle):
    pb = arm.pose.bones[ELBOW]
    pb.rotation_mode = "QUATERNION"
    pb.rotation_quaternion = (np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2))
    bpy.context.view_layer.update()


def _corrective_demo(bpy, np, out_dir, size):
    """CesiumMan's elbow: LBS collapses when bent; three sculpted examples fix it at a held-out bend.

    The "sculpts" are Blender's own Preserve Volume result at each example bend (a stand-in for an
    artist's sculpt that a test can check); the held-out bend is compared with it too.
    """
    from shapespace.bridge import assets, meshes, posespace, skin
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(CESIUM, replace=False)
    ob, arm = bpy.data.objects["Cesium_Man"], bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:  # the rest pose, then only the elbow bends
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        pb.location = (0.0, 0.0, 0.0)
    mod = skin.armature_modifiers(ob)[0]
    depsgraph = bpy.context.evaluated_depsgraph_get()

    def reference(angle):
        _bend(bpy, np, arm, angle)
        mod.use_deform_preserve_volume = True
        ref = meshes.evaluated_positions(ob, depsgraph).astype(np.float64)
        mod.use_deform_preserve_volume = False
        return ref

    st = ob.shapespace_psd
    st.method = "SBE"
    st.readers.add().source = ELBOW
    bpy.context.view_layer.objects.active = ob
    for angle in (1.0, 1.8, 2.4):
        wanted = reference(angle)
        name = posespace.add_example(ob, make_sculpt_copy=False)
        posespace.apply_example(ob, name, wanted)
    held_out = 2.1
    want = reference(held_out)
    size_m = float(np.linalg.norm(np.ptp(want, axis=0)))
    names = [e.name for e in st.examples]
    from shapespace.bridge import shapekeys
    shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    lbs = meshes.evaluated_positions(ob, depsgraph).astype(np.float64)
    posespace.preview(ob)
    fixed = meshes.evaluated_positions(ob, depsgraph).astype(np.float64)
    # renders: the arm, LBS vs corrected
    _setup_render(bpy, np, [ob], size)
    cam = bpy.context.scene.camera
    elbow = np.array(arm.matrix_world @ arm.pose.bones[ELBOW].head)
    body = meshes.to_world(ob, want)
    cam.data.ortho_scale = float(np.ptp(body, axis=0).max() * 0.45)
    cam.location = (float(elbow[0]), float(body[:, 1].min() - 5.0), float(elbow[2]))
    shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    lbs_png = _render(bpy, os.path.join(out_dir, "elbow_lbs.png"))
    posespace.preview(ob)
    fixed_png = _render(bpy, os.path.join(out_dir, "elbow_corrected.png"))
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out_dir, "correctives.blend"), check_existing=False)
    # pose-space confidence: the uncertainty heat map at a bend no example covers
    _bend(bpy, np, arm, 0.4)
    confidence = posespace.confidence(ob, heat_map=True)
    scene = bpy.context.scene
    scene.display.shading.color_type = "VERTEX"
    heat_png = _render(bpy, os.path.join(out_dir, "elbow_confidence.png"))
    scene.display.shading.color_type = "SINGLE"
    _bend(bpy, np, arm, held_out)
    confidence_held_out = posespace.confidence(ob)["variance"]
    return {"examples": names, "held_out_bend_rad": held_out,
            "confidence_variance_far_bend": confidence["variance"], "confidence_variance_held_out":
            confidence_held_out,
            "max_error_rel_lbs": float(np.abs(lbs - want).max() / size_m),
            "max_error_rel_corrected": float(np.abs(fixed - want).max() / size_m),
            "renders": {"lbs": lbs_png, "corrected": fixed_png, "confidence": heat_png}}


def _retarget_demo(bpy, np, out_dir, size):
    """The Live Link Face recording onto the Face Cap head, and the Face Cap capture onto FBHead."""
    from shapespace.bridge import actions, assets, retarget
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(os.path.join(env.ROOT, "assets", "llf_fbhead", "Live_Link_Face.blend"))
    fbhead = bpy.data.objects["FBHead"]
    assets.load(FACECAP, replace=False)
    head = bpy.data.objects[HEAD]
    capture = actions.active_action(head.data.shape_keys)
    scene = bpy.context.scene
    scene.frame_start = 1
    csv = os.path.join(env.ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    onto_facecap = retarget.retarget(head, csv, "spacetime", key_tolerance=0.01)
    onto_fbhead = retarget.retarget(fbhead, capture, "spacetime", key_tolerance=0.01)
    # side by side: facecap (left, LLF performance) and FBHead (right, the Face Cap capture)
    fbhead.location = (0.0, 0.0, 0.0)
    for ob in bpy.data.objects:
        ob.hide_render = ob.type == "EMPTY" or ob.name.startswith("marker_")
    renders = {}
    facecap_parts = {"Mesh_0", "Mesh_1", "Mesh_2", "Mesh_3"}
    for label, obj, rep in (("llf_on_facecap", head, onto_facecap), ("facecap_on_fbhead", fbhead, onto_fbhead)):
        mine = facecap_parts if obj is head else {obj.name}
        others = [o for o in bpy.data.objects if o.type == "MESH" and o.name not in mine]
        hidden = {o.name: o.hide_render for o in others}
        for o in others:
            o.hide_render = True
        parts = [o for o in bpy.data.objects if o.type == "MESH" and not o.hide_render]
        for cam in [o for o in bpy.data.objects if o.type == "CAMERA"]:
            bpy.data.objects.remove(cam)
        _setup_render(bpy, np, parts, size // 2)
        paths = []
        frames = np.linspace(scene.frame_start + 5, scene.frame_start + rep["frames"] - 5, 3).astype(int)
        for f in frames:
            scene.frame_set(int(f))
            paths.append(_render(bpy, os.path.join(out_dir, f"{label}_{int(f)}.png")))
        renders[label] = paths
        for o in others:
            o.hide_render = hidden[o.name]
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out_dir, "retargeted.blend"), check_existing=False)
    keep = ("frames", "mapped_channels", "position_error_mm", "velocity_error_mm", "velocity_error_rms",
            "position_error_rms", "clipping_frames", "keys_kept_frac", "action")
    return {"llf_on_facecap": {k: onto_facecap.get(k) for k in keep},
            "facecap_on_fbhead": {k: onto_fbhead.get(k) for k in keep}, "renders": renders}


def _grid(bpy, np, paths, out_path, columns):
    """Tile equally sized PNGs into one picture (row-major), through Blender's own image I/O."""
    tiles = []
    for p in paths:
        img = bpy.data.images.load(p)
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        tiles.append(px.reshape(h, w, 4))
        bpy.data.images.remove(img)
    rows = [np.concatenate(tiles[i:i + columns], axis=1) for i in range(0, len(tiles), columns)]
    grid = np.concatenate(rows[::-1], axis=0)             # Blender's pixel rows go bottom-up
    out = bpy.data.images.new("grid", grid.shape[1], grid.shape[0], alpha=True)
    out.pixels.foreach_set(grid.ravel())
    out.filepath_raw, out.file_format = out_path, "PNG"
    out.save()
    bpy.data.images.remove(out)
    return out_path


def _facespace_demo(bpy, np, out_dir, size):
    """Face Cap rig: coherence image, compression, the face prior, and an in-between of two captured
    expressions — linear (drifts to the average face) vs shell (keeps the expression's strength)."""
    from shapespace.bridge import actions, assets, facespace, shapekeys
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(FACECAP, replace=False)
    head = bpy.data.objects[HEAD]
    key = head.data.shape_keys
    capture = actions.active_action(key)
    model = shapekeys.read_blendshape_model(head)
    analysis = facespace.analyse(head, capture, os.path.join(out_dir, "coherence.png"))
    compression = facespace.compression(head, capture, 1e-3 * model.scale)
    prior = facespace.learn_prior(head, capture)
    flagged = facespace.implausible_frames(head, capture, 0.01)
    g, names = facespace.prior(head)
    frames = np.arange(2, 268)
    W = actions.sample_shape_keys(head, names, frames, capture)
    norms = g.face_norm(W)
    # two strong, different expressions: the most extreme frame and the farthest-apart one of similar norm
    a = int(np.argmax(norms))
    similar = np.flatnonzero(np.abs(norms - norms[a]) < 0.25 * norms[a])
    b = int(similar[np.argmax(np.linalg.norm(g.whiten(W[similar]) - g.whiten(W[a]), axis=1))])
    visible = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.name != "Icosphere"]
    _setup_render(bpy, np, visible, size // 2)
    scene = bpy.context.scene
    paths, mid_norms = [], {}
    for mode in ("LINEAR", "SHELL"):
        act = bpy.data.actions.new(f"inbetween_{mode.lower()}")
        actions.assign_action(key, act)
        for j, name in enumerate(names):
            actions.write_curve(key, actions.shape_key_path(name), [1.0, 21.0], W[[a, b], j])
        facespace.fill_between(head, 1, 21, mode)
        scene.frame_set(11)
        mid_norms[mode] = float(g.face_norm(actions.sample_shape_keys(head, names, [11.0], act))[0])
        if mode == "LINEAR":
            scene.frame_set(1)
            paths.append(_render(bpy, os.path.join(out_dir, "inbetween_start.png")))
            scene.frame_set(11)
        paths.append(_render(bpy, os.path.join(out_dir, f"inbetween_{mode.lower()}.png")))
    scene.frame_set(21)
    paths.append(_render(bpy, os.path.join(out_dir, "inbetween_end.png")))
    grid = _grid(bpy, np, paths, os.path.join(out_dir, "inbetween_linear_vs_shell.png"), 4)
    return {"mutual_coherence": analysis.mutual_coherence, "empty_targets": analysis.empty_targets,
            "similar_pairs": analysis.similar_pairs, "sparsity": analysis.sparsity_message,
            "compression": compression.to_json(), "prior": prior.to_json(), "implausible_frames": len(flagged),
            "inbetween": {"frames": [int(frames[a]), int(frames[b])], "endpoint_norms":
                          [float(norms[a]), float(norms[b])], "mid_norm_linear": mid_norms["LINEAR"],
                          "mid_norm_shell": mid_norms["SHELL"], "shell_radius": g.shell_radius},
            "renders": {"coherence": analysis.png, "inbetween": grid}}


def run(out_dir: str, size: int = 512) -> dict:
    import bpy
    import numpy as np

    import package
    pkg = package.load(register=True)
    try:
        return _run(bpy, np, out_dir, size)
    finally:
        pkg.unregister()  # a clean shutdown: bpy 4.2 can crash at exit with handlers still registered


def _run(bpy, np, out_dir, size):
    from shapespace.bridge import actions, assets, inventory, meshes, shapekeys
    from shapespace.core.blendshape import bounding_box_diagonal, diagnose_model

    os.makedirs(out_dir, exist_ok=True)
    t0 = time.perf_counter()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(FACECAP, replace=False)
    head = bpy.data.objects[HEAD]
    key = head.data.shape_keys
    model = shapekeys.read_blendshape_model(head)
    diag = diagnose_model(model)
    action = actions.active_action(key)
    first, last = actions.frame_range(action)

    # 1. The core model against Blender's own evaluation at captured frames (fractional times).
    scene = bpy.context.scene
    errors = []
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for frame in np.linspace(first, last, 12):
        whole = int(np.floor(frame))
        scene.frame_set(whole, subframe=float(frame - whole))
        weights = actions.sample_shape_keys(head, model.names, [frame])[0]
        blender = meshes.evaluated_positions(head, depsgraph).astype(np.float64)
        errors.append(float(np.abs(model.evaluate(weights) - blender).max() / model.scale))

    # 2. Renders: neutral (animation detached, sliders at 0), then the most expressive captured frame.
    visible = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.name != "Icosphere"]
    _setup_render(bpy, np, visible, size)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    weights = actions.sample_shape_keys(head, model.names, frames)
    peak = int(frames[int(np.argmax(np.linalg.norm(weights, axis=1)))])
    key.animation_data.action = None
    shapekeys.write_slider_values(head, model.names, np.zeros(model.n_targets))
    scene.frame_set(peak)
    neutral_png = _render(bpy, os.path.join(out_dir, "neutral.png"))
    actions.assign_action(key, action)
    scene.frame_set(peak)
    frame_png = _render(bpy, os.path.join(out_dir, f"captured_frame_{peak}.png"))

    drag_report = _drag_demo(bpy, np, head, model, action, peak, out_dir)

    blend_path = os.path.join(out_dir, "demo.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend_path, check_existing=False)
    report = {
        "blender": bpy.app.version_string,
        "asset": os.path.relpath(FACECAP, env.ROOT),
        "head": {
            "object": head.name, "vertices": model.n_vertices, "targets": model.n_targets,
            "rank": diag.diagnostics["rank"], "issues": [i.message for i in diag.issues],
            "bbox_diagonal_local": model.scale,
            "bbox_diagonal_world": bounding_box_diagonal(meshes.to_world(head, model.neutral)),
        },
        "capture": {"action": action.name, "frame_range": [first, last], "fps": scene.render.fps,
                    "rendered_frame": peak},
        "model_vs_blender_max_rel_error": max(errors),
        "direct_manipulation": drag_report,
        "inventory": inventory.describe_file().to_json(),
        "outputs": {"blend": blend_path, "neutral_png": neutral_png, "frame_png": frame_png},
    }
    report["pose_space_correctives"] = _corrective_demo(bpy, np, out_dir, size)   # loads another file
    import pictures
    report["pose_space_pictures"] = pictures.posespace_pictures(bpy, np, out_dir, size)   # re-invert, post-deform
    report["retargeting"] = _retarget_demo(bpy, np, out_dir, size)
    report["face_space"] = _facespace_demo(bpy, np, out_dir, size)
    report["transfer_shapes"] = pictures.transfer_pictures(bpy, np, out_dir, size)   # Face Cap → FBHead
    report["seconds"] = round(time.perf_counter() - t0, 2)
    with open(os.path.join(out_dir, "report.json"), "w", encoding="utf-8") as fh:
        json.dump(report, fh, indent=2)
    return report


def main(argv) -> int:
    ap = argparse.ArgumentParser(description="ShapeSpace demo on the bundled real assets.")
    ap.add_argument("--out", required=True, help="output folder (demo.blend, PNG renders, report.json)")
    ap.add_argument("--size", type=int, default=512, help="render size in pixels")
    args = ap.parse_args(argv)
    env.reexec_in("bpy50", os.path.abspath(__file__), argv)
    report = run(os.path.abspath(args.out), args.size)
    dm = report["direct_manipulation"]
    print(f"demo: model vs Blender max error {report['model_vs_blender_max_rel_error']:.2e} of the head size; "
          f"{dm['drags']} drags took the neutral to {dm['max_error_rel_after_each_drag'][-1]:.3f} of the head size "
          f"from frame {dm['target_frame']} ({dm['sliders_in_target']} sliders)")
    pc = report["pose_space_correctives"]
    print(f"demo: elbow at a held-out bend: LBS error {pc['max_error_rel_lbs']:.4f}, corrected "
          f"{pc['max_error_rel_corrected']:.4f} of the body size")
    pp = report["pose_space_pictures"]["max_error_rel"]
    print(f"demo: elbow example after a re-weight: {pp['stale']:.4f} of the body size from its sculpt (flagged), "
          f"{pp['reinverted']:.1e} after Re-invert; post-deformation corrective {pp['post_deform_applied']:.1e}")
    rt = report["retargeting"]
    print(f"demo: retargeted the Live Link Face take onto facecap ({rt['llf_on_facecap']['frames']} frames) and "
          f"the Face Cap capture onto FBHead ({rt['facecap_on_fbhead']['frames']} frames); "
          f"wrote {args.out}/demo.blend, "
          f"correctives.blend, retargeted.blend, report.json and renders")
    fsd = report["face_space"]
    print(f"demo: face space — {fsd['compression']['components']} of {fsd['compression']['targets']} PCA components "
          f"keep the capture within 1e-3 of the head; in-between norm linear {fsd['inbetween']['mid_norm_linear']:.2f} "
          f"vs shell {fsd['inbetween']['mid_norm_shell']:.2f} (ends {fsd['inbetween']['endpoint_norms'][0]:.2f}, "
          f"{fsd['inbetween']['endpoint_norms'][1]:.2f})")
    tr = report["transfer_shapes"]
    print(f"demo: transferred {tr['created']} Face Cap shapes onto FBHead's bare neutral ({tr['landmarks']} landmarks "
          f"proposed from geometry, registration residual {tr['registration_residual_mm']:.2f} mm)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
