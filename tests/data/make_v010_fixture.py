"""Build ``shapespace_0_1_0.blend`` and its JSON sidecar with the ShapeSpace **0.1.0** add-on.

Usage (from the repository root)::

    git worktree add /tmp/ss010 e07c414          # 0.1.0, outside the working tree
    .venv/bpy42/bin/python tests/data/make_v010_fixture.py /tmp/ss010 tests/data/shapespace_0_1_0.blend
    git worktree remove /tmp/ss010 --force && git worktree prune

Any supported Blender runs it (``.venv/bpy50`` too); the committed file was saved by the OLDEST one,
Blender 4.2 LTS, because the Blender tiers run on 4.2 … 5.2 and a .blend opens only in its own and
newer Blender versions (a 5.0 file loses its layered actions in 4.2).  The sidecar numbers agree between
Blender 4.2 and 5.0 to ~1e-7.

The add-on is loaded from the given checkout (as ``shapespace``, the way ``tools/package.py`` does) and
registered with a throw-away Blender user folder.  Every piece of state 0.1.0 keeps in a .blend is made
through its operators, as an artist would:

- ``Pinned``: a shape-key grid with three pins (``Object.shapespace``: pins, mode, α, μ, learned-prior
  action and range, prior form);
- ``Driven``: an in-between (``up@0.5``) and a combination (``up+wide``) made with the operators — the
  ``shapespace_driven`` blob on the Key and native drivers;
- ``Face``: ARKit-named keys animated by ``Face_capture``; a channel-mapping override
  (``shapespace_mapping``), a per-frame retarget result ``Face_perframe`` that replaced ``Face_capture``
  (``shapespace_last_retarget``), a learnt face prior (``shapespace_face_prior``) with its flagged
  frames, an analysis (``shapespace_analysis`` and a packed coherence image) and the Retarget/Face-Space
  panel settings;
- ``Face_wholeface`` / ``Face_pca``: Convert Rig copies (``shapespace_representation``; the whole-face
  copy's Neutral key has the 1 − Σw Sum driver);
- ``Limb`` skinned to ``Armature`` (two bones): two pose-space examples sculpted on their posed copies
  and applied, a driven target (the armature's ``["exertion"]``) recorded at both, the second example
  moved to a third pose (``pose``, ``pseudo_pose`` and ``target_values`` strings).

The sidecar (same name, ``.json``) holds what 0.1.0 + Blender's depsgraph produced from that file:
evaluated vertex fingerprints at given slider / pose / frame states and the results of re-running
operators (Solve Pins, Make Convex, Find Implausible Frames, a copy retarget through the override), so
``tests/bridge/test_file_compat.py`` can compare the current add-on against 0.1.0 on the same file.
"""
from __future__ import annotations

import importlib.util
import json
import math
import os
import sys
import tempfile

USER_DIR = tempfile.mkdtemp(prefix="shapespace-fixture-user-")
os.environ["BLENDER_USER_RESOURCES"] = USER_DIR
for _var in ("BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS", "BLENDER_USER_DATAFILES", "BLENDER_USER_EXTENSIONS"):
    os.environ.pop(_var, None)

import bpy  # noqa: E402
import numpy as np  # noqa: E402

FPS = 24
FRAMES = (1, 60)
CAPTURE_KEYS = ("jawOpen", "mouthClose", "mouthSmileLeft", "mouthSmileRight", "eyeBlinkLeft", "eyeBlinkRight",
                "browInnerUp")


# ----------------------------------------------------------------------------------------- helpers
def load_addon(root: str):
    """Import the checkout at ``root`` as the ``shapespace`` package and register it."""
    root = os.path.abspath(root)
    spec = importlib.util.spec_from_file_location("shapespace", os.path.join(root, "__init__.py"),
                                                  submodule_search_locations=[root])
    pkg = importlib.util.module_from_spec(spec)
    sys.modules["shapespace"] = pkg
    spec.loader.exec_module(pkg)
    pkg.register()
    return pkg


