"""Where the time of a 10-minute take goes (issue #24): the batch command's stages, timed in one Blender process.

The shipped Live Link Face take looped to 36,000 scene frames onto FBHead (``bench_retarget._tiled_csv``, as
the ``longtake_s_<method>_fbhead_36000`` benchmark keys), key reduction at 0.01, for each method given:
reading (file → scene frames), solving (copy / per-frame / space-time), key reduction, writing the curves —
JSON per method on stdout.  ``.venv/bpy50/bin/python tools/profile_longtake.py copy perframe spacetime``
"""
import json
import os
import resource
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import package  # noqa: E402


def stages(method: str, csv: str) -> dict:
    import bpy

    from bench_support import ASSETS
    from shapespace.bridge import assets, retarget
    from shapespace.core.retarget import copy_weights, retarget_weights
    from shapespace.core.retarget.job import plan_curves
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    t0 = time.perf_counter()
    plan = retarget.read_retarget(ob, csv, method, key_tolerance=0.01)
    t1 = time.perf_counter()
    raw = copy_weights(plan.source_weights, plan.pairs, plan.model.n_targets, plan.gain, plan.offset)
    fit = retarget_weights(plan.model, raw, plan.method, plan.lam)
    t2 = time.perf_counter()
    curves, kept = plan_curves(plan.model.names, plan.paths, plan.frames, fit.weights, plan.key_tolerance,
                               plan.key_shape)
    t3 = time.perf_counter()
    plan.report.record(fit, plan.frames)
    retarget.write_retarget(retarget.RetargetOutcome(plan, fit.weights, curves, plan.report))
    t4 = time.perf_counter()
    return {"read_s": t1 - t0, "solve_s": t2 - t1, "key_reduction_s": t3 - t2, "write_s": t4 - t3,
            "total_s": t4 - t0, "frames": int(plan.frames.size), "keys_kept_frac": kept,
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9}


def main(methods) -> None:
    package.load()
    import bench_retarget
    csv = bench_retarget._tiled_csv(tempfile.mkdtemp(prefix="shapespace_profile_"), 36000, 30.0)
    for method in methods or ("copy", "perframe", "spacetime"):
        print(json.dumps({method: stages(method, csv)}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
