"""Transfer v2 (issue #22): facial parts, contact across openings, per-key checks — against known answers.

Every expected value is built here: rigid motions from SciPy's Rotation, spheres of known centre and radius,
contours whose gaps are known by construction.  Each check of ``core.authoring.quality`` has a case that
makes it fail and one that passes.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.authoring import contacts, landmarks_from_indices, parts, quality, register
from core.authoring.transfer import Transfer
from core.result import ShapeSpaceError, Status


def _sphere(n_lat=16, n_lon=24, r=1.0, centre=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0), nose=False):
    """UV sphere (poles at ±y): vertices (n, 3), triangles (f, 3); vertex ``1 + i·n_lon + j`` is on latitude ring
    ``i`` at longitude ``j`` (x = sin, z = cos).  ``nose``: a bump at +z and a chin, so that x is the only mirror."""
    lat = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    th, ph = np.meshgrid(lat, lon, indexing="ij")
    d = np.stack([np.sin(th) * np.sin(ph), np.cos(th), np.sin(th) * np.cos(ph)], axis=-1).reshape(-1, 3)
    d = np.vstack([[0, 1, 0], d, [0, -1, 0]])
    if nose:
        d = d * (1.0 + 0.3 * np.exp(-np.sum((d - [0, 0, 1]) ** 2, axis=1) / 0.05)
                 + 0.2 * np.exp(-np.sum((d - [0, -0.8, 0.6]) ** 2, axis=1) / 0.08))[:, None]
    V = d * r * np.asarray(scale) + centre
    ring = lambda i: 1 + i * n_lon  # noqa: E731
    T = [[0, ring(0) + (j + 1) % n_lon, ring(0) + j] for j in range(n_lon)]
    for i in range(n_lat - 2):
        for j in range(n_lon):
            a, b = ring(i) + j, ring(i) + (j + 1) % n_lon
            c, e = ring(i + 1) + j, ring(i + 1) + (j + 1) % n_lon
            T += [[a, b, e], [a, e, c]]
    last = len(V) - 1
    T += [[last, ring(n_lat - 2) + j, ring(n_lat - 2) + (j + 1) % n_lon] for j in range(n_lon)]
    return V, np.array(T, dtype=np.int64)


def _assemble(*meshes):
    Vs, Ts, off = [], [], 0
    for V, T in meshes:
        Vs.append(V)
        Ts.append(T + off)
        off += len(V)
    return np.vstack(Vs), np.vstack(Ts)


@pytest.fixture(scope="module")
def face():
    """Skin (radius 1), a left eyeball just under the skin, a thin lash patch on the skin, lower and upper
    'teeth' deep inside; the jaw motion: the front skin below y = −0.3 turned 15° about x through (0, 0, −0.3)."""
    skin = _sphere(20, 32, nose=True)
    eye = _sphere(8, 12, r=0.12, centre=(0.35, 0.3, 0.75))
    n = np.array([0.35, 0.5, 0.8]) / np.linalg.norm([0.35, 0.5, 0.8])
    cap = skin[1][np.all(np.linalg.norm(skin[0][skin[1]] - n, axis=2) < 0.2, axis=1)]   # a patch 0.3 % above
    used, inv = np.unique(cap, return_inverse=True)
    lash = (skin[0][used] * 1.003, inv.reshape(-1, 3))
    lower = _sphere(4, 8, r=0.1, centre=(0.0, -0.55, 0.45), scale=(1.0, 0.4, 0.6))
    upper = _sphere(4, 8, r=0.1, centre=(0.0, 0.05, 0.6), scale=(1.0, 0.4, 0.6))
    V, T = _assemble(skin, eye, lash, lower, upper)
    lab, _ = parts.triangle_parts(len(V), T)
    lash_part = int(lab[len(skin[0]) + len(eye[0])])
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    jaw = np.zeros_like(V)
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw[chin] = (V[chin] - pivot) @ rot.T + pivot - V[chin]
    return V, T, lab, jaw, rot, pivot, lash_part


def _part_of(V, lab, point):
    return int(lab[np.argmin(np.linalg.norm(V - point, axis=1))])


def test_sphere_fit_recovers_centre_and_radius():
    V, _ = _sphere(10, 14, r=0.3, centre=(1.0, -2.0, 0.5))
    c, r, res = parts.sphere_fit(V)
    assert np.allclose(c, [1.0, -2.0, 0.5], atol=1e-9) and abs(r - 0.3) < 1e-9 and res < 1e-9


def test_fit_rigid_recovers_a_known_motion():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(40, 3))
    R = Rotation.random(random_state=4).as_matrix()
    t = np.array([0.3, -1.0, 2.0])
    Rf, tf = parts.fit_rigid(X, X @ R.T + t, rng.uniform(0.1, 1.0, 40))
    assert np.abs(Rf - R).max() < 1e-10 and np.abs(tf - t).max() < 1e-10


def test_proposal_classifies_eye_lash_jaw_and_skull_parts(face):
    V, T, lab, jaw, _, _, lash = face
    plan = parts.propose_parts(V, T, lab, None, jaw)
    kinds = {name: plan.kinds[_part_of(V, lab, p)] for name, p in
             (("eye", (0.35, 0.3, 0.87)), ("lower", (0.0, -0.55, 0.45)), ("upper", (0.0, 0.05, 0.6)))}
    assert kinds == {"eye": "eye", "lower": "jaw", "upper": "skull"}
    assert plan.kinds[lash] == "follow" and plan.kinds[0] == "skin"
    assert all(0.0 < c <= 1.0 for c in plan.confidence.values())
    changed = plan.with_kinds({lash: "still"})
    assert changed.kinds[lash] == "still" and changed.confidence[lash] == 1.0
    with pytest.raises(ShapeSpaceError, match="kind 'bone' is not one of"):
        plan.with_kinds({1: "bone"})
    with pytest.raises(ShapeSpaceError, match="part 99 does not exist"):
        plan.with_kinds({99: "still"})


def test_jaw_parts_take_the_jaw_rotation_eyes_turn_lashes_follow(face):
    V, T, lab, jaw, rot, pivot, lash_part = face
    plan = parts.propose_parts(V, T, lab, None, jaw)
    lift = np.zeros_like(V)
    lift[(lab == 0) & (V[:, 2] > 0.3)] = [0.0, 0.02, 0.0]              # a uniform lift of the face
    D = np.stack([jaw, lift, np.zeros_like(V)])
    names = ["jawOpen", "browInnerUp", "eyeLookUp_L"]
    out, moved = parts.move_parts(plan, V, T, D.copy(), names)
    lower = lab == _part_of(V, lab, (0.0, -0.55, 0.45))
    expect = (V[lower] - pivot) @ rot.T + pivot - V[lower]
    assert np.abs(out[0, lower] - expect).max() < 1e-9
    upper = lab == _part_of(V, lab, (0.0, 0.05, 0.6))
    assert not out[:, upper].any()
    lash = lab == lash_part
    assert np.abs(out[1, lash] - [0.0, 0.02, 0.0]).max() < 0.02 * 0.02       # bound to the skin (w > 0.98)
    eye = lab == _part_of(V, lab, (0.35, 0.3, 0.87))
    c = np.array([0.35, 0.3, 0.75])
    before, after = V[eye] - c, V[eye] + out[2, eye] - c
    assert np.allclose(np.linalg.norm(after, axis=1), np.linalg.norm(before, axis=1), atol=1e-9)
    front = np.argmax(before[:, 2])                                    # the pupil turns up by the convention angle
    ang = np.degrees(np.arccos(np.clip(before[front] @ after[front] / 0.12 ** 2, -1, 1)))
    assert abs(ang - parts.EYE_LOOK_DEGREES["Up"]) < 1e-6 and after[front, 1] > before[front, 1]
    assert moved[int(lab[eye][0])] > 0 and not out[0, eye].any()


def _row(n_lon, ring, js):
    """Vertices of latitude ring ``ring`` at longitudes ``js`` (see :func:`_sphere`)."""
    return 1 + ring * n_lon + np.asarray(js)


def test_facing_pairs_and_closures_match_the_construction():
    V = np.array([[0, 1, 0], [1, 1, 0], [2, 1, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    pairs, t = contacts.facing_pairs(V, [0, 1, 2], [3, 4, 5])
    assert pairs.tolist() == [[0, 3], [1, 4], [2, 5]] and np.allclose(t, [0, 0.5, 1])
    D = np.zeros((2, 6, 3))
    D[0, [0, 1, 2], 1] = -1.0                # closes
    D[1, [0, 1, 2], 1] = 0.5                 # opens by half
    o = contacts.Opening("eye_L", pairs, t, pairs, t)
    assert np.allclose(contacts.closures([o], V, D), [[1, 1, 1], [-0.5, -0.5, -0.5]])
    assert np.allclose(contacts.gap_fractions(V, D, pairs), [[0, 0, 0], [1.5, 1.5, 1.5]])


def test_contact_rows_close_the_targets_own_gap():
    """Source lids two rows apart close fully; the target's lids are four rows apart.  Plain deformation
    transfer moves the upper row by the source's (smaller) gap and leaves the target's open; with the
    opening the target closes over its own gap."""
    V, T = _sphere(24, 40)
    lm = np.array([int(np.argmin(np.linalg.norm(V - g, axis=1))) for g in
                   ([0, 0, 1], [0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, -1], [0.5, 0.5, 0.7])])
    reg = register(V, T, V, T, landmarks_from_indices(V, V, lm, lm)).value
    up, lo_s, lo_t = _row(40, 6, range(1, 6)), _row(40, 8, range(1, 6)), _row(40, 10, range(1, 6))
    w = np.exp(-np.sum((V - V[up].mean(axis=0)) ** 2, axis=1) / 0.02)
    D = np.zeros((1,) + V.shape)
    D[0] = w[:, None] * (V[lo_s].mean(axis=0) - V[up].mean(axis=0))
    meet, _ = contacts.facing_pairs(V, up, lo_s)
    D[0, meet[:, 0]] = V[meet[:, 1]] - V[meet[:, 0]]                    # the source's lids meet
    D[0, lo_s] = 0.0
    o = contacts.opening("eye_L", V, up, lo_s, V, up, lo_t)
    assert np.abs(contacts.closures([o], V, D)).min() > 0.99
    plain = Transfer(V, T, V, T, reg).solve(D)
    closed = Transfer(V, T, V, T, reg, openings=[o]).solve(D)
    g_plain = contacts.gap_fractions(V, plain, o.target_pairs)
    g_closed = contacts.gap_fractions(V, closed, o.target_pairs)
    assert g_plain.min() > 0.3 and np.abs(g_closed).max() < 0.05


def _mirror_pair(V, right):
    """Mirror (x → −x) of a right-side delta as the left one."""
    _, m = quality.cKDTree(V).query(V * [-1, 1, 1])
    return right[m] * [-1, 1, 1]


def test_each_check_fails_on_its_defect_and_passes_without():
    V, T = _sphere(20, 32, nose=True)
    up, lo = _row(32, 5, range(1, 5)), _row(32, 7, range(1, 5))
    upR, loR = _row(32, 5, range(31, 27, -1)), _row(32, 7, range(31, 27, -1))
    oL, oR = contacts.opening("eye_L", V, up, lo, V, up, lo), contacts.opening("eye_R", V, upR, loR, V, upR, loR)
    blinkR = np.zeros_like(V)
    meet, _ = contacts.facing_pairs(V, upR, loR)
    blinkR[meet[:, 0]] = V[meet[:, 1]] - V[meet[:, 0]]
    blinkL = _mirror_pair(V, blinkR)
    good = np.stack([blinkL, blinkR])
    names = ["eyeBlink_L", "eyeBlink_R"]
    keys, issues, status = quality.check_keys(V, good, names, V, good, openings=[oL, oR])
    assert status == Status.OK and not issues and keys[0]["gap_left"] < 1e-9 and keys[0]["asymmetry"] < 1e-9
    half = good.copy()
    half[0] *= 0.5                                                      # left blink stops half way
    keys, issues, status = quality.check_keys(V, good, names, V, half, openings=[oL, oR])
    assert status == Status.WARNING and "gap" in keys[0]["failed"] and "symmetry" in keys[0]["failed"]
    assert any("eyeBlink_L" in i.message and "50 % of the lid gap" in i.message for i in issues)
    over = good.copy()
    over[1] *= 1.6                                                      # right lid passes through the lower
    keys, _, status = quality.check_keys(V, good, names, V, over, openings=[oL, oR])
    assert status == Status.WARNING and "crossing" in keys[1]["failed"] and keys[1]["crossings"] == upR.size
    big = good * 10.0
    keys, issues, _ = quality.check_keys(V, good, names, V, big)
    assert "size" in keys[0]["failed"] and "10.00×" in issues[0].message


def test_shut_lips_are_classified_and_not_carried():
    """Lips that touch at rest on either head make an 'offset' opening (no gap to take a fraction of), with the
    contours' length ratio as its scale; the transfer carries only the openings open at rest."""
    x = np.linspace(0.0, 1.0, 5)
    S = np.r_[np.c_[x, np.zeros(5), np.zeros(5)], np.c_[x, np.zeros(5), np.zeros(5)]]       # shut: rows coincide
    T = np.r_[np.c_[2 * x, np.full(5, 0.3), np.zeros(5)], np.c_[2 * x, np.zeros(5), np.zeros(5)]]
    lips = contacts.opening("mouth", S, range(5), range(5, 10), T, range(5), range(5, 10))
    eyes = contacts.opening("eye_L", T, range(5), range(5, 10), T, range(5), range(5, 10))
    assert lips.mode == "offset" and abs(lips.scale - 2.0) < 1e-12 and eyes.mode == "ratio"
    assert contacts.carried([lips, eyes]) == [eyes]


