"""Pose-space examples in Blender: reading poses, posed sculpt copies, applying sculpts as correctives."""
from __future__ import annotations

import json

import bpy
import numpy as np

from ..core import rbf
from ..core.posespace.inversion import invert_deformation
from ..core.posespace.readers import PoseReader, pose_features
from ..core.posespace.psd import example_issues, train_psd
from ..core.result import ShapeSpaceError
from ..core.skinning import deform
from . import meshes, shapekeys, skin
from .arrays import read_float, write_float

SCULPT_SUFFIX = "_sculpt"


def settings(obj):
    return obj.shapespace_psd


def armature_of(obj):
    st = settings(obj)
    if st.armature is not None:
        if st.armature.type != "ARMATURE":
            raise ShapeSpaceError(f"{st.armature.name!r}, chosen as the pose-space armature, is not an armature",
                                  "not_armature")
        return st.armature
    mods = skin.armature_modifiers(obj)
    return mods[0].object if mods else None


def readers(obj) -> list:
    return [PoseReader(r.kind.lower(), r.source, r.scale) for r in settings(obj).readers]


def _local_quaternion(pose_bone) -> np.ndarray:
    return np.array(pose_bone.matrix_basis.to_quaternion(), dtype=np.float64)


def read_pose(obj) -> np.ndarray:
    """The current pose-space location of ``obj``'s rig (feature vector)."""
    arm = armature_of(obj)
    rs = readers(obj)
    if not rs:
        raise ShapeSpaceError("the pose space has no readers: add the bones that drive the correctives",
                              "no_readers")
    values = []
    for r in rs:
        if r.is_bone:
            if arm is None:
                raise ShapeSpaceError(f"{obj.name!r} has no armature to read bone {r.source!r} from", "no_armature")
            pb = arm.pose.bones.get(r.source)
            if pb is None:
                raise ShapeSpaceError(f"bone {r.source!r} no longer exists in {arm.name!r}: was it renamed "
                                      "or deleted? Fix the pose-space reader", "missing_bone")
            values.append(np.array(pb.matrix_basis.translation) if r.kind == "location" else _local_quaternion(pb))
        elif r.kind == "shape_key":
            blocks = obj.data.shape_keys.key_blocks if obj.data.shape_keys else {}
            if r.source not in blocks:
                raise ShapeSpaceError(f"shape key {r.source!r} no longer exists", "missing_key")
            values.append(blocks[r.source].value)
        else:
            owner = arm if arm is not None else obj
            try:
                values.append(float(owner.path_resolve(r.source)))
            except (ValueError, TypeError):
                raise ShapeSpaceError(f"property {r.source!r} not found on {owner.name!r}", "missing_property") \
                    from None
    return pose_features(rs, values)


def default_readers(obj) -> list:
    """Rotation readers for every deforming bone posed away from rest (a sensible first pose space)."""
    arm = armature_of(obj)
    if arm is None:
        raise ShapeSpaceError(f"{obj.name!r} has no Armature modifier", "no_armature")
    out = []
    for pb in arm.pose.bones:
        q = _local_quaternion(pb)
        if pb.bone.use_deform and abs(abs(q[0]) - 1.0) > 1e-6:
            out.append(pb.name)
    return out


def correctives_meta(obj) -> dict:
    """``{example key name: {"pose": [...], "pseudo": [...] or None}}`` from the examples list."""
    out = {}
    for ex in settings(obj).examples:
        out[ex.name] = {"pose": json.loads(ex.pose) if ex.pose else None,
                        "pseudo": json.loads(ex.pseudo_pose) if ex.pseudo_pose else None}
    return out


def _example_keys(obj) -> set:
    return {ex.name for ex in settings(obj).examples} | {WPSD_KEY}


def pre_armature_positions(obj) -> np.ndarray:
    """Mesh positions before the Armature modifier, without the pose-space correctives (object space)."""
    model = shapekeys.read_blendshape_model(obj)
    w = model.values.copy()
    for name in _example_keys(obj):
        if name in model.names:
            w[model.index(name)] = 0.0
    return model.evaluate(w)


def check_topology(obj) -> None:
    if obj.data.shape_keys is not None:
        errors = [i for i in shapekeys.check_shape_keys(obj) if i.severity == "error" and i.code != "no_targets"]
        if errors:
            raise ShapeSpaceError(errors[0].message, errors[0].code)


