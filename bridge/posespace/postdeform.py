"""Post-deformation correctives: offsets in a per-vertex frame of the deformed surface, applied after skinning.

A post-deformation example stores its corrective as offsets ``o_v`` in a frame ``F_v = [T_v B_v N_v]`` of the
*deformed* surface (N the vertex normal, T the direction to a fixed neighbour vertex made perpendicular to N,
B = N × T), and a generated Geometry Nodes modifier at the end of the stack adds

    x_v ← x_v + Σ_k w_k F_v o_vk

natively (no Python at playback).  ``o_vk`` lives in the point attribute ``ss_pd_<example>``; ``w_k`` is a
modifier input driven (a plain Average driver, no script) by the example's shape-key value, which Live Preview,
Update Correctives and Bake set as for any example.  The example's key keeps the rest-space inversion of the
same sculpt (for training and flags) but is muted, so it does not deform.

At the example pose the offsets are computed from the frames the node group itself produced (it stores T and N
as attributes, read back from Blender's evaluation), so ``P + F o = sculpt`` to float32 precision.  Because the
offsets ride on the deformed surface, re-weighting the skin changes where they are applied, not what they are:
no re-inversion.  Refused when a modifier changes the topology after the armature (the offsets are per vertex).
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.finalshape import TOUCH_REL
from ...core.result import ShapeSpaceError
from .. import compat, meshes, skin
from ..arrays import read_float
from .correctives import check_finite_positions, check_not_editing, check_topology, example_keys
from .inversion import sculpt_positions_of
from .pose import settings
from .sculpt import apply_example
from .stored import MODIFIER, check_examples, find_example, is_post_deform_modifier

__all__ = ["MODIFIER", "GROUP_PREFIX", "REF_ATTRIBUTE", "attribute_name", "post_deform_examples",
           "check_post_deform_stack", "apply_post_deform", "sync_post_deform", "is_post_deform_modifier"]

#: Prefix of the generated node group (one per mesh).
GROUP_PREFIX = "ShapeSpace Post-Deform"
#: Point attribute: the neighbour vertex whose direction gives each vertex's tangent.
REF_ATTRIBUTE = "ss_pd_ref"
#: Point attributes the node group writes: the frame's tangent and normal (read back to compute offsets).
FRAME_T, FRAME_N = "ss_pd_frame_t", "ss_pd_frame_n"


def attribute_name(example_name: str) -> str:
    """The point attribute holding an example's frame offsets."""
    return f"ss_pd_{example_name}"


def post_deform_examples(obj) -> list:
    """The post-deformation examples of ``obj`` (in the examples' order)."""
    return [ex for ex in settings(obj).examples if ex.post_deform]


def _counts(mesh) -> tuple:
    return len(mesh.vertices), len(mesh.edges), len(mesh.polygons)


def check_post_deform_stack(obj) -> None:
    """Refuse meshes whose modifiers change the topology (offsets are per vertex), naming the first such
    modifier after the armature; also refuse meshes without an Armature modifier."""
    if not skin.armature_modifiers(obj):
        raise ShapeSpaceError(f"{obj.name!r} has no Armature modifier: post-deformation correctives are applied "
                              "after the armature", ErrorCode.NO_ARMATURE)
    mods = list(obj.modifiers)
    ours = [i for i, m in enumerate(mods) if is_post_deform_modifier(m)]
    if ours and ours[0] < max(i for i, m in enumerate(mods) if m.type == "ARMATURE"):
        raise ShapeSpaceError(f"the modifier {MODIFIER!r} of {obj.name!r} must come after the Armature modifier: "
                              "move it down the stack", ErrorCode.TOPOLOGY_MODIFIERS)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = ob_eval.to_mesh()
    try:
        same = _counts(mesh) == _counts(obj.data)
    finally:
        ob_eval.to_mesh_clear()
    if same:
        return
    last = max(i for i, m in enumerate(mods) if m.type == "ARMATURE")
    after = [m for m in mods[last + 1:] if m.show_viewport and not is_post_deform_modifier(m)]
    before = [m for m in mods[:last] if m.show_viewport and m.type != "ARMATURE"]
    culprit = (after or before or [None])[0]
    where = f"modifier {culprit.name!r} ({culprit.type.lower()})" if culprit is not None else "a modifier"
    raise ShapeSpaceError(f"{where} changes the topology of {obj.name!r} (vertex, edge or face count): "
                          "post-deformation offsets are stored per vertex; disable it or use a rest-space "
                          "corrective", ErrorCode.TOPOLOGY_MODIFIERS)


