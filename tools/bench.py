"""ShapeSpace benchmarks.

    python tools/bench.py SUITE --json FILE [--quick]

Suites: ``dm`` (direct manipulation, issue #3), ``psd`` (pose-space correctives,
issue #4), ``retarget`` (expression cloning, issue #5), ``facespace`` (covariance inpainting of
held-out gaps in real curves vs Blender's own interpolation, thesis 9.3), ``live`` (live capture
per packet, issue #14); psd, retarget and
facespace also write a PNG plot next to the JSON; ``export`` (glTF/FBX/Alembic round trips through
Blender's importers and bake + export speed, issue #12); ``transfer`` (model transfer between the shared
ARKit heads and symmetry, issue #13).  Every goal metric named in
the issue is computed in ``--quick`` mode too, with fewer repetitions.
Reference solvers are measured in the same run, on the same machine.
Creates ``.venv/bpy50`` on first use (Blender is needed to read the real rigs).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
import env  # noqa: E402

SUITES = ("dm", "psd", "retarget", "facespace", "live", "export", "transfer", "rig")


def main(argv) -> int:
    ap = argparse.ArgumentParser(description="ShapeSpace benchmarks")
    ap.add_argument("suite", choices=SUITES)
    ap.add_argument("--json", required=True, help="write the flat metrics here")
    ap.add_argument("--quick", action="store_true", help="fewer repetitions (same metrics)")
    args = ap.parse_args(argv)
    env.reexec_in("bpy50", os.path.abspath(__file__), argv)
    if args.suite == "dm":
        import bench_dm
        metrics = bench_dm.run(quick=args.quick)
    elif args.suite == "retarget":
        import bench_retarget
        metrics = bench_retarget.run(quick=args.quick, plot_path=os.path.splitext(args.json)[0] + ".png")
    elif args.suite == "live":
        import bench_live
        metrics = bench_live.run(quick=args.quick)
    elif args.suite == "facespace":
        import bench_facespace
        metrics = bench_facespace.run(quick=args.quick, plot_path=os.path.splitext(args.json)[0] + ".png")
    elif args.suite == "export":
        import bench_export
        metrics = bench_export.run(quick=args.quick)
    elif args.suite == "transfer":
        import bench_transfer
        metrics = bench_transfer.run(quick=args.quick)
    elif args.suite == "rig":
        import bench_rig
        metrics = bench_rig.run(quick=args.quick)
    else:
        import bench_psd
        metrics = bench_psd.run(quick=args.quick, plot_path=os.path.splitext(args.json)[0] + ".png")
    with open(args.json, "w", encoding="utf-8") as fh:
        json.dump(metrics, fh, indent=2, sort_keys=True)
    width = max(len(k) for k in metrics)
    for k in sorted(metrics):
        v = metrics[k]
        print(f"{k:<{width}}  {v:.6g}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
