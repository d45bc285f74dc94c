"""Test rigs for issue #25, built from Blender's own parts on a shared real head (facecap's ARKit head).

- :func:`hybrid_rig`: facecap's head (2,694 vertices, 52 ARKit shape keys) + an armature with a static head bone
  and a jaw bone hinged in front of the ears (:func:`jaw_hinge`, from the head's named landmarks; Limit Rotation
  constraint, Y locked) bound by an Armature modifier; the jaw's vertex group is hand-computed from the head's
  own ``jawOpen`` shape (weight ∝ how far ``jawOpen`` moves the vertex, saturating at 2/3 of its largest
  motion) and the head bone's is the rest (1 − jaw: the Armature modifier normalises the weights, so without it
  every vertex the jaw touches would follow the jaw fully — the upper lip too), so the bone moves the chin and
  lower lip region, falling off through the lips and cheeks.  Controls: jaw rotation X/Z and six shape keys.
- :func:`rigify_rig`: the same head with Rigify's face, the human meta-rig seated on the head's named landmarks
  (:data:`RIGIFY_SEATS`), generated and bound with automatic weights.
- :func:`driver_rig`: the same head driven by a control armature through drivers: a bone location drives
  ``jawOpen`` linearly and an in-between shape (half open + funnel) through a hat expression; another bone's
  location drives ``mouthSmile_L`` through ``sin`` (nonlinear) and a third ``mouthSmile_R`` through an
  averaged (non-scripted) driver; a bone's rotation drives ``browInnerUp`` through ``var + 2 var²``; a custom
  property on the armature drives both blinks through ``var (0.5 + var)``.  Bounds from Limit Location / Limit
  Rotation constraints and the property's soft range.

Each builder returns a :class:`Rig` with the mesh, the armature, the control set and a sampler of random
control poses inside the bounds.  Used by ``tests/bridge/test_rig*.py`` and ``tools/bench_rig.py``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import addon_utils
import bpy
import numpy as np

import package  # tools/package.py

SS = package.load()
from shapespace.bridge import assets  # noqa: E402
from shapespace.bridge import rig as brig  # noqa: E402
from shapespace.core.authoring.named import load_head_file  # noqa: E402
from shapespace.core.authoring.registration import similarity  # noqa: E402

FACECAP = os.path.join("facecap", "facecap_decoded.glb")
#: The head's landmarks files (``tools/landmarks/<head>.json``: 26 named landmarks per shared head).
LANDMARKS = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "tools",
                         "landmarks")
HYBRID_KEYS = ("mouthSmile_L", "mouthSmile_R", "browInnerUp", "eyeBlink_L", "mouthFunnel", "cheekPuff")


@dataclass
class Rig:
    mesh: object
    armature: object
    controls: object
    name: str
    pose_lo: np.ndarray = None
    pose_hi: np.ndarray = None

    def random_pose(self, rng, spread: float = 0.8) -> np.ndarray:
        """Random controls uniformly in the inner ``spread`` of every channel's bounds (``pose_lo``/``pose_hi``
        when set, for channels whose bounds are wider than a plausible pose), above the rest value for channels
        whose rest sits on a bound."""
        lo = self.controls.lo if self.pose_lo is None else self.pose_lo
        hi = self.controls.hi if self.pose_hi is None else self.pose_hi
        c0 = brig.read_controls(self.controls)
        a = np.where(c0 <= lo, lo, c0 - spread * (c0 - lo))
        b = c0 + spread * (hi - c0)
        return rng.uniform(a, b)

    def world_points(self) -> np.ndarray:
        """Blender's evaluated world-space vertex positions of the mesh, float64 (V, 3)."""
        bpy.context.view_layer.update()
        dg = bpy.context.evaluated_depsgraph_get()
        ob = self.mesh.evaluated_get(dg)
        me = ob.to_mesh()
        try:
            co = np.empty(len(me.vertices) * 3, np.float32)
            me.vertices.foreach_get("co", co)
        finally:
            ob.to_mesh_clear()
        m = np.array(self.mesh.matrix_world, dtype=np.float64)
        return co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]