def ok(result, what):
    if result != {"FINISHED"}:
        raise RuntimeError(f"{what}: {result}")


def activate(ob):
    for o in bpy.context.view_layer.objects:
        o.select_set(o == ob)
    bpy.context.view_layer.objects.active = ob


def evaluated(ob) -> np.ndarray:
    """Blender's evaluated object-space vertex positions (depsgraph), float64 (p, 3)."""
    bpy.context.view_layer.update()
    dg = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64)


def key_co(kb) -> np.ndarray:
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def fingerprint(ob, vertices) -> dict:
    """Evaluated coordinates of ``vertices`` plus whole-mesh moments and the bounding-box diagonal."""
    co = evaluated(ob)
    return {"co": co[vertices].tolist(), "mean": co.mean(axis=0).tolist(),
            "rms": np.sqrt((co ** 2).mean(axis=0)).tolist(),
            "diag": float(np.linalg.norm(co.max(axis=0) - co.min(axis=0)))}


def pick_vertices(deltas, count: int, stride: int) -> list:
    """The ``count`` vertices the given displacements (list of (p, 3)) move most, plus every ``stride``-th."""
    mag = np.max([np.linalg.norm(d, axis=1) for d in deltas], axis=0)
    top = np.argsort(-mag)[:count]
    return sorted({int(i) for i in top} | set(range(0, mag.size, stride)))


def grid(name, nx, ny, size=2.0, dome=0.0):
    """A quad grid in the XY plane (optionally domed in Z), linked to the scene."""
    xs, ys = np.linspace(-size / 2, size / 2, nx), np.linspace(-size / 2, size / 2, ny)
    X, Y = np.meshgrid(xs, ys)
    Z = dome * (1.0 - (X ** 2 + Y ** 2) / (size / 2) ** 2)
    verts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    faces = [(j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1, (j + 1) * nx + i)
             for j in range(ny - 1) for i in range(nx - 1)]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts.tolist(), [], faces)
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def bump(co, centre, width, direction):
    fall = np.exp(-np.sum((co - np.asarray(centre)) ** 2, axis=1) / width ** 2)
    return fall[:, None] * np.asarray(direction, dtype=np.float64)


def add_key(ob, name, positions):
    if ob.data.shape_keys is None:
        ob.shape_key_add(name="Basis", from_mix=False)
    kb = ob.shape_key_add(name=name, from_mix=False)
    kb.data.foreach_set("co", np.asarray(positions, np.float32).ravel())
    return kb


def set_values(ob, values: dict):
    blocks = ob.data.shape_keys.key_blocks
    for name, v in values.items():
        blocks[name].value = v


def quat(axis, degrees):
    a = math.radians(degrees) / 2
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    return [math.cos(a)] + (math.sin(a) * axis).tolist()


def set_pose(arm, pose: dict):
    for bone, q in pose.items():
        arm.pose.bones[bone].rotation_quaternion = q
    bpy.context.view_layer.update()