def add_example(obj, name: str = None, make_sculpt_copy: bool = True):
    """Record the current pose as a new example, create its (empty) corrective key and a posed copy to sculpt."""
    check_topology(obj)
    st = settings(obj)
    if not len(st.readers):
        for bone in default_readers(obj):
            r = st.readers.add()
            r.kind, r.source, r.scale = "ROTATION", bone, 1.0
        if not len(st.readers):
            raise ShapeSpaceError("pose the rig away from its rest pose first (no bone is rotated), or add "
                                  "pose-space readers by hand", "no_readers")
    pose = read_pose(obj)
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    name = name or f"PSD_{len(st.examples) + 1:02d}"
    kb = obj.shape_key_add(name=name, from_mix=False)
    kb.slider_min, kb.slider_max = -10.0, 10.0   # cardinal weights may leave [0, 1]
    kb.value = 0.0
    ex = st.examples.add()
    ex.name = kb.name
    ex.pose = json.dumps([float(v) for v in pose])
    ex.target_values = json.dumps(read_targets(obj))
    st.active_example = len(st.examples) - 1
    st.revision += 1
    copy = make_sculpt_copy and posed_copy(obj, kb.name + SCULPT_SUFFIX)
    if copy:
        ex.sculpt = copy
    return ex.name


def posed_copy(obj, name: str):
    """A plain mesh object holding ``obj``'s evaluated (posed) surface, at the same place, for sculpting."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = bpy.data.meshes.new_from_object(ob_eval)
    mesh.name = name
    copy = bpy.data.objects.new(name, mesh)
    copy.matrix_world = obj.matrix_world.copy()
    for coll in obj.users_collection:
        coll.objects.link(copy)
    return copy


def apply_example(obj, example_name: str, sculpt_positions=None):
    """Invert the example's sculpt to rest space and store it in the example's shape key.

    ``sculpt_positions`` (p, 3) in ``obj``'s object space; default: the sculpt copy's vertices.
    Returns the InversionResult.
    """
    check_topology(obj)
    st = settings(obj)
    ex = st.examples.get(example_name)
    if ex is None:
        raise ShapeSpaceError(f"there is no example {example_name!r}", "missing_example")
    p = len(obj.data.vertices)
    if sculpt_positions is None:
        if ex.sculpt is None:
            raise ShapeSpaceError(f"example {example_name!r} has no sculpt copy: give sculpt positions", "no_sculpt")
        if len(ex.sculpt.data.vertices) != p:
            raise ShapeSpaceError(f"the sculpt copy of {example_name!r} has {len(ex.sculpt.data.vertices)} "
                                  f"vertices, the mesh has {p}: the topology changed", "vertex_count")
        world = meshes.to_world(ex.sculpt, meshes.vertex_positions(ex.sculpt.data))
        sculpt_positions = meshes.to_local(obj, world)
    sculpt_positions = np.asarray(sculpt_positions, dtype=np.float64)
    if sculpt_positions.shape != (p, 3):
        raise ShapeSpaceError(f"sculpt positions must have shape ({p}, 3)", "shape")
    rest = pre_armature_positions(obj)
    if skin.armature_modifiers(obj) and modelled_exactly(obj):
        rig = skin.read_skinning(obj)
        poses = skin.modifier_poses(obj)
        result = invert_deformation(lambda x: deform(x, rig, poses), rest, sculpt_positions)
    elif [m for m in obj.modifiers if m.show_viewport]:
        result = _invert_through_blender(obj, rest, sculpt_positions)
    else:
        from ..core.posespace.inversion import InversionResult
        result = InversionResult(sculpt_positions - rest, 0.0, 0, 0, "no armature: the sculpt is the corrective")
    key = obj.data.shape_keys
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    write_float(key.key_blocks[example_name].data, "co", basis + result.corrective)
    obj.data.update()
    st.revision += 1
    return result


def modelled_exactly(obj) -> bool:
    """True when ShapeSpace's skinning model reproduces the modifier stack exactly (plain Armature
    modifiers with vertex groups, no B-Bones, no other deforming modifiers)."""
    others = [m for m in obj.modifiers if m.show_viewport and m.type != "ARMATURE"]
    if others:
        return False
    problems = skin.check_skinning(obj)
    return not any(i.severity == "error" or i.code == "bbones" for i in problems)


TEMP_KEY = "ShapeSpace_invert"


def _invert_through_blender(obj, rest, sculpt):
    """Newton inversion with Blender's own evaluation as the deformer (B-Bones, other modifiers).

    Each evaluation writes the candidate pre-modifier positions into a temporary shape key and reads
    Blender's evaluated mesh; Jacobians come from central differences of that evaluation.
    """
    key = obj.data.shape_keys
    blocks = key.key_blocks
    examples = [n for n in _example_keys(obj) if n in blocks]
    saved = {n: blocks[n].value for n in examples}
    for n in examples:
        blocks[n].value = 0.0
    tmp = obj.shape_key_add(name=TEMP_KEY, from_mix=False)
    tmp.slider_min, tmp.slider_max = -10.0, 10.0
    tmp.value = 1.0
    name = tmp.name
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    depsgraph = bpy.context.evaluated_depsgraph_get()

    def blender_deform(x):
        write_float(obj.data.shape_keys.key_blocks[name].data, "co", basis + (x - rest))
        obj.data.update()
        return meshes.evaluated_positions(obj, depsgraph).astype(np.float64)

    try:
        # float32 evaluation: ask for what single precision can give
        size = float(np.linalg.norm(np.ptp(rest, axis=0))) or 1.0
        return invert_deformation(blender_deform, rest, sculpt, tol=2e-7 * size)
    finally:
        obj.shape_key_remove(obj.data.shape_keys.key_blocks[name])
        for n, v in saved.items():
            obj.data.shape_keys.key_blocks[n].value = v
        obj.data.update()


def trained_deformer(obj):
    """Train the object's pose-space deformer from its examples (muted examples left out)."""
    st = settings(obj)
    key = obj.data.shape_keys
    active = [ex for ex in st.examples if not ex.mute]
    if not active:
        raise ShapeSpaceError("no (unmuted) examples to interpolate", "no_examples")
    missing = [ex.name for ex in active if ex.name not in key.key_blocks]
    if missing:
        raise ShapeSpaceError(f"the corrective keys {', '.join(missing)} were deleted", "missing_key")
    n_features = sum(r.dims for r in readers(obj))
    poses = []
    for ex in active:
        pose = json.loads(ex.pseudo_pose or ex.pose)
        if len(pose) != n_features:
            raise ShapeSpaceError(f"example {ex.name!r} was recorded with a different pose space; record it "
                                  "again", "stale_example")
        poses.append(pose)
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    D = np.stack([read_float(key.key_blocks[ex.name].data, "co", 3).astype(np.float64) - basis for ex in active])
    method = st.method.lower()
    kwargs = {}
    if method == "wpsd":
        kwargs = _skin_groups(obj)
    return train_psd(np.array(poses), D, method, **kwargs), [ex.name for ex in active]


