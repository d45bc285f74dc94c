"""Final-shape examples: keep each example's sculpt, find stale correctives, re-invert them exactly.

When an example is applied, ShapeSpace stores (:data:`.stored.FINAL_SHAPE_SCHEMA`):

- the sculpted posed positions of the vertices its corrective moves (float32, object space, sparse);
- the rig pose it was sculpted at (every bone's ``matrix_basis``);
- a fingerprint of the inputs its rest-space corrective was inverted from: the skin weights of those
  vertices, the rest matrices of the bones that move them (and their parents), the modifiers up to the last
  Armature modifier, the basis positions of those vertices and the mesh's placement relative to the armature.

:func:`stale_examples` compares fingerprints with the rig as it is now; :func:`reinvert_example` poses the rig
as stored, inverts the stored sculpt through today's deformation (the skinning model when it is exact, else
Blender's own evaluation) and writes the corrective key.  Examples made by ShapeSpace 0.1.0 have no final
shape: :func:`capture_final_shape` stores today's corrective's posed result as one.
"""
from __future__ import annotations

import hashlib
import time
from contextlib import contextmanager

import bpy
import numpy as np

from ...core.cache import BoundedCache
from ...core.errors import ErrorCode
from ...core.posespace.finalshape import (
    array_digest,
    compare_fingerprints,
    decode_array,
    encode_array,
    lbs_affine_maps,
    touched_vertices,
)
from ...core.posespace.inversion import InversionResult, invert_affine, invert_deformation
from ...core.result import ShapeSpaceError, Status
from ...core.skinning import ArmatureDeform, SkinningRig, SkinWeights, deform
from .. import meshes, skin
from ..arrays import matrix, read_float, read_matrices, write_float
from .correctives import (
    basis_positions,
    check_not_editing,
    check_topology,
    example_correctives,
    example_keys,
    pre_armature_positions,
)
from .inversion import invert_through_blender, modelled_exactly
from .pose import read_pose, readers, settings
from .stored import check_examples, example_pose, final_shape, find_example, set_final_shape

__all__ = ["rig_pose", "at_pose", "fingerprint", "store_final_shape", "capture_final_shape", "stale_examples",
           "stale_examples_cached", "reinvert_example", "reinvert_all", "final_shape_positions"]

#: How close the current pose must be to an example's pose to capture its final shape (feature units).
POSE_TOL = 1e-4


def _size(points) -> float:
    return float(np.linalg.norm(np.ptp(points, axis=0))) if len(points) else 1.0


def _armatures(obj) -> list:
    """The armature objects of ``obj``'s enabled Armature modifiers, each once, in stack order."""
    out = []
    for m in skin.armature_modifiers(obj):
        if m.object not in out:
            out.append(m.object)
    return out


def rig_pose(obj) -> dict:
    """Every bone's ``matrix_basis`` (16 floats, row-major) per armature: ``{armature: {bone: [...]}}``."""
    out = {}
    for arm in _armatures(obj):
        mats = read_matrices(arm.pose.bones, "matrix_basis")
        out[arm.name] = {pb.name: [float(v) for v in mats[i].ravel()] for i, pb in enumerate(arm.pose.bones)}
    return out


def _set_basis(arm, values: dict) -> None:
    bones = arm.pose.bones
    names = [pb.name for pb in bones]
    mats = read_matrices(bones, "matrix_basis")
    for i, n in enumerate(names):
        if n in values:
            mats[i] = np.asarray(values[n], dtype=np.float64).reshape(4, 4)
    # foreach_set takes column-major 4 × 4 matrices (as Blender stores them)
    bones.foreach_set("matrix_basis", np.ascontiguousarray(mats.transpose(0, 2, 1), np.float32).ravel())
    arm.update_tag()


_CHANNELS = (("location", 3), ("rotation_quaternion", 4), ("rotation_euler", 3), ("rotation_axis_angle", 4),
             ("scale", 3))


def _save_channels(arm) -> dict:
    bones = arm.pose.bones
    return {attr: read_float(bones, attr, width) for attr, width in _CHANNELS}