# ----------------------------------------------------------------------------------------- pins
def build_pinned(side):
    ob = grid("Pinned", 10, 10)
    base = np.array([v.co[:] for v in ob.data.vertices])
    add_key(ob, "raise", base + bump(base, (0, 0, 0), 0.5, (0, 0, 0.4)))
    add_key(ob, "tilt", base + np.column_stack([0 * base[:, 0], 0 * base[:, 0], 0.2 * base[:, 0]]))
    add_key(ob, "curl", base + np.column_stack([0 * base[:, 0], -0.1 * base[:, 1] ** 2, 0.15 * base[:, 1] ** 2]))
    activate(ob)
    st = ob.shapespace
    st.alpha, st.mu = 0.05, 0.002
    st.prior_form, st.snap = "PCA", False
    key = ob.data.shape_keys
    names = ("raise", "tilt", "curl")
    shapes = {n: key_co(key.key_blocks[n]) for n in ("Basis",) + names}

    def pin1_at(weights):       # pin 1 (barycentric on 55, 56, 65) with the sliders at ``weights``
        co = shapes["Basis"] + sum(w * (shapes[n] - shapes["Basis"]) for n, w in zip(names, weights))
        return tuple(float(x) for x in 0.5 * co[55] + 0.3 * co[56] + 0.2 * co[65])

    # pins made at sliders (0.3, 0.2, 0.1): two corners (one stationary) and a point near the middle
    set_values(ob, dict(zip(names, (0.3, 0.2, 0.1))))
    ok(bpy.ops.shapespace.add_pin(vertices=(9, 0, 0), weights=(1, 0, 0)), "add_pin 0")
    ok(bpy.ops.shapespace.add_pin(vertices=(55, 56, 65), weights=(0.5, 0.3, 0.2), use_target=True,
                                  target=pin1_at((0.3, 0.2, 0.1))), "add_pin 1")
    ok(bpy.ops.shapespace.add_pin(vertices=(90, 0, 0), weights=(1, 0, 0), stationary=True), "add_pin 2")
    pin1_target = tuple(st.pins[1].target)
    # a training action for learned mode (not played by the mesh: only the panel's Prior Action uses it)
    for f in range(1, 31):
        for j, n in enumerate(names):
            key.key_blocks[n].value = 0.5 + 0.4 * math.sin(0.3 * f + 1.7 * j) * math.cos(0.11 * f * (j + 1))
            key.key_blocks[n].keyframe_insert("value", frame=f)
    train = key.animation_data.action
    train.name = "Pinned_train"
    key.animation_data.action = None
    st.prior_action, st.prior_start, st.prior_end = train, 3, 28
    set_values(ob, {n: 0.0 for n in names})
    ok(bpy.ops.shapespace.solve_pins(), "solve_pins (saved state)")
    saved = {n: key.key_blocks[n].value for n in names}
    # what 0.1.0 answers to a drag of pin 1 to where it is at raise 0.7 (Direct, then Learned mode)
    target = pin1_at((0.7, 0.2, 0.1))
    answers = {}
    for mode in ("DIRECT", "LEARNED"):
        st.mode = mode
        set_values(ob, saved)
        ok(bpy.ops.shapespace.solve_pins(pin=1, target=target), f"solve_pins {mode}")
        answers[mode] = {n: key.key_blocks[n].value for n in names}
        st.pins[1].target = pin1_target
    st.mode = "DIRECT"
    set_values(ob, saved)
    # Make Convex from sliders outside the hull
    before = {"raise": 0.9, "tilt": 0.7, "curl": -0.2}
    set_values(ob, before)
    ok(bpy.ops.shapespace.make_convex(), "make_convex")
    convex = {n: key.key_blocks[n].value for n in names}
    set_values(ob, saved)
    side["Pinned"] = {
        "sliders": saved,
        "pins": [{"vertices": list(p.vertices), "weights": list(p.weights), "target": list(p.target),
                  "stationary": p.stationary} for p in st.pins],
        "settings": {"mode": st.mode, "alpha": st.alpha, "mu": st.mu, "prior_form": st.prior_form,
                     "prior_action": train.name, "prior_start": st.prior_start, "prior_end": st.prior_end,
                     "active_pin": st.active_pin},
        "solve": {"pin": 1, "target": list(target), "sliders": answers},
        "make_convex": {"before": before, "after": convex},
    }


