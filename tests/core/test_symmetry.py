"""Mirror maps (position and topology) and shape-delta mirroring, splitting and combining (core/symmetry.py)."""
import numpy as np
import pytest

from core import symmetry as S
from core.result import ShapeSpaceError, Status

N = 4          # columns each side of the centre column
ROWS = 5


def grid_mesh(n=N, rows=ROWS, triangles=True):
    """A symmetric sheet: vertex (i, j) at x = i − n, bent in z by |x|; quads split into triangles whose diagonals
    mirror across the centre column.  Returns positions (p, 3), loop arrays, index(i, j) and the known mirror."""
    cols = 2 * n + 1
    idx = lambda i, j: j * cols + i  # noqa: E731
    ii, jj = np.meshgrid(np.arange(cols), np.arange(rows))
    x = (ii - n).ravel().astype(float)
    y = jj.ravel().astype(float)
    co = np.stack([x * 0.1, y * 0.1 + 0.02 * x ** 2, 0.05 * np.cos(x) + 0.01 * y], axis=1)
    faces = []
    for j in range(rows - 1):
        for i in range(cols - 1):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            if not triangles:
                faces.append([a, b, c, d])
            elif i < n:
                faces += [[a, b, c], [a, c, d]]
            else:                           # the mirror image of the left diagonal
                faces += [[a, b, d], [b, c, d]]
    totals = np.array([len(f) for f in faces])
    starts = np.cumsum(totals) - totals
    loops = np.concatenate(faces)
    mirror = np.array([idx(2 * n - i, j) for j in range(rows) for i in range(cols)])
    return co, loops, starts, totals, idx, mirror


def topo_of(co, loops, starts, totals):
    return S.Topology.from_loops(len(co), loops, starts, totals, S.weld_coincident(co))


def posed(co):
    """A non-rigid, asymmetric deformation (a twist and a shear that depend on x): position mirroring fails."""
    out = co.copy()
    out[:, 0] += 0.07 * co[:, 1] + 0.05 * np.sin(3 * co[:, 0] + 1.0)
    out[:, 2] += 0.2 * co[:, 0] ** 2 + 0.3 * co[:, 0]
    return out


def test_position_map_known_answer():
    co, *_, mirror = grid_mesh()
    m = S.position_map(co)
    assert m.status == Status.OK and m.coverage == 1.0
    np.testing.assert_array_equal(m.mirror, mirror)
    np.testing.assert_array_equal(np.flatnonzero(m.centre), np.flatnonzero(co[:, 0] == 0))
    assert m.unmapped.size == 0


def test_position_map_with_offset_plane_and_other_axis():
    co, *_, mirror = grid_mesh()
    shifted = co[:, [1, 0, 2]] + np.array([0.0, 5.0, 0.0])     # symmetric across y = 5
    assert S.position_map(shifted, axis="Y", offset=0.0).coverage < 0.5
    m = S.position_map(shifted, axis="Y", offset=None)
    assert m.offset == pytest.approx(5.0) and m.axis == 1
    np.testing.assert_array_equal(m.mirror, mirror)


def test_coincident_vertices_are_paired_one_to_one():
    co, *_, mirror = grid_mesh()
    dup = np.vstack([co, co[[0, 8, 4]]])          # seam copies of a vertex pair (0 ↔ 8) and of a centre vertex (4)
    m = S.position_map(dup)
    assert m.coverage == 1.0
    assert np.array_equal(m.mirror[m.mirror], np.arange(len(dup)))           # involution
    assert len(np.unique(m.mirror)) == len(dup)                              # one-to-one
    np.testing.assert_allclose(dup[m.mirror], dup * [-1.0, 1.0, 1.0], atol=1e-12)


def test_topology_map_on_symmetric_mesh_matches_known_answer():
    co, loops, starts, totals, idx, mirror = grid_mesh()
    t = topo_of(co, loops, starts, totals)
    m = S.topology_map(t, (idx(N, 1), idx(N, 2)))
    assert m.status == Status.OK and m.method == "topology"
    np.testing.assert_array_equal(m.mirror, mirror)