def load_head(path: str, mesh_name: str = "Mesh_2"):
    """A shared head (facecap's ``Mesh_2`` by default) on an empty scene, its shape-key animation removed, every
    slider at 0."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(path, replace=False)
    ob = bpy.data.objects[mesh_name]
    if ob.data.shape_keys.animation_data is not None:
        ob.data.shape_keys.animation_data_clear()
    for kb in ob.data.shape_keys.key_blocks[1:]:
        kb.value = 0.0
    return ob


def _shape_delta(ob, name: str) -> np.ndarray:
    """World-space displacement (V, 3) of shape key ``name`` at 1 (linear part of matrix_world)."""
    kbs = ob.data.shape_keys.key_blocks
    base = np.empty(len(ob.data.vertices) * 3, np.float32)
    co = np.empty_like(base)
    kbs[0].data.foreach_get("co", base)
    kbs[name].data.foreach_get("co", co)
    m = np.array(ob.matrix_world, dtype=np.float64)[:3, :3]
    return (co - base).reshape(-1, 3).astype(np.float64) @ m.T


def _armature(name: str, bones: dict, location=(0.0, 0.0, 0.0)):
    """An armature object with ``bones`` {name: (head, tail)} (world space), linked to the scene, Object Mode."""
    arm = bpy.data.armatures.new(name)
    ob = bpy.data.objects.new(name, arm)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.objects.active = ob
    bpy.ops.object.mode_set(mode="EDIT")
    for bname, (head, tail) in bones.items():
        eb = arm.edit_bones.new(bname)
        eb.head, eb.tail = head, tail
    bpy.ops.object.mode_set(mode="OBJECT")
    return ob


def _limit_rotation(pb, x=None, y=None, z=None):
    con = pb.constraints.new("LIMIT_ROTATION")
    con.owner_space = "LOCAL"
    for axis, lim in zip("xyz", (x, y, z)):
        if lim is not None:
            setattr(con, f"use_limit_{axis}", True)
            setattr(con, f"min_{axis}", lim[0])
            setattr(con, f"max_{axis}", lim[1])
    return con


def _limit_location(pb, y):
    con = pb.constraints.new("LIMIT_LOCATION")
    con.owner_space = "LOCAL"
    con.use_min_y = con.use_max_y = True
    con.min_y, con.max_y = y
    return con


def _face_bones(ob, arm, count: int, moving) -> list:
    """``count`` game-rig face bones (no parent) at farthest-point samples of the ``moving`` vertices (V,) bool,
    each weighting the vertices within a tenth of the head's diagonal (Gaussian falloff, Blender normalises),
    Limit Location ±1/50 of the diagonal on every axis; returns their location channels (3 per bone)."""
    world = Rig(ob, None, None, "").world_points()
    diag = diagonal(world)
    cand = np.flatnonzero(moving)
    picked = [cand[np.argmax(world[cand, 1])]]
    dist = np.linalg.norm(world[cand] - world[picked[0]], axis=1)
    for _ in range(count - 1):
        picked.append(cand[np.argmax(dist)])
        dist = np.minimum(dist, np.linalg.norm(world[cand] - world[picked[-1]], axis=1))
    names = [f"face.{k:03d}" for k in range(count)]
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for name, v in zip(names, picked):
        eb = arm.data.edit_bones.new(name)
        eb.head, eb.tail = tuple(world[v]), tuple(world[v] + [0.0, 0.0, 0.02 * diag])
    bpy.ops.object.mode_set(mode="OBJECT")
    chans = []
    for name, v in zip(names, picked):
        d = np.linalg.norm(world - world[v], axis=1) / (0.1 * diag)
        w = np.round(np.exp(-2.0 * d * d) * (d < 1.0), 2)
        group = ob.vertex_groups.new(name=name)
        for value in np.unique(w[w > 0]):
            group.add(np.flatnonzero(w == value).tolist(), float(value), "REPLACE")
        con = arm.pose.bones[name].constraints.new("LIMIT_LOCATION")
        con.owner_space = "LOCAL"
        r = 0.02 * diag
        for axis in "xyz":
            setattr(con, f"use_min_{axis}", True)
            setattr(con, f"use_max_{axis}", True)
            setattr(con, f"min_{axis}", -r)
            setattr(con, f"max_{axis}", r)
        chans += [brig.bone_channel(arm, name, "location", a) for a in range(3)]
    return chans


#: Named landmarks file (``tools/landmarks/``) of each shared head's mesh.
HEAD_MARKS = {"Mesh_2": "facecap.json", "ICTFace": "ict.json"}


def jaw_hinge(world: np.ndarray, marks: dict) -> np.ndarray:
    """Where a rigger puts the jaw's hinge (world (3,)): just in front of the ears, at their middle height, on
    the midline.  Face frame from the named landmarks: side = jaw_angle_R → jaw_angle_L, up = chin → brows (made
    perpendicular), forward = side × up.  The ears are the vertices between the jaw angles' and the brows' height
    that stick out sideways (lateral coordinate within 8 % of the largest); the hinge is their front-most point's
    depth at their mean height."""
    p = {n: world[v] for n, v in marks.items()}
    side = p["jaw_angle_L"] - p["jaw_angle_R"]
    side /= np.linalg.norm(side)
    up = 0.5 * (p["brow_mid_L"] + p["brow_mid_R"]) - p["chin"]
    up -= (up @ side) * side
    up /= np.linalg.norm(up)
    fwd = np.cross(side, up)
    mid = 0.5 * (p["jaw_angle_L"] + p["jaw_angle_R"])
    rel = world - mid
    h, lat, f = rel @ up, rel @ side, rel @ fwd
    band = (h > 0.0) & (h < (p["brow_mid_L"] - mid) @ up)
    ears = band & (np.abs(lat) > 0.92 * np.abs(lat[band]).max())
    midline = (0.5 * (p["chin"] + p["lip_upper_outer"]) - mid) @ side
    return mid + up * h[ears].mean() + fwd * f[ears].max() + side * midline


def hybrid_rig(path: str, mesh_name: str = "Mesh_2", keys=HYBRID_KEYS, name: str = "hybrid",
               face_bones: int = 0) -> Rig:
    """A shared head + a weighted jaw bone + its shape keys ``keys`` (facecap and six keys by default; ``None``:
    every key that moves a vertex) (module doc); ``face_bones`` > 0 adds that many game-rig face bones with
    their location channels (:func:`_face_bones`: ICT with every key and 30 bones is a ~150-channel rig)."""
    ob = load_head(path, mesh_name)
    jaw = _shape_delta(ob, "jawOpen")
    mag = np.linalg.norm(jaw, axis=1)
    world = Rig(ob, None, None, "").world_points()
    chin = world[np.argmax(mag)]
    pivot = jaw_hinge(world, load_head_file(os.path.join(LANDMARKS, HEAD_MARKS[mesh_name]), len(world)))
    top = pivot + np.array([0.0, 0.0, 0.5 * np.linalg.norm(chin - pivot)])
    arm = _armature("FaceRig", {"head": (tuple(pivot), tuple(top)), "jaw": (tuple(pivot), tuple(chin))})
    pb = arm.pose.bones["jaw"]
    pb.rotation_mode = "XYZ"
    pb.lock_rotation[1] = True
    _limit_rotation(pb, x=(-0.35, 0.35), z=(-0.15, 0.15))
    group = ob.vertex_groups.new(name="jaw")
    weights = np.clip(1.5 * mag / mag.max(), 0.0, 1.0)
    for g, wg in ((group, weights), (ob.vertex_groups.new(name="head"), 1.0 - weights)):
        for w in np.unique(np.round(wg[wg > 0], 3)):
            idx = np.flatnonzero(np.isclose(np.round(wg, 3), w))
            g.add(idx.tolist(), float(w), "REPLACE")
    mod = ob.modifiers.new("Armature", "ARMATURE")
    mod.object = arm
    chans = [brig.bone_channel(arm, "jaw", "rotation", 0), brig.bone_channel(arm, "jaw", "rotation", 2)]
    if keys is None:
        keys = [kb.name for kb in ob.data.shape_keys.key_blocks[1:] if np.abs(_shape_delta(ob, kb.name)).max() > 0]
    chans += [brig.shape_key_channel(ob, k) for k in keys]
    if face_bones:
        moving = np.zeros(len(ob.data.vertices), bool)
        for k in keys:
            moving |= np.abs(_shape_delta(ob, k)).max(axis=1) > 0
        chans += _face_bones(ob, arm, face_bones, moving)
    bpy.context.view_layer.update()
    return Rig(ob, arm, brig.control_set(chans), name)


def _driver(key_block, expression: str, arm, target: dict, dtype: str = "SCRIPTED"):
    fc = key_block.driver_add("value")
    drv = fc.driver
    drv.type = dtype
    var = drv.variables.new()
    var.name = "var"
    if "prop" in target:
        var.type = "SINGLE_PROP"
        var.targets[0].id = arm
        var.targets[0].data_path = f'["{target["prop"]}"]'
    else:
        var.type = "TRANSFORMS"
        var.targets[0].id = arm
        var.targets[0].bone_target = target["bone"]
        var.targets[0].transform_type = target["transform"]
        var.targets[0].transform_space = "LOCAL_SPACE"
    if dtype == "SCRIPTED":
        drv.expression = expression
    return fc


def driver_rig(path: str) -> Rig:
    """Facecap's head driven through drivers by a control armature and a custom property (module doc)."""
    ob = load_head(path)
    world = Rig(ob, None, None, "").world_points()
    top = world.max(0)
    names = ("ctl_jaw", "ctl_smile_L", "ctl_smile_R", "ctl_brow")
    bones = {n: ((0.3 * i, top[1] + 0.2, top[2]), (0.3 * i, top[1] + 0.2, top[2] + 0.1)) for i, n in enumerate(names)}
    arm = _armature("Controls", bones)
    for n in names[:3]:
        pb = arm.pose.bones[n]
        pb.lock_location = (True, False, True)
        _limit_location(pb, (0.0, 0.5))
    brow = arm.pose.bones["ctl_brow"]
    brow.rotation_mode = "XYZ"
    brow.lock_rotation = (False, True, True)
    _limit_rotation(brow, x=(0.0, 0.6))
    arm["blink"] = 0.0
    arm.id_properties_ui("blink").update(min=0.0, max=1.0, soft_min=0.0, soft_max=1.0)
    kbs = ob.data.shape_keys.key_blocks
    jaw, funnel = _shape_delta(ob, "jawOpen"), _shape_delta(ob, "mouthFunnel")
    inb = ob.shape_key_add(name="jawOpen_half", from_mix=False)
    base = np.empty(len(ob.data.vertices) * 3, np.float32)
    kbs[0].data.foreach_get("co", base)
    minv = np.linalg.inv(np.array(ob.matrix_world, dtype=np.float64)[:3, :3])
    extra = (0.3 * funnel + 0.2 * jaw) @ minv.T
    inb.data.foreach_set("co", (base.reshape(-1, 3) + extra).astype(np.float32).ravel())
    jaw_t = {"bone": "ctl_jaw", "transform": "LOC_Y"}
    _driver(kbs["jawOpen"], "var * 2.0", arm, jaw_t)
    _driver(inb, "max(0.0, 1.0 - abs(var * 2.0 - 0.5) * 2.0)", arm, jaw_t)
    _driver(kbs["mouthSmile_L"], "sin(var * 3.0)", arm, {"bone": "ctl_smile_L", "transform": "LOC_Y"})
    _driver(kbs["mouthSmile_R"], "", arm, {"bone": "ctl_smile_R", "transform": "LOC_Y"}, dtype="AVERAGE")
    _driver(kbs["browInnerUp"], "var + 2.0 * var * var", arm, {"bone": "ctl_brow", "transform": "ROT_X"})
    for side in ("L", "R"):
        _driver(kbs[f"eyeBlink_{side}"], "var * (0.5 + var)", arm, {"prop": "blink"})
    chans = [brig.bone_channel(arm, n, "location", 1) for n in names[:3]]
    chans += [brig.bone_channel(arm, "ctl_brow", "rotation", 0), brig.property_channel(arm, "blink")]
    bpy.context.view_layer.update()
    return Rig(ob, arm, brig.control_set(chans), "driver")