# ----------------------------------------------------------------------------------------- driven keys
def build_driven(side):
    ob = grid("Driven", 10, 10)
    ob.location = (3.0, 0.0, 0.0)
    base = np.array([v.co[:] for v in ob.data.vertices])
    up = base + bump(base, (0, 0, 0), 0.6, (0, 0, 0.5))
    wide = base * np.array([1.3, 1.0, 1.0])
    add_key(ob, "up", up)
    add_key(ob, "wide", wide)
    half = base + 0.5 * (up - base) + bump(base, (0.3, 0.2, 0), 0.3, (0.05, 0, 0.12))
    add_key(ob, "upHalf", half)
    both = base + (up - base) + (wide - base) + bump(base, (-0.4, 0.1, 0), 0.35, (0, 0.08, -0.15))
    add_key(ob, "upWide", both)
    activate(ob)
    blocks = ob.data.shape_keys.key_blocks
    ob.active_shape_key_index = blocks.find("upHalf")
    ok(bpy.ops.shapespace.add_inbetween(primary="up", weight=0.5), "add_inbetween")
    ob.active_shape_key_index = ob.data.shape_keys.key_blocks.find("upWide")
    ok(bpy.ops.shapespace.add_combination(first="up", second="wide"), "add_combination")
    blocks = ob.data.shape_keys.key_blocks
    assert "up@0.5" in blocks and "up+wide" in blocks and "upHalf" not in blocks
    verts = pick_vertices([half - base, both - base], 16, 9)
    states = [{"up": 0.25, "wide": 0.0}, {"up": 0.5, "wide": 0.0}, {"up": 0.8, "wide": 0.0},
              {"up": 1.0, "wide": 1.0}, {"up": 0.5, "wide": 0.7}]
    out = []
    for s in states:
        set_values(ob, s)
        out.append({"sliders": s, **fingerprint(ob, verts)})
    set_values(ob, {"up": 0.0, "wide": 0.0})
    side["Driven"] = {"vertices": verts, "states": out, "metadata": json.loads(ob.data.shape_keys["shapespace_driven"])}


