"""Where the time of a 10-minute take goes (issue #24): the batch command's stages, timed in one Blender process.

The shipped Live Link Face take looped to 36,000 scene frames onto FBHead or ICT FaceKit
(``bench_retarget._tiled_csv`` at the head's rate, as the ``longtake_s_<method>_<head>_36000`` benchmark keys), key
reduction at 0.01, for each method given: reading (file → scene frames), solving (copy / per-frame / space-time),
key reduction, writing the curves — wall and CPU seconds of each, dense and kept keys, JSON per method on stdout.
``.venv/bpy50/bin/python tools/profile_longtake.py [--head fbhead|ict] copy perframe spacetime``
"""
import json
import os
import resource
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import package  # noqa: E402

#: head label → (file under assets/ or ../shared/data, object name, scene rate of the tiled take)
HEADS = {"fbhead": (os.path.join("llf_fbhead", "Live_Link_Face.blend"), "FBHead", 30.0),
         "ict": (os.path.join("ict_facekit", "ict_facekit_expressions.glb"), "ICTFace", 24.0)}


def _clock():
    return time.perf_counter(), time.process_time()


def stages(method: str, csv: str, path: str, name: str) -> dict:
    import bpy

    from shapespace.bridge import assets, retarget
    from shapespace.core.retarget import copy_weights, retarget_weights
    from shapespace.core.retarget.job import plan_curves
    assets.load(path)
    ob = bpy.data.objects[name]
    marks = [_clock()]
    plan = retarget.read_retarget(ob, csv, method, key_tolerance=0.01)
    marks.append(_clock())
    raw = copy_weights(plan.source_weights, plan.pairs, plan.model.n_targets, plan.gain, plan.offset)
    fit = retarget_weights(plan.model, raw, plan.method, plan.lam)
    marks.append(_clock())
    curves, kept = plan_curves(plan.model.names, plan.paths, plan.frames, fit.weights, plan.key_tolerance,
                               plan.key_shape)
    marks.append(_clock())
    plan.report.record(fit, plan.frames)
    retarget.write_retarget(retarget.RetargetOutcome(plan, fit.weights, curves, plan.report))
    marks.append(_clock())
    out = {}
    for k, stage in enumerate(("read", "solve", "key_reduction", "write")):
        out[f"{stage}_s"] = marks[k + 1][0] - marks[k][0]
        out[f"{stage}_cpu_s"] = marks[k + 1][1] - marks[k][1]
    out.update({"total_s": marks[-1][0] - marks[0][0], "total_cpu_s": marks[-1][1] - marks[0][1],
                "frames": int(plan.frames.size), "curves": len(curves),
                "keys": int(sum(np.size(c[1]) for c in curves)), "keys_kept_frac": kept,
                "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9})
    return out


def main(argv) -> None:
    package.load()
    import bench_retarget
    from bench_support import shared_data
    head = "fbhead"
    if argv[:1] == ["--head"]:
        head, argv = argv[1], argv[2:]
    rel, name, fps = HEADS[head]
    path = shared_data(rel, f"the {head} long take")
    if path is None:
        return
    csv = bench_retarget._tiled_csv(tempfile.mkdtemp(prefix="shapespace_profile_"), 36000, fps)
    for method in argv or ("copy", "perframe", "spacetime"):
        print(json.dumps({method: {"head": head, **stages(method, csv, path, name)}}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