def _restore_channels(arm, saved: dict) -> None:
    for attr, values in saved.items():
        write_float(arm.pose.bones, attr, values)
    arm.update_tag()


@contextmanager
def at_pose(obj, pose: dict):
    """Pose ``obj``'s armatures as ``pose`` (:func:`rig_pose`) while the block runs, then put every channel
    back exactly.  Bones the pose does not name keep their channels; armatures it does not name are left alone.
    """
    saved = []
    try:
        for arm in _armatures(obj):
            if arm.name in pose:
                saved.append((arm, _save_channels(arm)))
                _set_basis(arm, pose[arm.name])
        bpy.context.view_layer.update()
        yield
    finally:
        for arm, channels in saved:
            _restore_channels(arm, channels)
        bpy.context.view_layer.update()


def _subset_groups(obj, idx: np.ndarray):
    """Vertex-group memberships of the vertices ``idx`` only: (t, k) group index (−1 padding), weights, names.

    Blender has no bulk accessor for deform weights: a few vertices are looked up one by one, many are read
    in one pass over the mesh (indexing ``mesh.vertices`` is far slower per vertex than iterating it).
    """
    verts = obj.data.vertices
    names = [g.name for g in obj.vertex_groups]
    idx = np.asarray(idx, dtype=np.int64)
    if len(idx) > len(verts) // 16:
        flat = [(i, g.group, g.weight) for i, v in enumerate(verts) for g in v.groups]
        arr = np.array(flat, dtype=np.float64).reshape(-1, 3)
        rows = arr[:, 0].astype(np.int64)
        cols = np.arange(len(rows)) - np.searchsorted(rows, rows)
        k = int(cols.max()) + 1 if len(cols) else 1
        gi = np.full((len(verts), k), -1, dtype=np.int64)
        gw = np.zeros((len(verts), k), dtype=np.float64)
        gi[rows, cols] = arr[:, 1].astype(np.int64)
        gw[rows, cols] = arr[:, 2]
        return gi[idx], gw[idx], names
    rows = [[(g.group, g.weight) for g in verts[int(i)].groups] for i in idx]
    k = max((len(r) for r in rows), default=0) or 1
    gi = np.full((len(idx), k), -1, dtype=np.int64)
    gw = np.zeros((len(idx), k), dtype=np.float64)
    for r, row in enumerate(rows):
        for c, (g, w) in enumerate(row):
            gi[r, c] = g
            gw[r, c] = w
    return gi, gw, names


def _subset_rig(obj, idx: np.ndarray, groups) -> SkinningRig:
    """:func:`bridge.skin.read_skinning` restricted to the vertices ``idx`` (same rules, same order)."""
    gi, gw, gnames = groups
    deformers = []
    for m in skin.armature_modifiers(obj):
        bones = m.object.data.bones
        lookup = {b.name: i for i, b in enumerate(bones) if b.use_deform}
        group_to_bone = np.array([lookup.get(n, -1) for n in gnames] + [-1], dtype=np.int64)
        mask = None
        if m.vertex_group and m.vertex_group in gnames:
            g = gnames.index(m.vertex_group)
            mask = np.where(gi == g, gw, 0.0).sum(axis=1)
            if m.invert_vertex_group:
                mask = 1.0 - mask
        deformers.append(ArmatureDeform(
            weights=SkinWeights(group_to_bone[gi], gw), bone_names=[b.name for b in bones],
            rest=read_matrices(bones, "matrix_local"), armature_world=meshes.world_matrix(m.object),
            preserve_volume=bool(m.use_deform_preserve_volume), vertex_mask=mask, name=m.name))
    return SkinningRig(mesh_world=meshes.world_matrix(obj), deformers=deformers)


#: What an Armature modifier's result depends on (other modifiers: every writable setting).
_ARMATURE_SETTINGS = ("object", "vertex_group", "invert_vertex_group", "use_deform_preserve_volume",
                      "use_vertex_groups", "use_bone_envelopes", "use_multi_modifier")
#: Settings that never change a modifier's result (UI state), across Blender versions.
_UI_SETTINGS = {"rna_type", "name", "is_active", "show_expanded", "is_override_data", "persistent_uid",
                "show_in_editmode", "show_on_cage", "show_render", "use_apply_on_spline", "use_pin_to_last",
                "show_group_selector", "show_manage_panel"}