def _reference_vertices(obj) -> np.ndarray:
    """Each vertex's tangent neighbour: of the vertices sharing an edge with it, the one whose direction is
    most perpendicular to its rest normal (−1 … no edge: its own index, a zero tangent)."""
    me = obj.data
    p = len(me.vertices)
    edges = np.empty(len(me.edges) * 2, np.int32)
    me.edges.foreach_get("vertices", edges)
    edges = edges.reshape(-1, 2).astype(np.int64)
    co = meshes.vertex_positions(me).astype(np.float64)
    normals = read_float(me.vertex_normals, "vector", 3).astype(np.float64)
    a = np.concatenate([edges[:, 0], edges[:, 1]])
    b = np.concatenate([edges[:, 1], edges[:, 0]])
    e = co[b] - co[a]
    length = np.linalg.norm(e, axis=1)
    tangent = e - np.sum(e * normals[a], axis=1)[:, None] * normals[a]
    score = np.where(length > 0, np.linalg.norm(tangent, axis=1) / np.where(length > 0, length, 1.0), -1.0)
    order = np.lexsort((-score, a))
    ref = np.arange(p, dtype=np.int64)
    first = np.ones(len(order), bool)
    first[1:] = a[order][1:] != a[order][:-1]
    ref[a[order][first]] = b[order][first]
    return ref


def _set_attribute(mesh, name: str, kind: str, values) -> None:
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.data_type != kind or attr.domain != "POINT"):
        mesh.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = mesh.attributes.new(name, kind, "POINT")
    if kind == "INT":
        attr.data.foreach_set("value", np.ascontiguousarray(values, np.int32).ravel())
    else:
        attr.data.foreach_set("vector", np.ascontiguousarray(values, np.float32).ravel())


def _group_name(obj) -> str:
    return f"{GROUP_PREFIX} {obj.name}"