def _skin_groups(obj):
    rs = readers(obj)
    from ..core.posespace.readers import feature_groups
    groups = feature_groups(rs)
    sources = list(groups)
    rig = skin.read_skinning(obj)
    d = rig.deformers[0]
    lookup = {name: i for i, name in enumerate(sources)}
    remap = np.array([lookup.get(b, -1) for b in d.bone_names] + [-1])
    gi = remap[d.weights.bone_index]
    gw = np.where(gi >= 0, d.weights.weight, 0.0)
    return {"vertex_groups": gi, "vertex_weights": gw, "group_columns": [groups[s] for s in sources]}


def flag_examples(obj) -> list:
    """Recompute duplicate/conflict/outlier flags on the examples; returns the issues."""
    st = settings(obj)
    key = obj.data.shape_keys
    exs = list(st.examples)
    if not exs or key is None:
        return []
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    poses = [json.loads(ex.pseudo_pose or ex.pose) for ex in exs]
    if len({len(p) for p in poses}) != 1:
        return []
    D = np.stack([read_float(key.key_blocks[ex.name].data, "co", 3).astype(np.float64) - basis
                  if ex.name in key.key_blocks else np.zeros_like(basis) for ex in exs])
    issues = example_issues(np.array(poses), D, [ex.name for ex in exs])
    for ex in exs:
        ex.flags = ", ".join(sorted({i.code.replace("_", " ") for i in issues if ex.name in i.items}))
    return issues


def preview(obj, deformer=None, names=None, driver=None) -> np.ndarray:
    """Set the correctives (and driven targets) for the current pose.

    Returns the applied weights (PSD/SbE) or displacement (weighted PSD).
    """
    if deformer is None:
        deformer, names = trained_deformer(obj)
    pose = read_pose(obj)
    driver = driver if driver is not None else target_driver(obj)
    if driver is not None:
        write_targets(obj, list(driver(pose).values()))
    if deformer.method == "wpsd":
        disp = deformer.evaluate_fast(pose)
        write_wpsd_preview(obj, disp, names)
        return disp
    w = deformer.weights(pose)
    shapekeys.write_slider_values(obj, names, w)
    return w