def _settings_digest(mod) -> str:
    """Digest of what a modifier's result depends on: an Armature modifier's deform settings, else every
    writable plain setting (pointers by the name of what they point at; read-only values such as timings and
    UI state are left out, so the digest is stable across evaluations and Blender versions)."""
    parts = [mod.type]
    props = mod.bl_rna.properties
    names = _ARMATURE_SETTINGS if mod.type == "ARMATURE" else [
        p.identifier for p in props if p.identifier not in _UI_SETTINGS and not p.is_readonly
        and not p.identifier.startswith("open_") and p.type != "COLLECTION"]
    for ident in names:
        prop = props.get(ident)
        if prop is None:
            continue
        value = getattr(mod, ident, None)
        if prop.type == "POINTER":
            value = getattr(value, "name", None)
        elif hasattr(value, "__len__") and not isinstance(value, str):
            value = tuple(round(float(v), 6) if isinstance(v, float) else v for v in value)
        elif isinstance(value, float):
            value = round(value, 6)
        parts.append(f"{ident}={value!r}")
    return hashlib.sha1("\n".join(parts).encode()).hexdigest()


def _stack_digests(obj) -> dict:
    """``{modifier: digest}`` for the enabled modifiers up to and including the last Armature modifier."""
    mods = [m for m in obj.modifiers if m.show_viewport]
    last = max((i for i, m in enumerate(mods) if m.type == "ARMATURE"), default=-1)
    return {m.name: _settings_digest(m) for m in mods[: last + 1]}


def _fingerprint(obj, idx: np.ndarray, groups, basis: np.ndarray) -> dict:
    rig = _subset_rig(obj, idx, groups)
    names, columns, masks = [], [], []
    bones_rest = {}
    for m, d in zip(skin.armature_modifiers(obj), rig.deformers):
        eff = d.weights.effective()
        if d.vertex_mask is not None:
            masks.append(d.vertex_mask)
        bones = m.object.data.bones
        used = np.unique(d.weights.bone_index[(d.weights.bone_index >= 0) & (eff > 0)])
        dense = d.weights.dense(len(bones))
        for b in sorted(used, key=lambda i: d.bone_names[i]):
            names.append(d.bone_names[b])
            columns.append(dense[:, b])
            bone = bones[d.bone_names[b]]
            while bone is not None:            # a parent's rest pose moves its children's pose matrices
                bones_rest[bone.name] = [float(v) for v in matrix(bone.matrix_local).ravel()]
                bone = bone.parent
    weights = np.stack(columns, axis=1) if columns else np.zeros((len(idx), 0))
    digest = array_digest(np.frombuffer("\n".join(names).encode(), dtype=np.uint8), weights, *masks)
    arms = _armatures(obj)
    relative = (np.linalg.inv(meshes.world_matrix(arms[0])) @ meshes.world_matrix(obj)) if arms else np.eye(4)
    return {"weights": digest, "bones": bones_rest, "modifiers": _stack_digests(obj),
            "basis": array_digest(basis[idx].astype(np.float32)), "relative": [float(v) for v in relative.ravel()]}


def fingerprint(obj, indices) -> dict:
    """The inputs a corrective moving vertices ``indices`` is inverted from (see the module docstring)."""
    idx = np.asarray(indices, dtype=np.int64)
    return _fingerprint(obj, idx, _subset_groups(obj, idx), basis_positions(obj))


def _decoded(obj, ex, data: dict):
    """(indices (t,), positions (t, 3) float64) of a stored final shape, checked against the mesh."""
    what = f"the final shape of example {ex.name!r}"
    idx = decode_array(data["indices"], "<i4", 1, what).astype(np.int64)
    pos = decode_array(data["positions"], "<f4", 3, what).astype(np.float64)
    p = len(obj.data.vertices)
    if data["vertex_count"] != p:
        raise ShapeSpaceError(f"{what} was stored for {data['vertex_count']} vertices, the mesh has {p}: the "
                              "topology changed", ErrorCode.VERTEX_COUNT_MISMATCH)
    if len(idx) != len(pos) or (len(idx) and (idx.min() < 0 or idx.max() >= p)) or not np.isfinite(pos).all():
        raise ShapeSpaceError(f"damaged ShapeSpace data in {what}: indices and positions do not match the mesh",
                              ErrorCode.CORRUPT_METADATA)
    return idx, pos