def test_quads_too():
    co, loops, starts, totals, idx, mirror = grid_mesh(triangles=False)
    m = S.topology_map(topo_of(co, loops, starts, totals), (idx(N, 2), idx(N, 3)))
    np.testing.assert_array_equal(m.mirror, mirror)


def test_posed_mesh_position_fails_topology_succeeds():
    co, loops, starts, totals, idx, mirror = grid_mesh()
    p = posed(co)
    by_pos = S.position_map(p)
    assert by_pos.status == Status.WARNING and by_pos.coverage < 0.5
    assert len(by_pos.unmapped) == int(np.sum(by_pos.mirror < 0))
    assert "have no mirror" in by_pos.message
    m = S.topology_map(topo_of(p, loops, starts, totals), (idx(N, 0), idx(N, 1)))
    np.testing.assert_array_equal(m.mirror, mirror)


def test_topology_across_a_uv_seam_with_weld():
    """Split the sheet along a row (duplicated vertices): welded, the walk still crosses it."""
    co, loops, starts, totals, idx, mirror = grid_mesh()
    cols = 2 * N + 1
    row = 2
    seam = np.arange(row * cols, (row + 1) * cols)
    co2 = np.vstack([co, co[seam]])
    new_of = {int(v): len(co) + k for k, v in enumerate(seam)}
    loops2 = loops.copy()
    face_of_loop = np.repeat(np.arange(len(starts)), totals)
    upper = np.array([(loops[starts[f]:starts[f] + totals[f]] // cols).min() >= row for f in range(len(starts))])
    for k in range(len(loops2)):
        if upper[face_of_loop[k]] and int(loops2[k]) in new_of:
            loops2[k] = new_of[int(loops2[k])]
    unwelded = S.Topology.from_loops(len(co2), loops2, starts, totals)
    assert S.topology_map(unwelded, (idx(N, 0), idx(N, 1))).coverage < 1.0
    m = S.topology_map(topo_of(co2, loops2, starts, totals), (idx(N, 0), idx(N, 1)))
    assert m.coverage == 1.0
    expected = np.concatenate([mirror, [new_of[int(mirror[v])] for v in seam]])
    np.testing.assert_array_equal(m.mirror, expected)


def test_separate_part_filled_by_position():
    co, loops, starts, totals, idx, mirror = grid_mesh()
    eye = np.array([[0.2, 0.9, 0.5], [-0.2, 0.9, 0.5], [0.0, 1.0, 0.5]])     # loose vertices (an "eye")
    co2 = np.vstack([co, eye])
    t = topo_of(co2, loops, starts, totals)
    m = S.topology_map(t, (idx(N, 0), idx(N, 1)))
    assert m.status == Status.WARNING and set(m.unmapped.tolist()) == {len(co), len(co) + 1, len(co) + 2}
    filled = S.fill_by_position(m, co2)
    assert filled.coverage == 1.0 and filled.method == "topology+position"
    assert filled.mirror[len(co)] == len(co) + 1 and filled.mirror[len(co) + 2] == len(co) + 2
    np.testing.assert_array_equal(filled.mirror[:len(co)], mirror)


def test_auto_map_finds_a_centre_edge_when_position_fails_partly():
    co, loops, starts, totals, idx, mirror = grid_mesh()
    p = co.copy()
    p[idx(1, 3)] += [0.0, 0.0, 0.03]             # a local asymmetric sculpt: two vertices lose their partner
    assert S.position_map(p).coverage < 1.0
    m = S.auto_map(p, topo_of(p, loops, starts, totals))
    np.testing.assert_array_equal(m.mirror, mirror)


def test_bad_centre_edges_are_refused():
    co, loops, starts, totals, idx, _ = grid_mesh()
    t = topo_of(co, loops, starts, totals)
    with pytest.raises(ShapeSpaceError) as e:
        S.topology_map(t, (idx(0, 0), idx(3, 3)))
    assert e.value.code == "centre_edge"
    with pytest.raises(ShapeSpaceError) as e:
        S.topology_map(t, (idx(N, 0), idx(N + 1, 0)))           # a boundary edge
    assert e.value.code == "centre_edge" and "one side only" in str(e.value)


def test_no_symmetry_reports_unmapped_and_does_nothing_wrong():
    rng = np.random.default_rng(3)
    co = rng.uniform(0.1, 1.0, size=(50, 3))                   # all on one side: nothing can mirror
    m = S.position_map(co)
    assert m.status == Status.WARNING and m.coverage == 0.0
    np.testing.assert_array_equal(m.unmapped, np.arange(50))
    delta = rng.normal(size=(50, 3))
    r = S.mirror_delta(delta, m)
    assert r.status == Status.WARNING and r.diagnostics["lost_vertices"] == list(range(50))
    np.testing.assert_array_equal(r.value, 0.0)                # nothing invented
    s = S.symmetrize_delta(delta, m, co)
    np.testing.assert_array_equal(s.value, delta)              # unmapped vertices keep their delta
    assert s.status == Status.WARNING


def test_mirror_delta_known_answer_and_twice_is_identity():
    co, *_, mirror = grid_mesh()
    m = S.position_map(co)
    rng = np.random.default_rng(0)
    delta = rng.normal(size=co.shape)
    once = S.mirror_delta(delta, m)
    assert once.status == Status.OK
    expected = delta[mirror] * [-1.0, 1.0, 1.0]
    np.testing.assert_array_equal(once.value, expected)
    np.testing.assert_array_equal(S.mirror_delta(once.value, m).value, delta)


def test_mirror_fills_unpaired_vertices_from_the_mirrored_surface():
    """#26.12: a vertex the map cannot pair takes the mirrored motion of the surface at its reflected position,
    interpolated (exact for a linear motion field); one whose reflection is off the mesh is left still and
    reported, as before."""
    xs, ys = np.linspace(-1.0, 1.0, 5), np.linspace(0.0, 1.0, 3)
    grid = np.array([[x, y, 0.0] for y in ys for x in xs])
    tris = []
    for j in range(2):
        for i in range(4):
            a, b, c, d = j * 5 + i, j * 5 + i + 1, (j + 1) * 5 + i, (j + 1) * 5 + i + 1
            tris += [[a, b, d], [a, d, c]]
    extra = np.array([[-0.3, 0.4, 0.0],                 # right side; its reflection lies inside a left triangle
                      [-0.7, 0.2, 0.5]])                # its reflection is 0.5 off the mesh: nothing to take
    co = np.vstack([grid, extra])
    mmap = S.position_map(co)
    assert mmap.unmapped.tolist() == [15, 16]
    rng = np.random.default_rng(0)
    A, b = rng.normal(size=(3, 3)), rng.normal(size=3)
    delta = co @ A.T + b                                  # a linear motion field
    res = S.mirror_delta(delta, mmap, co, np.array(tris))
    field = lambda p: p @ A.T + b                         # noqa: E731
    reflect = lambda p: p * [-1.0, 1.0, 1.0]              # noqa: E731
    np.testing.assert_allclose(res.value[15], reflect(field(reflect(co[15]))), atol=1e-12)
    np.testing.assert_allclose(res.value[:15], reflect(field(reflect(co[:15]))), atol=1e-12)
    np.testing.assert_array_equal(res.value[16], 0.0)
    assert res.diagnostics["filled"] == [15] and res.diagnostics["lost_vertices"] == [16]
    assert res.status == Status.WARNING and res.message.startswith(
        "1 vertices without a mirror took the mirrored surface's motion at their reflected position; 1 moving")
    assert S.mirror_delta(delta, mmap).diagnostics["filled"] == []    # without the rest mesh: no fill


def test_split_and_combine_exact():
    co, *_ = grid_mesh()
    rng = np.random.default_rng(1)
    delta = rng.normal(size=co.shape)
    for falloff in (0.0, 0.05, 0.5):
        w = S.split_weights(co, falloff=falloff)
        assert w.min() >= 0 and w.max() <= 1
        left, right = S.split_delta(delta, w)
        np.testing.assert_allclose(S.combine_deltas(left, right), delta, rtol=0, atol=4 * np.finfo(float).eps)
        # each half stays on its side: far left vertices are fully in L, far right fully in R
        far_left, far_right = co[:, 0] >= 0.3, co[:, 0] <= -0.3
        np.testing.assert_array_equal(right[far_left], 0.0)
        np.testing.assert_array_equal(left[far_right], 0.0)
    w = S.split_weights(co, falloff=0.0)
    np.testing.assert_array_equal(w[co[:, 0] == 0], 0.5)
    # smooth: monotone in x and symmetric (w_L(x) = w_R(−x)) for a symmetric mesh
    w = S.split_weights(co, falloff=0.3)
    m = S.position_map(co)
    np.testing.assert_allclose(w[m.mirror], 1 - w, atol=1e-12)


def test_split_then_mirror_swaps_halves():
    co, *_ = grid_mesh()
    m = S.position_map(co)
    rng = np.random.default_rng(2)
    sym = S.symmetrize_delta(rng.normal(size=co.shape), m, co).value     # a symmetric shape
    left, right = S.split_delta(sym, S.split_weights(co, falloff=0.2))
    np.testing.assert_allclose(S.mirror_delta(left, m).value, right, atol=1e-12)


def test_symmetrize_pushes_one_side():
    co, *_, mirror = grid_mesh()
    m = S.position_map(co)
    rng = np.random.default_rng(4)
    delta = rng.normal(size=co.shape)
    out = S.symmetrize_delta(delta, m, co, source="LEFT").value
    left = co[:, 0] > 0
    np.testing.assert_array_equal(out[left], delta[left])
    np.testing.assert_allclose(S.mirror_delta(out, m).value, out, atol=1e-12)    # the result is symmetric
    out_r = S.symmetrize_delta(delta, m, co, source="RIGHT").value
    right = co[:, 0] < 0
    np.testing.assert_array_equal(out_r[right], delta[right])


def test_stale_map_and_bad_inputs_refused():
    co, *_ = grid_mesh()
    m = S.position_map(co)
    with pytest.raises(ShapeSpaceError) as e:
        S.mirror_delta(np.zeros((len(co) + 1, 3)), m)
    assert e.value.code == "stale_mirror_map"
    with pytest.raises(ShapeSpaceError):
        S.position_map(co, axis="W")
    with pytest.raises(ShapeSpaceError):
        S.position_map(np.full((3, 3), np.nan))
    with pytest.raises(ShapeSpaceError):
        S.split_delta(np.zeros((3, 3)), [0.0, 2.0, 0.5])


def test_empty_mesh():
    m = S.position_map(np.zeros((0, 3)))
    assert m.coverage == 1.0 and m.mirror.shape == (0,)


def test_fingerprint_changes_with_topology():
    co, loops, starts, totals, *_ = grid_mesh()
    edges = np.array([[0, 1], [1, 2]])
    a = S.topology_fingerprint(3, edges, 1)
    assert a == S.topology_fingerprint(3, edges.copy(), 1)
    assert a != S.topology_fingerprint(3, edges[::-1], 1)
    assert a != S.topology_fingerprint(4, edges, 1)
    assert set(a) == {"vertices", "edges", "faces", "edge_hash"}


@pytest.mark.parametrize("name,other", [
    ("browDown_L", "browDown_R"), ("eyeBlinkLeft", "eyeBlinkRight"), ("EyeBlinkRight", "EyeBlinkLeft"),
    ("brow.L", "brow.R"), ("L_brow", "R_brow"), ("jawLeft", "jawRight"), ("cheek_l.001", "cheek_r.001"),
    ("jawOpen", None), ("Curl", None), ("L", None)])
def test_counterpart_names(name, other):
    assert S.counterpart_name(name) == other
    if other is not None:
        assert S.counterpart_name(other) == name


def test_split_and_whole_names():
    assert S.side_names("jawOpen") == ("jawOpen_L", "jawOpen_R")
    assert S.whole_name("jawOpen_L") == "jawOpen"
    assert S.whole_name("eyeBlinkLeft") == "eyeBlink"
    assert S.whole_name("jawOpen") is None