#: Rigify face controls (generated rig) the Rigify test rig solves for: (bone, kind, axes) — the jaw's rotation
#: (open, sideways) and, as an animator moves them, the lip corners, the upper and lower lip, the middle of each
#: brow and upper lid and the chin in all three directions (the lips push forward for a pucker or funnel).
RIGIFY_CONTROLS = (("jaw_master", "rotation", (0, 2)), ("lips.L", "location", (0, 1, 2)),
                   ("lips.R", "location", (0, 1, 2)), ("lip.T", "location", (0, 1, 2)),
                   ("lip.B", "location", (0, 1, 2)), ("brow.T.L.002", "location", (0, 1, 2)),
                   ("brow.T.R.002", "location", (0, 1, 2)), ("lid.T.L.002", "location", (0, 1, 2)),
                   ("lid.T.R.002", "location", (0, 1, 2)), ("chin", "location", (0, 1, 2)))


def _metarig_head_only():
    """Rigify's human meta-rig cut down to the spine chain and the face (Edit Mode removal of every other
    bone), in Object Mode."""
    bpy.ops.object.armature_human_metarig_add()
    meta = bpy.context.object
    bpy.ops.object.mode_set(mode="EDIT")
    eb = meta.data.edit_bones
    keep = set()
    b = eb["spine.006"]
    while b is not None:
        keep.add(b.name)
        b = b.parent
    stack = [eb["spine.006"]]
    while stack:
        b = stack.pop()
        keep.add(b.name)
        stack += list(b.children)
    for e in list(eb):
        if e.name not in keep:
            eb.remove(e)
    bpy.ops.object.mode_set(mode="OBJECT")
    return meta


