"""Pose-space Mirror Example re-uses the mesh's stored mirror map (issue #13) when it is fresh, and falls back to
the position map across local X otherwise; checked on the stored keys Blender evaluates."""
import json

import numpy as np
import pytest

from blender_support import bpy
from shapespace.bridge import symmetry
from shapespace.core import symmetry as core_sym
from test_correctives import _simple


def _co(kb):
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def _nearly_symmetric_example(ob):
    """Nudge the basis off symmetry by ~1e-3 of the size (beyond the position map's default 1e-4 tolerance; the
    topology, hence the stored map, unchanged) and give PSD_01 a bump on the +X side; return its delta."""
    key = ob.data.shape_keys
    basis = _co(key.reference_key)
    diag = float(np.linalg.norm(np.ptp(basis, axis=0)))
    rng = np.random.default_rng(3)
    basis = basis + rng.normal(0, 1e-3 * diag, basis.shape)
    centre = basis[np.argmax(basis[:, 0] + 0.1 * basis[:, 2])]
    fall = np.exp(-np.sum((basis - centre) ** 2, axis=1) / (0.2 * diag) ** 2)
    delta = 0.02 * diag * fall[:, None] * np.array([0.5, -0.3, 0.8])
    key.reference_key.data.foreach_set("co", basis.astype(np.float32).ravel())
    key.key_blocks["PSD_01"].data.foreach_set("co", (basis + delta).astype(np.float32).ravel())
    ob.data.update()
    return _co(key.key_blocks["PSD_01"]) - _co(key.reference_key), diag


def test_mirror_example_uses_the_fresh_stored_map(registered):
    ob, arm = _simple()
    assert bpy.ops.shapespace.build_mirror_map("EXEC_DEFAULT") == {"FINISHED"}
    mmap = symmetry.load_map(ob)
    assert mmap.coverage == 1.0
    delta, diag = _nearly_symmetric_example(ob)
    assert symmetry.map_status(ob)["state"] == "ok"
    assert bpy.ops.shapespace.psd_mirror_example() == {"FINISHED"}
    st = ob.shapespace_psd
    assert len(st.examples) == 2
    key = ob.data.shape_keys
    got = _co(key.key_blocks[st.examples[1].name]) - _co(key.reference_key)
    want = core_sym.mirror_delta(delta, mmap).value
    np.testing.assert_allclose(got, want, atol=1e-6 * diag)
    moved = np.linalg.norm(delta, axis=1) > 1e-3 * diag
    assert moved.any() and np.all(np.linalg.norm(got[mmap.mirror[moved]], axis=1) > 1e-3 * diag)


@pytest.mark.parametrize("how", ["stale", "none"])
def test_without_a_fresh_map_mirror_example_falls_back_to_the_position_map(registered, how):
    ob, arm = _simple()
    assert bpy.ops.shapespace.build_mirror_map("EXEC_DEFAULT") == {"FINISHED"}
    _nearly_symmetric_example(ob)
    if how == "stale":
        data = json.loads(ob.data[symmetry.PROP])
        data["topology"]["edge_hash"] = "0" * 40
        ob.data[symmetry.PROP] = json.dumps(data)
        assert symmetry.map_status(ob)["state"] == "stale"
    else:
        del ob.data[symmetry.PROP]
    # today's position map: the nudged basis is not symmetric within the default tolerance, but is within 1 %
    with pytest.raises(RuntimeError, match="not symmetric"):
        bpy.ops.shapespace.psd_mirror_example()
    assert len(ob.shapespace_psd.examples) == 1
    assert bpy.ops.shapespace.psd_mirror_example(tolerance=0.01) == {"FINISHED"}
    assert len(ob.shapespace_psd.examples) == 2
