"""Every capture app's recording retargets like the Live Link Face CSV (issue #24), and ``info`` describes it.

The known take is the shared Live Link Face recording at an even 60 fps (so every format, with or without
its own times, carries the same samples), written in each format by ``tools/capture_files.py`` from the
formats' documentation.  Retargeted by copy onto FBHead, each gives the Live Link Face CSV's curves.
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from blender_support import bpy, import_file
from capture_files import WRITERS, load_llf_take
from shapespace.bridge import actions, retarget
from support import ASSETS, ROOT

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")
EXT = {"llf_csv": ".csv", "facecap_txt": ".txt", "ifacialmocap": ".txt", "audio2face_json": ".json",
       "mediapipe_json": ".json", "mediapipe_csv": ".csv"}


@pytest.fixture(scope="module")
def even_take():
    names, t, w, rot = load_llf_take(CSV)
    return names, np.arange(t.size) / 60.0, w, rot


def write(tmp_path, kind, take):
    path = tmp_path / f"take_{kind}{EXT[kind]}"
    path.write_text(WRITERS[kind](take), encoding="utf-8")
    return str(path)


def curves_of(ob, action_name):
    curves = actions.shape_key_curves(ob, bpy.data.actions[action_name])
    return {n: actions.read_curve(fc)[:2] for n, fc in curves.items()}


def test_every_format_retargets_to_the_csv_curves(tmp_path, even_take):
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    reference = curves_of(ob, retarget.retarget(ob, write(tmp_path, "llf_csv", even_take), "copy")["action"])
    assert len(reference) == 51
    for kind in ("facecap_txt", "ifacialmocap", "audio2face_json", "mediapipe_json", "mediapipe_csv"):
        rep = retarget.retarget(ob, write(tmp_path, kind, even_take), "copy")
        got = curves_of(ob, rep["action"])
        assert set(got) == set(reference), kind
        for name, (x, y) in reference.items():
            np.testing.assert_array_equal(got[name][0], x, err_msg=f"{kind} {name}")
            np.testing.assert_allclose(got[name][1], y, atol=1e-6, err_msg=f"{kind} {name}")


def test_read_source_detects_the_kind_from_content(tmp_path, even_take):
    path = tmp_path / "take.dat"                           # no known extension: read for its content
    path.write_text(WRITERS["audio2face_json"](even_take), encoding="utf-8")
    names, frames, w, _ = retarget.read_source(str(path), bpy.context.scene)
    assert "jawOpen" in names and w.shape == (frames.size, 52)


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def test_cli_info_describes_capture_files(tmp_path, even_take):
    facecap, a2f = write(tmp_path, "facecap_txt", even_take), write(tmp_path, "audio2face_json", even_take)
    code, out, err = _cli("--", "info", facecap, a2f, CSV)
    assert code == 0, err
    reps = json.loads(out[out.index("["):])
    assert [r["kind"] for r in reps] == ["facecap_txt", "audio2face_json", "llf_csv"]
    fc, a2, llf = reps
    n = even_take[1].size
    assert fc["frames"] == n and fc["channels"] == 52 and fc["rate"] == pytest.approx(60, abs=0.01)
    assert fc["duration_s"] == pytest.approx((n - 1) / 60, abs=1e-6)
    assert fc["head_eye_channels"][0] == "HeadYaw" and "HeadYaw" in fc["head_eye_moving"]
    assert a2["head_eye_channels"] == [] and a2["rate"] == 60
    assert llf["frames"] == 328 and len(llf["head_eye_channels"]) == 9 and "HeadYaw" not in llf["head_eye_moving"]
    assert llf["start_timecode"] == "00:32:09:07.867"
