"""Retargeting at production scale (#11): the batch command's progress lines."""
import os
import re
import shutil
import subprocess
import sys

from support import ASSETS, ROOT

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")


def test_batch_prints_a_progress_line_per_source_with_frames_per_second(tmp_path):
    blend, takes = tmp_path / "shot.blend", [tmp_path / "a.csv", tmp_path / "b.csv"]
    shutil.copy(BLEND, blend)
    for t in takes:
        shutil.copy(CSV, t)
    proc = subprocess.run([sys.executable, RUN_CLI, str(blend), "--", "retarget", "--source", str(takes[0]),
                           "--source", str(takes[1]), "--method", "copy", "--dry-run"],
                          capture_output=True, text=True, timeout=600, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "frames/s" in ln]
    assert len(lines) == 2
    for take, line in zip(takes, lines):
        m = re.fullmatch(rf"shapespace: {re.escape(str(take))}: (\d+) frames in [\d.]+ s \((\d+) frames/s\)", line)
        assert m and int(m.group(1)) > 100 and int(m.group(2)) > 0, line