def final_shape_positions(obj, example_name: str):
    """An example's stored final shape: (vertex indices (t,), object-space positions (t, 3)), or None."""
    ex = find_example(obj, example_name)
    data = final_shape(ex)
    return None if data is None else _decoded(obj, ex, data)


def store_final_shape(obj, ex, indices, positions, pose: dict = None, groups=None) -> None:
    """Store an example's final shape: posed ``positions`` (t, 3) of vertices ``indices`` (object space), the
    rig ``pose`` (default: the current one) and the fingerprint of today's inputs (``groups``: the vertices'
    vertex groups when already read, :func:`_subset_groups`)."""
    idx = np.asarray(indices, dtype=np.int64)
    groups = _subset_groups(obj, idx) if groups is None else groups
    set_final_shape(ex, {
        "vertex_count": len(obj.data.vertices), "indices": encode_array(idx, "<i4"),
        "positions": encode_array(np.asarray(positions, dtype=np.float64).reshape(-1, 3), "<f4"),
        "pose": rig_pose(obj) if pose is None else pose,
        "fingerprint": _fingerprint(obj, idx, groups, basis_positions(obj))})


def touched(obj, corrective) -> np.ndarray:
    """The vertices a rest-space corrective (p, 3) moves (relative to the basis's size)."""
    return touched_vertices(corrective, _size(basis_positions(obj)))


@contextmanager
def _only_key(obj, name):
    """Example keys at 0 except ``name`` at 1 (None: all at 0) while the block runs; values restored after."""
    blocks = obj.data.shape_keys.key_blocks
    saved = {n: blocks[n].value for n in example_keys(obj) if n in blocks}
    try:
        for n in saved:
            blocks[n].value = 1.0 if n == name else 0.0
        obj.data.update()
        yield
    finally:
        for n, v in saved.items():
            blocks[n].value = v
        obj.data.update()


def _evaluated(obj) -> np.ndarray:
    bpy.context.view_layer.update()
    return meshes.evaluated_positions(obj, bpy.context.evaluated_depsgraph_get()).astype(np.float64)