#: Where the meta-rig's face is seated on the head's named landmarks (``core/authoring/named.py``): meta-rig
#: point → landmark name(s), their mean when two (the lip bones run along the middle of each lip, between its
#: outer and inner midline landmarks).  A point is ``(bone, "head" | "tail")``; ``.R`` bones mirror ``.L``.
RIGIFY_SEATS = {
    ("lid.B.L", "head"): ("eye_inner_L",), ("lid.T.L", "head"): ("eye_outer_L",),
    ("lid.T.L.002", "head"): ("lid_upper_L",), ("lid.B.L.002", "head"): ("lid_lower_L",),
    ("brow.T.L.003", "head"): ("brow_inner_L",), ("brow.T.L.002", "head"): ("brow_mid_L",),
    ("brow.T.L.001", "head"): ("brow_outer_L",),
    ("nose.002", "head"): ("nose_tip",), ("nose.L.001", "head"): ("nostril_L",),
    ("lip.T.L.001", "tail"): ("mouth_corner_L",), ("lip.T.L", "head"): ("lip_upper_outer", "lip_upper_inner"),
    ("lip.B.L", "head"): ("lip_lower_outer", "lip_lower_inner"),
    ("chin", "tail"): ("chin",), ("jaw.L", "tail"): ("jaw_angle_L",),
}