# ----------------------------------------------------------------------------------------- face rig
def build_face(side):
    ob = grid("Face", 12, 12, dome=0.4)
    ob.location = (0.0, 3.0, 0.0)
    base = np.array([v.co[:] for v in ob.data.vertices])
    specs = {"jawOpen": ((0, -0.8, 0), 0.6, (0, -0.25, -0.1)), "mouthClose": ((0, -0.5, 0), 0.35, (0, 0.08, 0.05)),
             "mouthSmileLeft": ((0.4, -0.4, 0), 0.3, (0.1, 0.1, 0.05)),
             "mouthSmileRight": ((-0.4, -0.4, 0), 0.3, (-0.1, 0.1, 0.05)),
             "eyeBlinkLeft": ((0.4, 0.4, 0), 0.25, (0, -0.1, 0.02)),
             "eyeBlinkRight": ((-0.4, 0.4, 0), 0.25, (0, -0.1, 0.02)),
             "browInnerUp": ((0, 0.75, 0), 0.4, (0, 0.12, 0.08))}
    for name, (c, w, d) in specs.items():
        add_key(ob, name, base + bump(base, c, w, d))
    ob.data.shape_keys.key_blocks["eyeBlinkLeft"].slider_max = 0.7      # clipped by the retarget
    activate(ob)
    key = ob.data.shape_keys
    # the capture: smooth channels, one extreme frame and a few frames at rest
    for f in range(FRAMES[0], FRAMES[1] + 1):
        for j, n in enumerate(CAPTURE_KEYS):
            v = 0.45 + 0.4 * math.sin(0.21 * f + 0.9 * j) * math.sin(0.05 * f * (j + 2) + 0.3)
            if f == 33:
                v = 1.0
            elif f in (50, 51):
                v = 0.0
            key.key_blocks[n].value = v
            key.key_blocks[n].keyframe_insert("value", frame=f)
    key.animation_data.action.name = "Face_capture"
    capture = key.animation_data.action
    verts = pick_vertices([key_co(kb) - base for kb in key.key_blocks[1:]], 16, 11)
    scene = bpy.context.scene
    scene.frame_set(12)
    at_capture = fingerprint(ob, verts)
    scene.frame_set(1)
    # face space: prior, flagged frames, analysis, conversions
    ok(bpy.ops.shapespace.learn_face_prior(), "learn_face_prior")
    ok(bpy.ops.shapespace.find_implausible_frames(alpha=0.05), "find_implausible_frames")
    flagged = [[i.frame, i.reason] for i in ob.shapespace_face.implausible]
    ok(bpy.ops.shapespace.analyse_rig(), "analyse_rig")
    ok(bpy.ops.shapespace.compression_report(tolerance=0.001), "compression_report")
    ok(bpy.ops.shapespace.convert_rig(form="WHOLE_FACE", convex=True), "convert_rig whole face")
    ok(bpy.ops.shapespace.convert_rig(form="PCA"), "convert_rig pca")
    face_panel = ob.shapespace_face
    face_panel.gap_path, face_panel.gap_index, face_panel.gap_start, face_panel.gap_end = (
        'key_blocks["jawOpen"].value', 0, 20, 26)
    # retarget: an override, a copy through it (then discarded), and the per-frame result that stays
    ok(bpy.ops.shapespace.set_mapping(source="jawOpen", target="mouthClose", gain=0.5, offset=0.1), "set_mapping")
    ok(bpy.ops.shapespace.retarget(action=capture.name, method="copy"), "retarget copy")
    copy_report = json.loads(key["shapespace_last_retarget"])
    copy_action = key.animation_data.action
    probe = [5.0, 17.0, 33.0, 44.0]
    copied = {}
    for fc in _fcurves(copy_action):
        name = fc.data_path[len('key_blocks["'):-len('"].value')]
        copied[name] = [fc.evaluate(f) for f in probe]
    ok(bpy.ops.shapespace.discard_retarget(), "discard_retarget")
    assert key.animation_data.action == capture
    rt = ob.shapespace_retarget
    rt.source_kind, rt.action, rt.method, rt.key_tolerance, rt.key_shape = "ACTION", capture, "perframe", 0.005, \
        "BEZIER"
    ok(bpy.ops.shapespace.retarget(action=capture.name, method="perframe", key_tolerance=0.005, key_shape="BEZIER"),
       "retarget perframe")
    last = json.loads(key["shapespace_last_retarget"])
    scene.frame_set(12)
    at_result = fingerprint(ob, verts)
    scene.frame_set(1)
    side["Face"] = {
        "vertices": verts,
        "frame": 12,
        "capture_action": capture.name,
        "result_action": last["action"],
        "at_result": at_result,
        "at_capture": at_capture,
        "implausible": {"alpha": 0.05, "frames": flagged},
        "mapping": json.loads(key["shapespace_mapping"]),
        "last_retarget": last,
        "copy_retarget": {"report": copy_report, "frames": probe, "curves": copied},
    }
    return ob


def _fcurves(action):
    if "slots" not in bpy.types.Action.bl_rna.properties:
        return list(action.fcurves)
    out = []
    for layer in action.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                out += list(bag.fcurves)
    return out


def record_conversions(side, face):
    whole = bpy.data.objects["Face_wholeface"]
    pca = bpy.data.objects["Face_pca"]
    names = list(CAPTURE_KEYS)
    states = [{"jawOpen": 0.6, "mouthSmileLeft": 0.3, "browInnerUp": 0.2},
              {"eyeBlinkLeft": 0.5, "eyeBlinkRight": 0.5, "mouthClose": 0.4}]
    verts = side["Face"]["vertices"]
    out = []
    for s in states:
        full = {n: s.get(n, 0.0) for n in names}
        set_values(whole, full)
        out.append({"sliders": full, **fingerprint(whole, verts)})
    set_values(whole, {n: 0.0 for n in names})
    side["Face_wholeface"] = {"vertices": verts, "states": out,
                              "representation": json.loads(whole.data.shape_keys["shapespace_representation"])}
    rep = json.loads(pca.data.shape_keys["shapespace_representation"])
    side["Face_pca"] = {"representation_form": rep["form"], "sliders": rep["sliders"],
                        "keys": [kb.name for kb in pca.data.shape_keys.key_blocks]}
    side["Face"]["analysis"] = json.loads(face.data.shape_keys["shapespace_analysis"])
    side["Face"]["prior_names"] = json.loads(face.data.shape_keys["shapespace_face_prior"])["names"]