WPSD_KEY = "ShapeSpace_WPSD"


def write_wpsd_preview(obj, disp, names) -> None:
    """Weighted PSD is per vertex: its result lives in one key; the example keys stay at 0."""
    key = obj.data.shape_keys
    if WPSD_KEY not in key.key_blocks:
        obj.shape_key_add(name=WPSD_KEY, from_mix=False)
    key = obj.data.shape_keys
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    write_float(key.key_blocks[WPSD_KEY].data, "co", basis + disp)
    key.key_blocks[WPSD_KEY].value = 1.0
    shapekeys.write_slider_values(obj, names, np.zeros(len(names)))



def bake_weights(obj, scene, start: int, end: int) -> int:
    """Key every example key's weight on every frame of [start, end] (playback without the add-on)."""
    from . import actions
    deformer, names = trained_deformer(obj)
    if deformer.method == "wpsd":
        raise ShapeSpaceError("weighted PSD is per vertex and cannot be baked into example keys", "method")
    frames = np.arange(start, end + 1, dtype=np.float64)
    current = scene.frame_current
    weights = np.empty((frames.size, len(names)))
    driver = target_driver(obj)
    targets = np.empty((frames.size, len(settings(obj).targets)))
    try:
        for i, f in enumerate(frames):
            scene.frame_set(int(f))
            pose = read_pose(obj)
            weights[i] = deformer.weights(pose)
            if driver is not None:
                targets[i] = list(driver(pose).values())
    finally:
        scene.frame_set(current)
    for j, t in enumerate(settings(obj).targets):
        actions.write_curve(t.owner, t.data_path, frames, targets[:, j], index=max(t.index, 0))
    key = obj.data.shape_keys
    action = actions.active_action(key)
    if action is None:
        action = actions.new_action(key, f"{obj.name}_PSD")
    for j, name in enumerate(names):
        actions.write_curve(key, actions.shape_key_path(name), frames, weights[:, j])
    return len(names)


MESH_CACHE_NAME = "ShapeSpace Correctives"


