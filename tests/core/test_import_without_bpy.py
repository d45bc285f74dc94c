"""core must be importable (and usable) with Blender's modules absent."""
import os
import re
import subprocess
import sys

REPO_ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))

CORE_DIR = os.path.join(REPO_ROOT, "core")
SUBMODULES = ["core.blendshape", "core.skinning", "core.animation", "core.names", "core.result"]


def test_import_core_with_bpy_blocked():
    code = (
        "import sys, importlib\n"
        "sys.modules['bpy'] = None\n"
        "sys.modules['mathutils'] = None\n"
        f"sys.path.insert(0, {REPO_ROOT!r})\n"
        "import core\n"
        f"for name in {SUBMODULES!r}:\n"
        "    importlib.import_module(name)\n"
        "import numpy as np\n"
        # a tiny smoke use so lazy imports inside functions would also trip
        "m = core.BlendshapeModel(np.zeros((2, 3)), np.ones((1, 2, 3)), ['a'])\n"
        "assert np.allclose(m.evaluate([1.0]), 1.0)\n"
        "assert core.canonical_name('eyeBlink_L') == 'eyeBlinkLeft'\n"
        "assert 'bpy' not in [k for k, v in sys.modules.items() if v is not None]\n"
        "print('OK')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=os.path.dirname(REPO_ROOT), timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("OK")


def test_core_sources_do_not_mention_blender_modules():
    pattern = re.compile(r"^\s*(import\s+(bpy|mathutils)\b|from\s+(bpy|mathutils)\b)", re.M)
    files = [f for f in os.listdir(CORE_DIR) if f.endswith(".py")]
    assert files, "core/ has no python files"
    for fname in files:
        with open(os.path.join(CORE_DIR, fname), encoding="utf-8") as fh:
            text = fh.read()
        assert "import bpy" not in text, fname
        assert "import mathutils" not in text, fname
        assert not pattern.search(text), fname