def _build_group(obj, names: list):
    """(Re)build the node group: frames from the deformed surface, Σ_k w_k F o_k added to the positions."""
    ng = bpy.data.node_groups.get(_group_name(obj))
    if ng is None:
        ng = bpy.data.node_groups.new(_group_name(obj), "GeometryNodeTree")
    compat.clear_node_group(ng)
    compat.new_interface_socket(ng, "Geometry", "OUTPUT", "NodeSocketGeometry")
    compat.new_interface_socket(ng, "Geometry", "INPUT", "NodeSocketGeometry")
    for n in names:
        compat.new_interface_socket(ng, n, "INPUT", "NodeSocketFloat")
    nodes, links = ng.nodes, ng.links
    gin = nodes.new("NodeGroupInput")
    gout = nodes.new("NodeGroupOutput")
    pos = nodes.new("GeometryNodeInputPosition")
    normal = nodes.new("GeometryNodeInputNormal")
    ref = compat.named_attribute_node(ng, "INT", REF_ATTRIBUTE)
    sample = compat.sample_index_node(ng, "FLOAT_VECTOR")
    links.new(gin.outputs[0], compat.socket(sample.inputs, "Geometry"))
    links.new(pos.outputs[0], compat.socket(sample.inputs, "Value"))
    links.new(compat.socket(ref.outputs, "Attribute"), compat.socket(sample.inputs, "Index"))

    def vmath(op, a, b=None):
        node = nodes.new("ShaderNodeVectorMath")
        node.operation = op
        links.new(a, node.inputs[0])
        if b is not None:
            links.new(b, node.inputs[1])
        return node

    def out(node, name="Vector"):
        return compat.socket(node.outputs, name)

    edge = vmath("SUBTRACT", compat.socket(sample.outputs, "Value"), pos.outputs[0])
    along = vmath("DOT_PRODUCT", out(edge), normal.outputs[0])
    proj = vmath("SCALE", normal.outputs[0])
    links.new(out(along, "Value"), compat.socket(proj.inputs, "Scale"))
    tan = vmath("NORMALIZE", out(vmath("SUBTRACT", out(edge), out(proj))))
    bitan = vmath("CROSS_PRODUCT", normal.outputs[0], out(tan))
    total = None
    for k, n in enumerate(names):
        attr = compat.named_attribute_node(ng, "FLOAT_VECTOR", attribute_name(n))
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(compat.socket(attr.outputs, "Attribute"), sep.inputs[0])
        parts = []
        for axis, basis in (("X", out(tan)), ("Y", out(bitan)), ("Z", normal.outputs[0])):
            s = vmath("SCALE", basis)
            links.new(compat.socket(sep.outputs, axis), compat.socket(s.inputs, "Scale"))
            parts.append(out(s))
        offset = vmath("ADD", out(vmath("ADD", parts[0], parts[1])), parts[2])
        weighted = vmath("SCALE", out(offset))
        links.new(gin.outputs[k + 1], compat.socket(weighted.inputs, "Scale"))
        total = out(weighted) if total is None else out(vmath("ADD", total, out(weighted)))
    store_t = compat.store_attribute_node(ng, "FLOAT_VECTOR", FRAME_T)
    store_n = compat.store_attribute_node(ng, "FLOAT_VECTOR", FRAME_N)
    links.new(gin.outputs[0], compat.socket(store_t.inputs, "Geometry"))
    links.new(out(tan), compat.socket(store_t.inputs, "Value"))
    links.new(compat.socket(store_t.outputs, "Geometry"), compat.socket(store_n.inputs, "Geometry"))
    links.new(normal.outputs[0], compat.socket(store_n.inputs, "Value"))
    geo = compat.socket(store_n.outputs, "Geometry")
    if total is not None:
        setp = nodes.new("GeometryNodeSetPosition")
        links.new(geo, compat.socket(setp.inputs, "Geometry"))
        links.new(total, compat.socket(setp.inputs, "Offset"))
        geo = compat.socket(setp.outputs, "Geometry")
    links.new(geo, gout.inputs[0])
    return ng


def _drive(obj, mod, ng, names: list) -> None:
    """Each example input of the modifier driven by the example key's value (Average driver: no script)."""
    key = obj.data.shape_keys
    for k, n in enumerate(names):
        ident = compat.interface_input_identifier(ng, k + 1)
        compat.set_modifier_input(mod, ident, 0.0)
        path = compat.modifier_input_path(mod, ident)
        fc = obj.driver_add(path)
        drv = fc.driver
        drv.type = "AVERAGE"
        var = drv.variables.new()
        var.name = "w"
        var.type = "SINGLE_PROP"
        var.targets[0].id_type = "KEY"
        var.targets[0].id = key
        var.targets[0].data_path = f'key_blocks["{n}"].value'


def sync_post_deform(obj) -> None:
    """Make the generated node group, modifier, drivers and reference attribute match the post-deformation
    examples (removing them when there are none)."""
    names = [ex.name for ex in post_deform_examples(obj)]
    mod = obj.modifiers.get(MODIFIER)
    ad = obj.animation_data
    if ad is not None:
        for fc in list(ad.drivers):
            if fc.data_path.startswith(f'modifiers["{MODIFIER}"]'):
                ad.drivers.remove(fc)
    if not names:
        if mod is not None:
            obj.modifiers.remove(mod)
        ng = bpy.data.node_groups.get(_group_name(obj))
        if ng is not None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
        return
    if REF_ATTRIBUTE not in obj.data.attributes:
        _set_attribute(obj.data, REF_ATTRIBUTE, "INT", _reference_vertices(obj))
    ng = _build_group(obj, names)
    if mod is None:                                         # made at the end of the stack, then left where it is
        mod = obj.modifiers.new(MODIFIER, "NODES")
    mod.node_group = ng
    _drive(obj, mod, ng, names)
    obj.data.update()


