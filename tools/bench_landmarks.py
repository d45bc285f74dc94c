"""Named-landmark benchmark (issue #22 §3): the automatic proposal against the landmarks placed on each head.

For each shared head (``facecap``, ``fbhead``, ``ict``, ``rpm``) as the target, the named landmarks placed from
known vertex indices (``tools/landmarks/<head>.json``, how they were chosen: ``tools/landmarks/README.md``) are
compared with the ones ``core.authoring.propose_landmark_pairs`` proposes from another head's rig (the target's
shapes unused), in mm with the target scaled to a 30 cm bounding-box diagonal:

- ``landmark_auto_err_mm_<head>``: the largest distance over every named point proposed, over the sources;
- ``landmark_auto_unflagged_err_mm_<head>``: the same over the points the proposal did not flag as unsure;
- ``landmark_auto_median_mm_<head>`` (diagnostic): the median distance over all points and sources;
- ``landmark_auto_flagged_<head>``: the number of flagged points (largest over the sources);
- ``landmark_auto_worst_<head>``: the three worst points as ``source:name``.

Sources: every other head; ``quick`` uses one (FBHead, or facecap for the FBHead target) — a 27k-vertex ICT
source takes ~13 s per target.

    .venv/bpy50/bin/python tools/bench_landmarks.py [--quick]   # JSON on stdout; or run(quick) from a suite
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

from bench_support import shared_data

HEADS = {
    "facecap": ("facecap/facecap_decoded.glb", "Mesh_2"),
    "fbhead": ("llf_fbhead/Live_Link_Face.blend", "FBHead"),
    "ict": ("ict_facekit/ict_facekit_expressions.glb", "ICTFace"),
    "rpm": ("rpm_brunette/brunette-t.glb", "Wolf3D_Head"),
}
LANDMARK_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "landmarks")


def landmark_path(tag: str) -> str:
    """``tools/landmarks/<tag>.json``: the named landmarks placed on a shared head."""
    return os.path.join(LANDMARK_DIR, f"{tag}.json")


def read_head(tag: str):
    """(neutral (n, 3), triangles (f, 3), deltas (k, n, 3), names) of a shared head read through Blender, or None
    when its file is missing."""
    import bpy

    from shapespace.bridge import assets, shapekeys
    rel, name = HEADS[tag]
    path = shared_data(rel, f"the {tag} head")
    if path is None:
        return None
    assets.load(path)
    ob = bpy.data.objects[name]
    me = ob.data
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    model = shapekeys.read_blendshape_model(ob)
    return model.neutral, tris.reshape(-1, 3).astype(np.int64), model.deltas, list(model.names)


def evaluate(heads: dict, placed: dict, sources: dict) -> dict:
    """Metrics for targets ``placed`` ({tag: {name: vertex}}) from ``sources`` ({target tag: [source tags]})."""
    from shapespace.core.authoring import mm_per_unit, propose_landmark_pairs
    out = {}
    for tag, truth in placed.items():
        TV, TT, _, _ = heads[tag]
        mm = mm_per_unit(TV)
        errs, unflagged, worst, flagged = [], [], [], 0
        for src in sources[tag]:
            SV, ST, SD, SN = heads[src]
            res = propose_landmark_pairs(SV, ST, SD, SN, TV, TT, named=True)
            pairs = res.value
            if pairs is None:
                continue
            for name, v, f in zip(pairs.names, pairs.target_index, pairs.flagged):
                if name not in truth:
                    continue
                d = float(np.linalg.norm(TV[v] - TV[truth[name]]) * mm)
                errs.append(d)
                worst.append((d, f"{src}:{name}", bool(f)))
                if not f:
                    unflagged.append(d)
            flagged = max(flagged, int(np.sum(pairs.flagged)))
            print(f"bench landmarks: {src} -> {tag}: {res.message}", file=sys.stderr)
        if not errs:
            continue
        out[f"landmark_auto_err_mm_{tag}"] = max(errs)
        out[f"landmark_auto_unflagged_err_mm_{tag}"] = max(unflagged) if unflagged else 0.0
        out[f"landmark_auto_median_mm_{tag}"] = float(np.median(errs))
        out[f"landmark_auto_flagged_{tag}"] = flagged
        out[f"landmark_auto_worst_{tag}"] = [f"{n} {d:.1f}" for d, n, _ in sorted(worst, reverse=True)[:3]]
        out[f"landmark_auto_worst_unflagged_{tag}"] = [f"{n} {d:.1f}" for d, n, f in sorted(worst, reverse=True)
                                                       if not f][:3]
    return out


def run(quick: bool = False) -> dict:
    """All metrics (``quick``: one source per target)."""
    import package
    package.load()
    from shapespace.core.authoring.named import load_head_file
    heads = {tag: read_head(tag) for tag in HEADS}
    heads = {k: v for k, v in heads.items() if v is not None}
    placed = {tag: load_head_file(landmark_path(tag), len(heads[tag][0])) for tag in heads}
    if quick:
        sources = {tag: ["facecap" if tag == "fbhead" else "fbhead"] for tag in heads}
    else:
        sources = {tag: [s for s in heads if s != tag] for tag in heads}
    sources = {tag: [s for s in src if s in heads] for tag, src in sources.items()}
    return evaluate(heads, placed, sources)


if __name__ == "__main__":
    print(json.dumps(run(quick="--quick" in sys.argv[1:]), indent=1))