def bake_point_cache(obj, scene, start: int, end: int, path: str):
    """Bake the corrected pre-armature mesh of every frame to PC2 and play it with a Mesh Cache modifier.

    Works for every method (weighted PSD included): the Mesh Cache modifier,
    placed before the Armature modifier, replaces the shape-key result with
    the corrected one, so playback needs neither ShapeSpace nor Python.
    """
    from ..core.pointcache import write_pc2
    deformer, names = trained_deformer(obj)
    frames = list(range(start, end + 1))
    current = scene.frame_current
    st = settings(obj)
    was_live = st.live_preview
    st.live_preview = False
    out = np.empty((len(frames), len(obj.data.vertices), 3))
    try:
        for i, f in enumerate(frames):
            scene.frame_set(f)
            pose = read_pose(obj)
            rest = pre_armature_positions(obj)
            out[i] = rest + deformer.evaluate(pose)
    finally:
        scene.frame_set(current)
        st.live_preview = was_live
    write_pc2(path, out, start_frame=float(start), sample_rate=1.0)
    mod = obj.modifiers.get(MESH_CACHE_NAME) or obj.modifiers.new(MESH_CACHE_NAME, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = path
    mod.deform_mode = "OVERWRITE"
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    mod.frame_start = float(start)
    mod.frame_scale = 1.0
    mod.interpolation = "NONE"
    index = list(obj.modifiers).index(mod)
    if index != 0:
        with bpy.context.temp_override(object=obj):
            bpy.ops.object.modifier_move_to_index(modifier=mod.name, index=0)
    # the correctives now come from the cache: keep the example keys (and the WPSD preview key) at 0
    key = obj.data.shape_keys
    zero = [n for n in list(names) + [WPSD_KEY] if n in key.key_blocks]
    shapekeys.write_slider_values(obj, zero, np.zeros(len(zero)))
    return mod.name


def move_example(obj, example_name: str, reset: bool = False) -> None:
    """Shape-by-Example pseudo-example: interpolate this sculpt at the current pose (or back where sculpted)."""
    st = settings(obj)
    ex = st.examples.get(example_name)
    if ex is None:
        raise ShapeSpaceError(f"there is no example {example_name!r}", "missing_example")
    ex.pseudo_pose = "" if reset else json.dumps([float(v) for v in read_pose(obj)])
    st.revision += 1


def mirror_example(obj, example_name: str, tolerance: float = 1e-4) -> str:
    """Add the left↔right mirror of an example: mirrored pose and corrective (mesh mirrored across local X)."""
    from scipy.spatial import cKDTree
    from ..core.posespace.readers import mirror_name, mirror_pose
    st = settings(obj)
    ex = st.examples.get(example_name)
    if ex is None:
        raise ShapeSpaceError(f"there is no example {example_name!r}", "missing_example")
    rs = readers(obj)
    for r in rs:   # mirrored bone readers must point at bones that exist
        if r.is_bone:
            arm = armature_of(obj)
            if arm is None or mirror_name(r.source) not in arm.pose.bones:
                raise ShapeSpaceError(f"bone {mirror_name(r.source)!r} (the mirror of {r.source!r}) does not exist",
                                      "no_mirror")
    pose = mirror_pose(rs, json.loads(ex.pose))
    key = obj.data.shape_keys
    basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
    size = float(np.linalg.norm(np.ptp(basis, axis=0))) or 1.0
    dist, partner = cKDTree(basis).query(basis * np.array([-1.0, 1.0, 1.0]))
    unmatched = int(np.sum(dist > tolerance * size))
    if unmatched:
        raise ShapeSpaceError(f"{unmatched} vertices have no mirror partner across the mesh's local X axis "
                              f"(within {tolerance:g} of its size): the mesh is not symmetric", "not_symmetric")
    delta = read_float(key.key_blocks[ex.name].data, "co", 3).astype(np.float64) - basis
    mirrored = (delta * np.array([-1.0, 1.0, 1.0]))[partner]
    name = mirror_name(ex.name)
    if name == ex.name or name in key.key_blocks:
        name = ex.name + "_mirror"
    kb = obj.shape_key_add(name=name, from_mix=False)
    kb.slider_min, kb.slider_max = -10.0, 10.0
    kb.value = 0.0
    write_float(kb.data, "co", basis + mirrored)
    new = st.examples.add()
    new.name = kb.name
    new.pose = json.dumps([float(v) for v in pose])
    st.active_example = len(st.examples) - 1
    st.revision += 1
    return kb.name


# ----------------------------------------------------------------------------- driven targets (7.3.3)
def _target_ref(t):
    if t.owner is None:
        raise ShapeSpaceError(f"driven target {t.data_path!r} has no owner", "missing_target")
    try:
        value = t.owner.path_resolve(t.data_path)
    except ValueError:
        raise ShapeSpaceError(f"{t.owner.name!r} has no property {t.data_path!r}", "missing_target") from None
    return value


def read_targets(obj) -> list:
    """Current values of the driven targets (one float each)."""
    out = []
    for t in settings(obj).targets:
        value = _target_ref(t)
        out.append(float(value[t.index] if t.index >= 0 else value))
    return out


def write_targets(obj, values) -> None:
    for t, v in zip(settings(obj).targets, values):
        if t.index >= 0:
            arr = _target_ref(t)
            arr[t.index] = float(v)
        else:
            path, _, prop = t.data_path.rpartition(".")
            holder = t.owner.path_resolve(path) if path else t.owner
            if prop.startswith("["):   # custom property: owner["name"]
                holder[prop[2:-2]] = float(v)
            else:
                setattr(holder, prop, float(v))


def record_targets(obj, example_name: str) -> list:
    """Store the driven targets' current values as the example's (after the rigger set them at its pose)."""
    st = settings(obj)
    ex = st.examples.get(example_name)
    if ex is None:
        raise ShapeSpaceError(f"there is no example {example_name!r}", "missing_example")
    values = read_targets(obj)
    ex.target_values = json.dumps(values)
    st.revision += 1
    return values


def target_driver(obj):
    """The pose-space interpolant of the driven targets, or None when there are none."""
    from ..core.posespace.psd import train_driver
    st = settings(obj)
    if not len(st.targets):
        return None
    active = [ex for ex in st.examples if not ex.mute]
    rows = [json.loads(ex.target_values or "[]") for ex in active]
    if not active or any(len(r) != len(st.targets) for r in rows):
        raise ShapeSpaceError("some examples have no recorded values for the driven targets: pose each and use "
                              "Record Targets", "stale_targets")
    poses = np.array([json.loads(ex.pseudo_pose or ex.pose) for ex in active])
    names = [f"{t.data_path}[{t.index}]" for t in st.targets]
    d = rbf.pairwise_distances(poses, poses) if len(poses) > 1 else np.ones((1, 1))
    eps = 1.0 / float(np.median(d[d > 0])) if np.any(d > 0) else 1.0
    return train_driver(poses, np.array(rows), names, kernel="gaussian", epsilon=eps, degree=-1 if len(poses) < 3
                        else None)