def _evaluated_frames(obj) -> tuple:
    """Evaluated positions and the node group's frames (T, N), each (p, 3) float64."""
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = ob_eval.to_mesh()
    try:
        co = read_float(mesh.vertices, "co", 3).astype(np.float64)
        frames = []
        for name in (FRAME_T, FRAME_N):
            attr = mesh.attributes.get(name)
            if attr is None:
                raise ShapeSpaceError(f"the post-deformation node group of {obj.name!r} did not evaluate (no "
                                      f"{name!r} attribute)", ErrorCode.INVALID)
            frames.append(read_float(attr.data, "vector", 3).astype(np.float64))
    finally:
        ob_eval.to_mesh_clear()
    return co, frames[0], frames[1]


def apply_post_deform(obj, example_name: str, sculpt_positions=None, progress=None):
    """Store the example's sculpt as a post-deformation corrective (frame offsets, applied after the armature).

    The rig must be at the example's pose (as for Apply Sculpt).  The key also gets the rest-space inversion
    of the sculpt (muted: for training and flags).  Refused under weighted PSD (its per-vertex result has no
    per-example weight to drive the offsets) and when a modifier changes the topology.  Returns the
    rest-space ``InversionResult`` (its residual is the rest-space one).
    """
    check_not_editing(obj)
    check_topology(obj)
    st = settings(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    if st.method == "WPSD":
        raise ShapeSpaceError("post-deformation correctives need a per-example weight: use PSD or Shape by "
                              "Example (weighted PSD blends per vertex)", ErrorCode.METHOD)
    check_post_deform_stack(obj)
    p = len(obj.data.vertices)
    sculpt_positions = sculpt_positions_of(obj, ex, sculpt_positions)
    blocks = obj.data.shape_keys.key_blocks
    was = ex.post_deform
    had = attribute_name(ex.name) in obj.data.attributes
    try:
        ex.post_deform = True
        if not had:
            _set_attribute(obj.data, attribute_name(ex.name), "FLOAT_VECTOR", np.zeros((p, 3)))
        sync_post_deform(obj)
        offsets = _offsets(obj, ex, sculpt_positions)
        result = apply_example(obj, example_name, sculpt_positions, progress)   # rest-space key, muted below
    except BaseException:
        ex.post_deform = was
        if not had and attribute_name(ex.name) in obj.data.attributes:
            obj.data.attributes.remove(obj.data.attributes[attribute_name(ex.name)])
        sync_post_deform(obj)
        raise
    blocks[ex.name].mute = True
    _set_attribute(obj.data, attribute_name(ex.name), "FLOAT_VECTOR", offsets)
    obj.data.update()
    st.revision += 1
    return result


def _offsets(obj, ex, sculpt_positions) -> np.ndarray:
    """Frame offsets (p, 3) that take the evaluated surface (every corrective at 0) to the sculpt."""
    blocks = obj.data.shape_keys.key_blocks
    saved = {n: blocks[n].value for n in example_keys(obj) if n in blocks}
    try:
        for n in saved:
            blocks[n].value = 0.0
        posed, tangent, normal = _evaluated_frames(obj)
    finally:
        for n, v in saved.items():
            blocks[n].value = v
    bitangent = np.cross(normal, tangent)
    d = sculpt_positions - posed
    offsets = np.stack([np.sum(d * tangent, axis=1), np.sum(d * bitangent, axis=1), np.sum(d * normal, axis=1)], 1)
    size = float(np.linalg.norm(np.ptp(posed, axis=0))) or 1.0
    moved = np.abs(d).max(axis=1) > TOUCH_REL * size
    offsets[~moved] = 0.0                          # float noise of the evaluation, not sculpt
    bad = np.flatnonzero(moved & (np.linalg.norm(tangent, axis=1) < 0.5))
    if bad.size:
        raise ShapeSpaceError(f"vertex {int(bad[0])} has no surface frame (no edge off its normal): it cannot "
                              "carry a post-deformation offset", ErrorCode.DEGENERATE)
    check_finite_positions(offsets, f"the post-deformation offsets of {ex.name!r}")
    return offsets


def remove_post_deform(obj, example_name: str) -> None:
    """Drop an example's offsets and regenerate the node group (called when the example is removed)."""
    attr = obj.data.attributes.get(attribute_name(example_name))
    if attr is not None:
        obj.data.attributes.remove(attr)
    sync_post_deform(obj)
