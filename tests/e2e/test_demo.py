"""The README's demo command works and its report says what Blender says."""
import json
import os
import subprocess
import sys

import pytest

from support import ROOT

pytest.importorskip("bpy")


def test_demo_writes_blend_renders_and_report(tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "demo.py"), "--out", str(out),
                           "--size", "128"], capture_output=True, text=True, timeout=600, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["head"]["vertices"] == 2694 and report["head"]["targets"] == 52
    assert report["head"]["rank"] == 51
    assert report["model_vs_blender_max_rel_error"] < 1e-5
    dm = report["direct_manipulation"]
    errs = dm["max_error_rel_after_each_drag"]
    assert dm["drags"] == 5 and len(errs) == 6
    assert errs[-1] < 0.5 * errs[0]  # the drags bring the neutral toward the captured expression
    assert (out / "demo.blend").stat().st_size > 0
    pc = report["pose_space_correctives"]
    assert len(pc["examples"]) == 3
    assert pc["max_error_rel_corrected"] < 0.25 * pc["max_error_rel_lbs"]   # the held-out bend is fixed
    rt = report["retargeting"]
    assert rt["llf_on_facecap"]["mapped_channels"] == 52 and rt["facecap_on_fbhead"]["mapped_channels"] == 51
    assert 0 < rt["llf_on_facecap"]["keys_kept_frac"] < 0.5
    assert pc["confidence_variance_held_out"] < pc["confidence_variance_far_bend"]  # examples cover 2.1 rad
    fsd = report["face_space"]
    assert fsd["empty_targets"] == ["tongueOut"] and 1 < fsd["compression"]["components"] < 52
    ib = fsd["inbetween"]
    assert ib["mid_norm_shell"] > ib["mid_norm_linear"]          # linear drifts toward the average face
    assert abs(ib["mid_norm_shell"] - sum(ib["endpoint_norms"]) / 2) < 1e-3 * ib["mid_norm_shell"]
    renders = (list(dm["renders"].values()) + list(pc["renders"].values())
               + [p for paths in rt["renders"].values() for p in paths] + list(fsd["renders"].values()))
    for png in [report["outputs"][k] for k in ("neutral_png", "frame_png")] + renders:
        with open(png, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    # the saved file reopens and still plays the capture on the head
    check = ("import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
             "k = bpy.data.objects['Mesh_2'].data.shape_keys; "
             "assert k.animation_data and k.animation_data.action, 'no action'; print('REOPEN-OK')")
    proc = subprocess.run([sys.executable, "-c", check, str(out / "demo.blend")], capture_output=True,
                          text=True, timeout=300, env=dict(os.environ))
    assert "REOPEN-OK" in proc.stdout, proc.stderr[-2000:]