# ----------------------------------------------------------------------------------------- pose space
def build_limb(side):
    arm_data = bpy.data.armatures.new("ArmatureData")
    arm = bpy.data.objects.new("Armature", arm_data)
    arm.location = (-3.0, 0.0, 0.0)
    bpy.context.scene.collection.objects.link(arm)
    activate(arm)
    bpy.ops.object.mode_set(mode="EDIT")
    upper = arm_data.edit_bones.new("Upper")
    upper.head, upper.tail = (0, 0, 0), (0, 0, 1)
    lower = arm_data.edit_bones.new("Lower")
    lower.head, lower.tail = (0, 0, 1), (0, 0, 2)
    lower.parent, lower.use_connect = upper, True
    bpy.ops.object.mode_set(mode="OBJECT")
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
    arm["exertion"] = 0.0
    # a cylinder around the chain, blended weights at the elbow
    rings, around, radius = 21, 12, 0.2
    verts, faces = [], []
    for r in range(rings):
        z = 2.0 * r / (rings - 1)
        for a in range(around):
            t = 2 * math.pi * a / around
            verts.append((radius * math.cos(t), radius * math.sin(t), z))
    for r in range(rings - 1):
        for a in range(around):
            b = (a + 1) % around
            faces.append((r * around + a, r * around + b, (r + 1) * around + b, (r + 1) * around + a))
    me = bpy.data.meshes.new("Limb")
    me.from_pydata(verts, [], faces)
    me.update()
    ob = bpy.data.objects.new("Limb", me)
    ob.location = arm.location
    bpy.context.scene.collection.objects.link(ob)
    g_up, g_lo = ob.vertex_groups.new(name="Upper"), ob.vertex_groups.new(name="Lower")
    for i, (_, _, z) in enumerate(verts):
        s = min(max((z - 0.75) / 0.5, 0.0), 1.0)
        s = s * s * (3 - 2 * s)
        if s < 1.0:
            g_up.add([i], 1.0 - s, "REPLACE")
        if s > 0.0:
            g_lo.add([i], s, "REPLACE")
    mod = ob.modifiers.new("Armature", "ARMATURE")
    mod.object = arm
    activate(ob)
    st = ob.shapespace_psd
    st.armature = arm
    st.method = "SBE"
    ok(bpy.ops.shapespace.psd_add_target(data_path='["exertion"]'), "psd_add_target")
    poses = {"ex1": {"Upper": quat((0, 1, 0), 15), "Lower": quat((1, 0, 0), 60)},
             "ex2": {"Upper": quat((1, 0, 0), 30), "Lower": quat((1, 0, 0), 30)},
             "moved": {"Upper": quat((0, 0, 1), 0), "Lower": quat((1, 0, 0), 90)},
             "between": {"Upper": quat((1, 0, 0), 20), "Lower": quat((1, 0, 0), 45)}}
    sculpts = {"ex1": ((0.2, 0.0, 1.0), 0.25, (0.0, 0.0, 0.0)), "ex2": ((-0.2, 0.0, 0.8), 0.3, (0.0, 0.0, 0.0))}
    exertion = {"ex1": 0.3, "ex2": 0.8}
    for i, ex in enumerate(("ex1", "ex2")):
        set_pose(arm, poses[ex])
        ok(bpy.ops.shapespace.psd_add_example(), f"psd_add_example {ex}")
        example = st.examples[i]
        copy = example.sculpt
        co = np.array([v.co[:] for v in copy.data.vertices])
        # push the posed copy outward (away from its local centre line) near a point of the posed limb
        c, w, _ = sculpts[ex]
        centre = evaluated(ob)[int(np.argmin(np.linalg.norm(np.array(verts) - np.array(c), axis=1)))]
        fall = np.exp(-np.sum((co - centre) ** 2, axis=1) / w ** 2)
        co = co + 0.08 * fall[:, None] * np.array([1.0, 0.5, 0.0] if ex == "ex1" else [-0.6, 1.0, 0.3])
        copy.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
        copy.data.update()
        arm["exertion"] = exertion[ex]
        ok(bpy.ops.shapespace.psd_record_targets(), f"psd_record_targets {ex}")
        ok(bpy.ops.shapespace.psd_apply_example(), f"psd_apply_example {ex}")
    # move example 2 to a third pose (Shape-by-Example pseudo-example)
    set_pose(arm, poses["moved"])
    st.active_example = 1
    ok(bpy.ops.shapespace.psd_move_example(), "psd_move_example")
    key = ob.data.shape_keys
    base = key_co(key.reference_key)
    verts_fp = pick_vertices([key_co(key.key_blocks[e.name]) - base for e in st.examples], 16, 17)
    states = {}
    for name in ("ex1", "ex2", "moved", "between"):
        set_pose(arm, poses[name])
        arm["exertion"] = -1.0
        ok(bpy.ops.shapespace.psd_update(), f"psd_update {name}")
        states[name] = {"pose": poses[name], "weights": {e.name: key.key_blocks[e.name].value for e in st.examples},
                        "exertion": float(arm["exertion"]), **fingerprint(ob, verts_fp)}
    ok(bpy.ops.shapespace.psd_confidence(heat_map=False), "psd_confidence")
    set_pose(arm, {"Upper": [1, 0, 0, 0], "Lower": [1, 0, 0, 0]})
    arm["exertion"] = 0.0
    set_values(ob, {e.name: 0.0 for e in st.examples})
    side["Limb"] = {
        "vertices": verts_fp,
        "states": states,
        "examples": [{"name": e.name, "pose": json.loads(e.pose), "pseudo_pose": json.loads(e.pseudo_pose)
                      if e.pseudo_pose else None, "target_values": json.loads(e.target_values),
                      "sculpt": e.sculpt.name if e.sculpt else None} for e in st.examples],
        "readers": [[r.kind, r.source, r.scale] for r in st.readers],
        "sculpt_at_ex1": {"co": np.array([v.co[:] for v in st.examples[0].sculpt.data.vertices])[verts_fp].tolist()},
    }