def test_lips_check_fails_when_the_target_opens_lips_the_source_keeps_shut():
    x = np.linspace(0.0, 1.0, 5)
    S = np.r_[np.c_[x, np.zeros(5), np.zeros(5)], np.c_[x, np.zeros(5), np.zeros(5)]]
    o = contacts.opening("mouth", S, range(5), range(5, 10), S, range(5), range(5, 10))
    D = np.zeros((2, 10, 3))
    D[:, :, 2] = 0.05                                  # both lips pushed forward together: still meeting
    T = D.copy()
    T[1, 5:, 1] = -0.1                                 # the transfer drops the lower lip of the second key
    keys, issues, status = quality.check_keys(S, D, ["mouthPucker", "mouthFunnel"], S, T, openings=[o])
    assert keys[0]["lips_meet"] and not keys[0]["failed"]
    assert not keys[1]["lips_meet"] and keys[1]["failed"] == ["lips"] and status == Status.WARNING
    assert "mouthFunnel: leaves the lips apart" in issues[0].message


def test_a_source_whose_lids_cross_makes_the_targets_meet_not_cross():
    V = np.array([[0, 1, 0], [1, 1, 0], [2, 1, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    pairs, t = contacts.facing_pairs(V, [0, 1, 2], [3, 4, 5])
    o = contacts.Opening("eye_L", pairs, t, pairs, t)
    D = np.zeros((1, 6, 3))
    D[0, [0, 1, 2], 1] = -1.3                                # the source's upper lid passes the lower by 30 %
    assert np.allclose(contacts.closures([o], V, D), 1.3)
    assert np.allclose(contacts.gap_changes([o], V, D, V)[0], [[0, -1, 0]] * 3)


def test_closures_are_measured_against_the_sources_own_blink():
    """A source whose blink shuts its lid contour to a third of the gap only (the contour sits off where its
    lids meet): against that blink, the blink is a full closure and a half-way shape two thirds of it."""
    V = np.array([[0, 1, 0], [1, 1, 0], [2, 1, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    pairs, t = contacts.facing_pairs(V, [0, 1, 2], [3, 4, 5])
    o = contacts.Opening("eye_L", pairs, t, pairs, t)
    D = np.zeros((2, 6, 3))
    D[0, [0, 1, 2], 1] = -2.0 / 3.0                          # eyeBlinkLeft: a third of the gap left
    D[1, [0, 1, 2], 1] = -1.0 / 3.0
    (ref,) = contacts.with_references([o], V, D, ["eyeBlink_L", "eyeSquint_L"])
    assert np.allclose(ref.reference, 2.0 / 3.0)
    assert np.allclose(contacts.closures([ref], V, D), [[1.0] * 3, [0.5] * 3])
    assert contacts.with_references([o], V, D, ["jawOpen", "eyeSquint_L"])[0].reference is None


def test_parts_are_named_by_their_lowest_vertex_and_set_by_any_vertex(face):
    V, T, lab, jaw, _, _, lash = face
    plan = parts.propose_parts(V, T, lab, None, jaw)
    firsts = {s["part"]: s["first"] for s in plan.summary()}
    for p, v in firsts.items():                                      # the lowest index of each part
        assert v == int(np.flatnonzero(lab == p)[0])
    eye = _part_of(V, lab, (0.35, 0.3, 0.87))
    some = int(np.flatnonzero(lab == eye)[5])                         # any vertex of the eye names it
    set_ = plan.with_vertex_kinds({some: ("still", "moved by its rig: grp_eye is animated"),
                                   firsts[lash]: ("jaw", "set by the user")})
    assert set_.kinds[eye] == "still" and set_.reasons[eye].startswith("moved by its rig")
    assert set_.kinds[lash] == "jaw" and set_.confidence[lash] == 1.0 and plan.kinds[eye] == "eye"
    with pytest.raises(ShapeSpaceError, match="vertex 0: that vertex is the skin"):
        plan.with_vertex_kinds({0: ("still", "")})
    with pytest.raises(ShapeSpaceError, match=f"vertex {len(V)}: the target has {len(V)} vertices"):
        plan.with_vertex_kinds({len(V): ("still", "")})
    with pytest.raises(ShapeSpaceError, match="kind 'source' is not one of"):
        plan.with_vertex_kinds({some: ("source", "")})
    other = int(np.flatnonzero(lab == eye)[7])
    with pytest.raises(ShapeSpaceError, match="is given 'still' and 'eye'|is given 'eye' and 'still'"):
        plan.with_vertex_kinds({some: ("eye", ""), other: ("still", "")})


def test_a_part_set_still_stays_still_in_every_shape_moved_as_rigged_or_not(face):
    V, T, lab, jaw, _, _, _ = face
    eye = _part_of(V, lab, (0.35, 0.3, 0.87))
    v = int(np.flatnonzero(lab == eye)[0])
    plan = parts.propose_parts(V, T, lab, None, jaw).with_vertex_kinds({v: ("still", "moved by its rig")})
    D = np.stack([jaw, np.zeros_like(V)])
    out, moved = parts.move_parts(plan, V, T, D.copy(), ["jawOpen", "eyeLookUp_L"])
    assert not out[:, lab == eye].any() and moved.get(eye, 0.0) == 0.0
    mask = parts.still_vertices(len(V), T, {v: ("still", ""), 0: ("still", ""), int(np.flatnonzero(lab == 0)[0]):
                                            ("follow", "")})
    np.testing.assert_array_equal(mask, lab == eye)                  # the skin is never held still