def capture_final_shape(obj, example_name: str, replace: bool = False) -> int:
    """Store today's corrective's posed result as the example's final shape (examples from ShapeSpace 0.1.0).

    The rig must be at the example's pose (its pose-space features within :data:`POSE_TOL`): the posed
    result is Blender's evaluation with only this example's corrective on.  Refused when the example has a
    final shape already, unless ``replace``.  Returns how many vertices the final shape holds.
    """
    check_not_editing(obj)
    check_topology(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    if final_shape(ex) is not None and not replace:
        raise ShapeSpaceError(f"example {ex.name!r} has a final shape already: re-invert it, or capture with "
                              "Replace to overwrite its sculpt with today's corrective", ErrorCode.OVERWRITE)
    want = np.asarray(example_pose(ex))
    if want.size and readers(obj):
        now = np.asarray(read_pose(obj))
        gap = float(np.abs(now - want).max()) if now.shape == want.shape else float("inf")
        if gap > POSE_TOL:
            raise ShapeSpaceError(f"pose the rig at example {ex.name!r} first (its pose-space features differ by "
                                  f"{gap:.3g}): the final shape is today's corrective at its pose",
                                  ErrorCode.STALE_EXAMPLE)
    idx = touched(obj, example_correctives(obj, [ex])[0])
    with _only_key(obj, ex.name):
        posed = _evaluated(obj)
    store_final_shape(obj, ex, idx, posed[idx])
    settings(obj).revision += 1
    return int(len(idx))


def _bones_now(obj) -> list:
    return [b.name for arm in _armatures(obj) for b in arm.data.bones]


def stale_examples(obj) -> list:
    """Examples whose corrective no longer matches its final shape: ``[(name, code, message)]``.

    ``code`` is ``stale_example`` (an input changed: the message says which), ``missing_bone`` (a bone that
    moves its sculpted vertices was deleted), ``no_final_shape`` (made by ShapeSpace 0.1.0 or never applied:
    capture it) or ``corrupt_metadata``.  Weight changes on vertices no example moves flag nothing.
    """
    found, stored = [], []
    for ex in settings(obj).examples:
        if ex.post_deform:          # rides on the deformed surface: nothing to re-invert after rig changes
            continue
        try:
            data = final_shape(ex)
            if data is None:
                found.append((ex.name, "no_final_shape", f"{ex.name}: no final shape (made before ShapeSpace "
                              "kept one, or never applied): capture it from its corrective"))
            else:
                stored.append((ex, data, _decoded(obj, ex, data)[0]))
        except ShapeSpaceError as exc:
            found.append((ex.name, str(exc.code), str(exc)))
    if not stored:
        return found
    union = np.unique(np.concatenate([idx for _, _, idx in stored]))
    groups = _subset_groups(obj, union)
    basis = basis_positions(obj)
    bones_now = _bones_now(obj)
    for ex, data, idx in stored:
        rows = np.searchsorted(union, idx)
        sub = (groups[0][rows], groups[1][rows], groups[2])
        reasons = compare_fingerprints(data["fingerprint"], _fingerprint(obj, idx, sub, basis), bones_now)
        if reasons:
            code = "missing_bone" if "deleted" in reasons[0] else "stale_example"
            found.append((ex.name, code, f"{ex.name}: {'; '.join(reasons)}"))
    return found


#: The panel's stale-example checks by (mesh, revision, example count): (time, findings).
STALE_CHECKS = BoundedCache("stale-example checks of the pose-space panel", capacity=64)


def stale_examples_cached(obj, max_age: float = 1.0) -> list:
    """:func:`stale_examples` at most once per ``max_age`` seconds per mesh (for a panel's draw; never raises)."""
    key = (obj.name_full, settings(obj).revision, len(settings(obj).examples))
    now = time.monotonic()
    hit = STALE_CHECKS.get(key, valid=lambda e: now - e[0] < max_age)
    if hit is not None:
        return hit[1]
    try:
        value = stale_examples(obj)
    except Exception as exc:      # a draw must not fail: say what could not be read
        value = [("", "error", f"cannot check the examples: {exc}")]
    STALE_CHECKS.put(key, (now, value))
    return value


def _check_bones(obj, ex, data) -> None:
    """Refuse re-inverting an example whose sculpted vertices were moved by a bone that no longer exists."""
    now = set(_bones_now(obj))
    gone = [b for b in data["fingerprint"].get("bones", {}) if b not in now]
    if gone:
        raise ShapeSpaceError(f"cannot re-invert {ex.name!r}: bone {gone[0]!r} was deleted after it was sculpted "
                              "(it moved the sculpted vertices); restore the bone, or capture a new final shape",
                              ErrorCode.MISSING_BONE)


def _reinverted(obj, ex, data, progress=None) -> tuple:
    """(full corrective (p, 3), InversionResult, indices, positions, groups) for one example, nothing written."""
    _check_bones(obj, ex, data)
    idx, pos = _decoded(obj, ex, data)
    p = len(obj.data.vertices)
    full = np.zeros((p, 3))
    groups = _subset_groups(obj, idx)
    if not len(idx):
        return full, InversionResult(full, residual=0.0, iterations=0, status=Status.OK,
                                     message="nothing sculpted"), idx, pos, groups
    rest = pre_armature_positions(obj)
    size = _size(rest)
    with at_pose(obj, data["pose"]):
        if skin.armature_modifiers(obj) and modelled_exactly(obj):
            rig = _subset_rig(obj, idx, groups)
            poses = skin.modifier_poses(obj)
            maps = lbs_affine_maps(rig, poses)
            if maps is not None:      # linear blend skinning is affine per vertex: one exact solve
                result = invert_affine(maps, rest[idx], pos, tol=1e-9 * size)
                result = _checked(result, rig, poses, rest[idx], pos, 1e-9 * size)
            else:
                result = invert_deformation(lambda x: deform(x, rig, poses), rest[idx], pos, tol=1e-9 * size)
            full[idx] = result.corrective
        elif [m for m in obj.modifiers if m.show_viewport]:
            with _only_key(obj, None):
                target = _evaluated(obj)
            target[idx] = pos
            result = invert_through_blender(obj, rest, target, progress)
            full[idx] = result.corrective[idx]
        else:
            full[idx] = pos - rest[idx]
            result = InversionResult(full, residual=0.0, iterations=0, status=Status.OK,
                                     message="no armature: the sculpt is the corrective")
    if not np.isfinite(full).all():
        raise ShapeSpaceError(f"re-inverting {ex.name!r} gave non-finite positions", ErrorCode.NON_FINITE)
    return full, result, idx, pos, groups


def _checked(result, rig, poses, rest, sculpt, tol, sample: int = 4096):
    """``result`` with its residual measured by the skinning model itself on up to ``sample`` vertices (spread
    evenly): the affine maps are derived from the same formula, this checks they reproduce it."""
    rows = np.unique(np.linspace(0, len(rest) - 1, min(len(rest), sample)).astype(np.int64))
    sub = SkinningRig(mesh_world=rig.mesh_world, deformers=[ArmatureDeform(
        weights=SkinWeights(d.weights.bone_index[rows], d.weights.weight[rows]), bone_names=d.bone_names,
        rest=d.rest, armature_world=d.armature_world, preserve_volume=d.preserve_volume,
        vertex_mask=None if d.vertex_mask is None else d.vertex_mask[rows], name=d.name) for d in rig.deformers])
    err = float(np.abs(deform(rest[rows] + result.corrective[rows], sub, poses) - sculpt[rows]).max())
    result.residual = max(result.residual, err)
    if err > tol:
        result.status, result.message = Status.NOT_CONVERGED, "the skinning model disagrees with its affine maps"
    return result


def _write(obj, ex, full, idx, pos, pose, groups) -> None:
    key = obj.data.shape_keys
    write_float(key.key_blocks[ex.name].data, "co", basis_positions(obj) + full)
    store_final_shape(obj, ex, idx, pos, pose, groups)


def _need_final_shape(ex):
    data = final_shape(ex)
    if data is None:
        raise ShapeSpaceError(f"example {ex.name!r} has no final shape (made before ShapeSpace kept one, or never "
                              "applied): capture it from its current corrective first", ErrorCode.NO_SCULPT)
    return data


def reinvert_example(obj, example_name: str, progress=None) -> InversionResult:
    """Recompute an example's corrective exactly from its stored final shape through today's rig.

    Poses the rig as stored (and puts it back), inverts, writes the corrective key and a fresh fingerprint.
    Refused (nothing written) when the example has no final shape or a bone that moved its sculpted vertices
    was deleted (naming the bone).
    """
    check_not_editing(obj)
    check_topology(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    data = _need_final_shape(ex)
    full, result, idx, pos, groups = _reinverted(obj, ex, data, progress)
    _write(obj, ex, full, idx, pos, data["pose"], groups)
    obj.data.update()
    settings(obj).revision += 1
    return result


def reinvert_all(obj, progress=None) -> list:
    """Re-invert every example that has a final shape; all are computed before any is written.

    Returns ``[(name, InversionResult)]``; examples without a final shape are left as they are (the panel
    offers to capture them).  Refused, with nothing written, when any of them cannot be re-inverted.
    """
    check_not_editing(obj)
    check_topology(obj)
    check_examples(obj)
    todo = [(ex, final_shape(ex)) for ex in settings(obj).examples]
    todo = [(ex, data) for ex, data in todo if data is not None]
    done = []
    for k, (ex, data) in enumerate(todo):
        done.append((ex, data, _reinverted(obj, ex, data)))
        if progress is not None:
            progress((k + 1) / max(len(todo), 1))
    for ex, data, (full, _, idx, pos, groups) in done:
        _write(obj, ex, full, idx, pos, data["pose"], groups)
    obj.data.update()
    settings(obj).revision += 1
    return [(ex.name, result) for ex, _, (_, result, _, _, _) in done]
