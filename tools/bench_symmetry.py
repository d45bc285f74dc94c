"""Symmetry benchmark (issue #13 §3): mirror-map coverage on every shared head and split + recombine exactness.

``mirror_mapped_frac_<asset>``: fraction of the head's vertices the Build Mirror Map verb (AUTO: by position
within 1e-3 of the bounding-box diagonal, improved by topology from centre edges found on the plane) pairs with
a mirror vertex; the plane goes through the object origin or, when that maps more, the bounding-box centre
(facecap's head sits off-centre in its local space).  ``mirror_unmapped_<asset>`` lists the vertices left
unmapped, by index.  Goal: ≥ 0.995 on every head.

``split_recombine_err_max``: every shape key of every head is split into _L/_R by the Split Shape verb (stored
float32 keys, written to Blender), and max |(L − basis) + (R − basis) − (S − basis)| over vertices, shapes and
heads is divided by the head's bounding-box diagonal.  Blender evaluates the halves from those same float32
keys, so this is float32 precision (~1e-7) at best; ``split_recombine_err_max_eval`` is the same check
through Blender's depsgraph (halves at 1/1 vs the original at 1) for the first shapes of each head, and
``split_recombine_err_max_core`` the float64 core identity.  Goal: float precision.

Helper D's ``tools/bench_transfer.py`` merges :func:`run` into the ``transfer`` suite.
"""
from __future__ import annotations

import os
import time

import numpy as np

from bench_support import shared_data

#: key name → (path under assets/ or shared/data, object name); every shared asset that is a head.
HEADS = {
    "facecap": ("facecap/facecap_decoded.glb", "Mesh_2"),
    "fbhead": ("llf_fbhead/Live_Link_Face.blend", "FBHead"),
    "ict": ("ict_facekit/ict_facekit_expressions.glb", "ICTFace"),
    "rpm": ("rpm_brunette/brunette-t.glb", "Wolf3D_Head"),
}


def _load(rel: str, name: str, what: str):
    import bpy

    from shapespace.bridge import assets
    path = shared_data(rel, what)
    if path is None:
        return None
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assets.load(path, replace=False)
    ob = bpy.data.objects.get(name)
    if ob is not None and ob.data.shape_keys is not None:
        ob.data.shape_keys.animation_data_clear()
        for kb in ob.data.shape_keys.key_blocks[1:]:
            kb.value = 0.0
            kb.mute = False
    return ob


def _evaluated(ob):
    import bpy

    from shapespace.bridge import meshes
    bpy.context.view_layer.update()
    return meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)


def _split_errors(ob, mmap, n_eval: int) -> tuple:
    """(max stored error, max evaluated error, max core error), each relative to the bounding-box diagonal."""
    from shapespace.bridge import symmetry
    from shapespace.core import symmetry as core_sym
    blocks = ob.data.shape_keys.key_blocks
    rest = symmetry.rest_positions(ob)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    names = [kb.name for kb in blocks[1:]]
    w = core_sym.split_weights(rest, mmap.axis, mmap.offset, 0.05)
    stored = evald = core = 0.0
    for i, name in enumerate(names):
        delta = symmetry.key_delta(ob, name)
        left, right = core_sym.split_delta(delta, w)
        core = max(core, float(np.abs(core_sym.combine_deltas(left, right) - delta).max()) / diag)
        lname, rname = symmetry.split_shape(ob, name, mmap, 0.05)
        halves = symmetry.key_delta(ob, lname) + symmetry.key_delta(ob, rname)
        stored = max(stored, float(np.abs(halves - delta).max()) / diag)
        if i < n_eval:
            for kb in blocks[1:]:
                kb.value = 0.0
            blocks[name].mute = False
            blocks[name].value = 1.0
            whole = _evaluated(ob)
            blocks[name].value = 0.0
            blocks[name].mute = True
            blocks[lname].value = blocks[rname].value = 1.0
            evald = max(evald, float(np.abs(_evaluated(ob) - whole).max()) / diag)
        blocks[lname].value = blocks[rname].value = 0.0
    return stored, evald, core


def run(quick: bool = False) -> dict:
    import package
    package.load()
    from shapespace.bridge import symmetry
    metrics = {}
    worst = {"stored": 0.0, "eval": 0.0, "core": 0.0}
    for asset, (rel, name) in HEADS.items():
        ob = _load(rel, name, f"mirror map of {asset}")
        if ob is None:
            continue
        t0 = time.perf_counter()
        maps = [symmetry.build_map(ob, "AUTO", "X", centre) for centre in ("ORIGIN", "BOUNDS")]
        mmap = max(maps, key=lambda m: m.coverage)
        metrics[f"mirror_build_s_{asset}"] = (time.perf_counter() - t0) / 2
        metrics[f"mirror_mapped_frac_{asset}"] = mmap.coverage
        metrics[f"mirror_unmapped_count_{asset}"] = int(len(mmap.unmapped))
        metrics[f"mirror_unmapped_{asset}"] = mmap.unmapped.tolist()
        metrics[f"mirror_method_{asset}"] = mmap.method
        symmetry.store_map(ob, mmap)
        if ob.data.shape_keys is not None and len(ob.data.shape_keys.key_blocks) > 1:
            stored, evald, core = _split_errors(ob, mmap, n_eval=3 if quick else 8)
            metrics[f"split_recombine_err_{asset}"] = stored
            worst = {"stored": max(worst["stored"], stored), "eval": max(worst["eval"], evald),
                     "core": max(worst["core"], core)}
    metrics["split_recombine_err_max"] = worst["stored"]
    metrics["split_recombine_err_max_eval"] = worst["eval"]
    metrics["split_recombine_err_max_core"] = worst["core"]
    fracs = [v for k, v in metrics.items() if k.startswith("mirror_mapped_frac_")]
    metrics["mirror_goal_met"] = int(bool(fracs) and min(fracs) >= 0.995 and worst["stored"] <= 1e-6)
    return metrics


if __name__ == "__main__":
    import json
    import sys
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    print(json.dumps(run(quick="--quick" in sys.argv), indent=1, sort_keys=True))