# ----------------------------------------------------------------------------------------- main
def main(argv):
    if len(argv) != 2:
        raise SystemExit("usage: make_v010_fixture.py OLD_CHECKOUT OUT.blend")
    root, out = argv
    out = os.path.abspath(out)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    load_addon(root)
    scene = bpy.context.scene
    scene.render.fps, scene.frame_start, scene.frame_end = FPS, FRAMES[0], FRAMES[1]
    scene.frame_set(1)
    side = {"made_by": "ShapeSpace 0.1.0 (e07c414)", "blender": bpy.app.version_string}
    build_pinned(side)
    build_driven(side)
    face = build_face(side)
    record_conversions(side, face)
    build_limb(side)
    checks = {}
    for name in ("Pinned", "Driven", "Face", "Face_wholeface", "Face_pca", "Limb"):
        activate(bpy.data.objects[name])
        checks[name] = sorted(bpy.ops.shapespace.check_rig())
    side["check_rig"] = checks
    activate(face)
    scene.frame_set(1)
    bpy.ops.wm.save_as_mainfile(filepath=out, compress=True)
    with open(os.path.splitext(out)[0] + ".json", "w") as fh:
        json.dump(side, fh, indent=1, sort_keys=True)
        fh.write("\n")
    print(f"wrote {out} ({os.path.getsize(out)} bytes)")


if __name__ == "__main__":
    main(sys.argv[1:])