def _mirror_seat(bone: str) -> str:
    return bone.replace(".L", ".R") if ".L" in bone else bone


def rigify_seats(marks: dict, world: np.ndarray) -> dict:
    """Every meta-rig face point of :data:`RIGIFY_SEATS` (both sides) → its place on the head (world, (3,))."""
    out = {}
    for (bone, end), names in RIGIFY_SEATS.items():
        out[(bone, end)] = world[[marks[n] for n in names]].mean(0)
        if bone.endswith(".L") or ".L." in bone:
            out[(_mirror_seat(bone), end)] = world[[marks[n.replace("_L", "_R")] for n in names]].mean(0)
    return out


def _shepard(points: np.ndarray, at: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Inverse-squared-distance blend (Shepard) of ``offsets`` (m, 3) given at ``at`` (m, 3), evaluated at
    ``points`` (p, 3): exact at ``at``, never larger than the largest offset (no extrapolation)."""
    d2 = np.sum((points[:, None] - at[None]) ** 2, axis=-1)
    w = 1.0 / np.maximum(d2, 1e-18)
    return (w @ offsets) / w.sum(axis=1, keepdims=True)


def _seat_metarig(meta, seats: dict) -> None:
    """Fit the meta-rig's face to the head as a rigger does: move every meta-rig bone by the similarity (scale,
    rotation, translation: Umeyama) that best takes the seat points (:func:`rigify_seats`) to their places on the
    head, then every face bone by the smooth blend (:func:`_shepard`) of the seat points' remaining offsets, so
    each seat point lands on its landmark and the bones between follow.  Two bones are placed as the Rigify
    docs ask rather than warped: each eye from the middle of its seated lid ring (the meta-rig's eye offset from
    its lid ring, scaled; both eyes parallel, looking where the meta-rig's look), and the jaw from the hinge (the
    middle of the temples' lower ends, where the jaw line starts under the ears) to the chin."""
    bpy.context.view_layer.objects.active = meta
    bpy.ops.object.mode_set(mode="EDIT")
    eb = meta.data.edit_bones
    keys = list(seats)
    src = np.array([list(getattr(eb[b], end)) for b, end in keys])
    dst = np.array([seats[k] for k in keys])
    s, R, t = similarity(src, dst)
    A = s * R
    face = {b.name for b in eb["face"].children_recursive} | {"face"}
    moved = src @ A.T + t
    ends = {}
    for b in eb:
        for end in ("head", "tail"):
            p = np.array(list(getattr(b, end))) @ A.T + t
            ends[(b.name, end)] = p + (_shepard(p[None], moved, dst - moved)[0] if b.name in face else 0.0)
    for side in ("L", "R"):
        ring = [f"lid.{tb}.{side}{k}" for tb in "TB" for k in ("", ".001", ".002", ".003")]
        meta_c = np.mean([list(eb[n].head) for n in ring], axis=0)
        seat_c = np.mean([ends[(n, "head")] for n in ring], axis=0)
        eye = eb[f"eye.{side}"]
        ends[(eye.name, "head")] = seat_c + (np.array(list(eye.head)) - meta_c) @ A.T
        ends[(eye.name, "tail")] = ends[(eye.name, "head")] + (np.array(list(eye.tail - eye.head))) @ A.T
    hinge = 0.5 * (ends[("jaw.L", "head")] + ends[("jaw.R", "head")])
    ends[("jaw", "head")] = np.array([0.5 * (ends[("chin", "head")][0] + ends[("chin", "tail")][0]), *hinge[1:]])
    for b in eb:
        b.head, b.tail = tuple(ends[(b.name, "head")]), tuple(ends[(b.name, "tail")])
    bpy.ops.object.mode_set(mode="OBJECT")


def rigify_rig(path: str, marks: str = os.path.join(LANDMARKS, "facecap.json"), controls=None) -> Rig:
    """Facecap's head with Rigify's face: the human meta-rig (head and face only) seated on the head's named
    landmarks ``marks`` (:func:`_seat_metarig`: eye corners, lids, brows, nose, mouth corners, lips, chin, jaw
    angles, :data:`RIGIFY_SEATS`), generated by Rigify, bound with automatic weights; controls: jaw_master
    rotation and the lips, brows and upper lids' location (:data:`RIGIFY_CONTROLS`), each location bounded by a
    Limit Location constraint (±0.1, about 3 % of the head's diagonal) as an animator would; random poses rotate
    the jaw by at most ±0.2 rad."""
    ob = load_head(path)
    addon_utils.enable("rigify", default_set=True)
    world = Rig(ob, None, None, "").world_points()
    meta = _metarig_head_only()
    _seat_metarig(meta, rigify_seats(load_head_file(marks, len(ob.data.vertices)), world))
    bpy.ops.pose.rigify_generate()
    arm = bpy.context.object
    addon_utils.disable("rigify", default_set=True)           # the generated rig does not need the add-on
    bpy.ops.object.select_all(action="DESELECT")
    ob.select_set(True)
    arm.select_set(True)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.parent_set(type="ARMATURE_AUTO", keep_transform=True)
    bpy.ops.object.select_all(action="DESELECT")
    chans, pose_lo, pose_hi = [], [], []
    for bone, kind, axes in RIGIFY_CONTROLS if controls is None else controls:
        pb = arm.pose.bones[bone]
        if kind == "location":
            con = pb.constraints.new("LIMIT_LOCATION")
            con.owner_space = "LOCAL"
            for a in "xyz":
                setattr(con, f"use_min_{a}", True)
                setattr(con, f"use_max_{a}", True)
                setattr(con, f"min_{a}", -0.1)
                setattr(con, f"max_{a}", 0.1)
        for axis in axes:
            ch = brig.bone_channel(arm, bone, kind, axis)
            chans.append(ch)
            pose_lo.append(-0.2 if kind == "rotation" else ch.lo)
            pose_hi.append(0.2 if kind == "rotation" else ch.hi)
    bpy.context.view_layer.update()
    return Rig(ob, arm, brig.control_set(chans), "rigify", np.array(pose_lo), np.array(pose_hi))


def pin_vertices(rig: Rig, count: int, rng) -> np.ndarray:
    """``count`` distinct vertices spread over the channels: channel by channel in turn, one of the vertices
    that channel alone moves most (among its top 20), so every channel is pinned down."""
    rest = rig.world_points()
    c0 = brig.read_controls(rig.controls)
    far = rig.random_pose(rng, 1.0)
    tops = []
    for i in range(len(c0)):
        c = c0.copy()
        c[i] = far[i] if abs(far[i] - c0[i]) > 1e-3 else rig.controls.hi[i]
        brig.apply_controls(rig.controls, c)
        tops.append(list(np.argsort(np.linalg.norm(rig.world_points() - rest, axis=1))[::-1][:20]))
    brig.apply_controls(rig.controls, c0)
    chosen = []
    while len(chosen) < count:
        top = tops[len(chosen) % len(tops)]
        free = [v for v in top if v not in chosen]
        chosen.append(free[int(rng.integers(len(free)))])
    return np.sort(np.array(chosen, dtype=np.int64))


def smooth_take(rig: Rig, rng, frames: int, spread: float = 0.8) -> np.ndarray:
    """Random smooth control curves (F, n) of ``frames`` frames: per channel a sum of three low-frequency sines
    with random phases, rescaled into the inner ``spread`` of the channel's pose range (:meth:`Rig.random_pose`'s
    range: the rest value on a bound stays a bound)."""
    lo = rig.controls.lo if rig.pose_lo is None else rig.pose_lo
    hi = rig.controls.hi if rig.pose_hi is None else rig.pose_hi
    c0 = brig.read_controls(rig.controls)
    a = np.where(c0 <= lo, lo, c0 - spread * (c0 - lo))
    b = c0 + spread * (hi - c0)
    n = len(c0)
    t = np.linspace(0.0, 1.0, frames)[:, None]
    u = sum(np.sin(2 * np.pi * (k + 1) * t * rng.uniform(0.3, 1.0, n) + rng.uniform(0, 2 * np.pi, n)) / (k + 1)
            for k in range(3))
    u = 0.5 + 0.5 * (u - u.mean(0)) / np.abs(u - u.mean(0)).max(0)
    return a + u * (b - a)


def take_surface(rig: Rig, values) -> np.ndarray:
    """Blender's evaluated world-space surface (F, V, 3) of the rig at each row of control ``values`` (F, n);
    the rig is given back its controls."""
    c0 = brig.read_controls(rig.controls)
    out = []
    for c in values:
        brig.apply_controls(rig.controls, c)
        out.append(rig.world_points())
    brig.apply_controls(rig.controls, c0)
    return np.stack(out)


def take_vertices(rig: Rig, rng, every: int = 20) -> np.ndarray:
    """The vertices a test take targets: pins spread over the channels (:func:`pin_vertices`, two per channel,
    10–40) plus every ``every``-th vertex."""
    pins = pin_vertices(rig, int(np.clip(2 * len(rig.controls), 10, 40)), rng)
    return np.union1d(pins, np.arange(0, len(rig.mesh.data.vertices), every))


def played_surface(rig: Rig, frames) -> np.ndarray:
    """Blender's evaluation of the rig as its actions play (``frame_set``), at each frame (F, V, 3)."""
    scene = bpy.context.scene
    out = []
    for f in frames:
        scene.frame_set(int(f))
        out.append(rig.world_points())
    return np.stack(out)


def diagonal(points) -> float:
    return float(np.linalg.norm(points.max(0) - points.min(0)))


__all__ = ["Rig", "driver_rig", "hybrid_rig", "load_head", "pin_vertices", "diagonal", "played_surface",
           "smooth_take", "take_surface", "take_vertices"]
