"""Round trips for tests and benchmarks: evaluate the source, re-import the export with Blender's own
importer into an empty file, evaluate it at the same frames and compare (core.export.compare)."""
from __future__ import annotations

import json
import struct

import bpy
import numpy as np

from ...core.export.compare import match_vertices, roundtrip_error
from ..arrays import read_float


def world_positions(obj, depsgraph) -> np.ndarray:
    """Evaluated world-space positions of ``obj`` (p, 3), float64."""
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = ob_eval.to_mesh()
    try:
        co = read_float(mesh.vertices, "co", 3).astype(np.float64)
    finally:
        ob_eval.to_mesh_clear()
    m = np.array(ob_eval.matrix_world, dtype=np.float64)
    return co @ m[:3, :3].T + m[:3, 3]


def sample_positions(obj_names, frames, scene=None) -> dict:
    """``{name: (f, p, 3)}`` evaluated world positions at ``frames`` (the scene frame is restored)."""
    scene = scene or bpy.context.scene
    current = scene.frame_current
    out = {n: [] for n in obj_names}
    try:
        for f in frames:
            scene.frame_set(int(f))
            dg = bpy.context.evaluated_depsgraph_get()
            for n in obj_names:
                out[n].append(world_positions(bpy.data.objects[n], dg))
    finally:
        scene.frame_set(current)
    return {n: np.array(v) for n, v in out.items()}


def reimport(fmt: str, path: str, fps: int, fps_base: float = 1.0) -> list:
    """Start an empty file at the source's frame rate and import ``path`` with Blender's importer; returns the
    new mesh objects' names."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(fps), float(fps_base)
    if fmt == "gltf":
        bpy.ops.import_scene.gltf(filepath=path)
    elif fmt == "fbx":
        bpy.ops.import_scene.fbx(filepath=path, anim_offset=0.0)
    else:
        bpy.ops.wm.alembic_import(filepath=path, as_background_job=False)
    return [ob.name for ob in bpy.data.objects if ob.type == "MESH"]


def counterpart(name: str, imported: list) -> str:
    """The imported mesh standing for source object ``name`` (same name, maybe with a numeric suffix)."""
    for cand in imported:
        if cand == name or cand.rsplit(".", 1)[0] == name or cand == name.replace(".", "_") \
                or cand.rsplit("_", 1)[0] == name.replace(".", "_"):
            return cand
    if len(imported) == 1:
        return imported[0]
    raise KeyError(f"no imported mesh for {name!r} among {imported}")


def compare(source: dict, imported: dict) -> dict:
    """``{name: (f,) relative error per frame}`` for each source mesh and its imported counterpart."""
    out = {}
    for name, src in source.items():
        imp = imported[name]
        mapping = match_vertices(src[0], imp[0])
        out[name] = roundtrip_error(src, imp, mapping)
    return out


def imported_positions(source_names, imported_names, frames) -> dict:
    """``{source name: (f, q, 3)}`` of the imported counterparts at ``frames``."""
    pairs = {n: counterpart(n, imported_names) for n in source_names}
    got = sample_positions(list(pairs.values()), frames)
    return {n: got[c] for n, c in pairs.items()}


def glb_animations(path: str) -> tuple:
    """A .glb's JSON and every morph-weight animation output in it, concatenated (what an importer reads)."""
    with open(path, "rb") as fh:
        data = fh.read()
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + json_len])
    bin_start = 20 + json_len + 8
    out = []
    for anim in doc.get("animations", []):
        for ch in anim["channels"]:
            if ch["target"]["path"] != "weights":
                continue
            acc = doc["accessors"][anim["samplers"][ch["sampler"]]["output"]]
            view = doc["bufferViews"][acc["bufferView"]]
            start = bin_start + view.get("byteOffset", 0) + acc.get("byteOffset", 0)
            out.append(np.frombuffer(data, dtype="<f4", count=acc["count"], offset=start))
    return doc, (np.concatenate(out) if out else np.zeros(0))
