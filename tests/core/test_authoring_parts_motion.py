"""Facial parts (issue #22 §1): the jaw's rigid motion only in the jaw's shapes, teeth as solids even where they
lie close to the lips, and eyes turned about their own vertical axis — against motions built here."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.authoring import parts
from test_authoring_parts import _assemble, _part_of, _sphere


def _eye(centre, r=0.12):
    """An eyeball as Ready Player Me models it: the front of a sphere (z > −r/2), looking along +z."""
    V, T = _sphere(8, 12)
    T = T[np.all(V[T][:, :, 2] > -0.5, axis=1)]
    used, inv = np.unique(T, return_inverse=True)
    return V[used] * r + centre, inv.reshape(-1, 3)


@pytest.fixture(scope="module")
def head():
    """Skin (radius 1), a left eye, lower teeth close behind the lower lip (a solid), upper teeth deep inside;
    ``jawOpen`` turns the front skin below y = −0.3 by 15° about x through (0, 0, −0.3) — the chin drops and
    goes back, so the chin's drop is 36° off the vertical."""
    skin = _sphere(20, 32, nose=True)
    eye = _eye((0.35, 0.3, 0.75))
    lower = _sphere(4, 8, r=0.1, centre=(0.0, -0.63, 0.83), scale=(1.0, 0.4, 0.15))
    upper = _sphere(4, 8, r=0.1, centre=(0.0, 0.05, 0.6), scale=(1.0, 0.4, 0.6))
    V, T = _assemble(skin, eye, lower, upper)
    lab, _ = parts.triangle_parts(len(V), T)
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    jaw = np.zeros_like(V)
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw[chin] = (V[chin] - pivot) @ rot.T + pivot - V[chin]
    return V, T, lab, jaw, rot, pivot


def test_teeth_close_to_the_lips_are_a_solid_of_the_jaw(head):
    V, T, lab, jaw, _, _ = head
    lower = _part_of(V, lab, (0.0, -0.63, 0.83))
    _, _, _, dist = parts._Skin(V, T, lab).closest(V[lab == lower])
    assert np.median(dist) < parts.FOLLOW_MEDIAN * parts.bbox_diagonal(V)      # as close as a lash would be
    plan = parts.propose_parts(V, T, lab, None, jaw)
    assert plan.kinds[lower] == "jaw" and plan.kinds[_part_of(V, lab, (0.0, 0.05, 0.6))] == "skull"


def test_lip_shapes_leave_the_jaw_still_jaw_shapes_move_it_rigidly(head):
    V, T, lab, jaw, rot, pivot = head
    plan = parts.propose_parts(V, T, lab, None, jaw)
    lip = np.zeros_like(V)
    lip[(lab == 0) & (V[:, 1] < -0.3) & (V[:, 1] > -0.45) & (V[:, 2] > 0.5)] = [0.0, 0.05, 0.0]   # lower lip up
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, lip]), ["jawOpen", "mouthClose"])
    lower = lab == _part_of(V, lab, (0.0, -0.63, 0.83))
    assert np.abs(out[0, lower] - ((V[lower] - pivot) @ rot.T + pivot - V[lower])).max() < 1e-9
    assert not out[1, lower].any()                     # mouthClose closes the lips over a still jaw


@pytest.mark.parametrize("name, toward_left", [("eyeLookInLeft", False), ("eyeLookOutLeft", True)])
def test_eyes_turn_about_their_own_vertical_axis(head, name, toward_left):
    V, T, lab, jaw, _, _ = head
    plan = parts.propose_parts(V, T, lab, None, jaw)
    eye = lab == _part_of(V, lab, (0.35, 0.3, 0.75))
    assert plan.kinds[int(lab[eye][0])] == "eye"
    out, _ = parts.move_parts(plan, V, T, np.zeros((1,) + V.shape), [name])
    c, _, _ = parts.sphere_fit(V[eye])
    before, after = V[eye] - c, V[eye] + out[0, eye] - c
    assert np.abs(after[:, 1] - before[:, 1]).max() < 1e-9          # turned about the vertical (y) axis
    front = np.argmax(before[:, 2])
    ang = np.degrees(np.arctan2(after[front, 0], after[front, 2]) - np.arctan2(before[front, 0], before[front, 2]))
    want = parts.EYE_LOOK_DEGREES["Out" if toward_left else "In"] * (1 if toward_left else -1)
    assert abs(ang - want) < 1e-6


def test_teeth_rows_split_by_height_where_the_sector_misjudges_them(head):
    """Two lower teeth above the chin's lip line (out of the jaw's sector, as Face Cap's) and two upper teeth
    above them: the lower row goes with the jaw, the upper with the skull."""
    V0, T0, _, _, _, _ = head
    skin_eye = int(np.flatnonzero(parts.triangle_parts(len(V0), T0)[0] >= 2)[0])    # skin and eye come first
    meshes = [(V0[:skin_eye], T0[np.all(T0 < skin_eye, axis=1)])]
    rows = {"lower": -0.25, "upper": 0.05}
    for y in rows.values():
        for x in (-0.15, 0.15):
            meshes.append(_sphere(4, 8, r=0.06, centre=(x, y, 0.6), scale=(1.0, 0.4, 0.6)))
    V, T = _assemble(*meshes)
    lab, _ = parts.triangle_parts(len(V), T)
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    jaw = np.zeros_like(V)
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw[chin] = (V[chin] - pivot) @ rot.T + pivot - V[chin]
    plan = parts.propose_parts(V, T, lab, None, jaw)
    for name, y in rows.items():
        for x in (-0.15, 0.15):
            assert plan.kinds[_part_of(V, lab, (x, y, 0.6))] == {"lower": "jaw", "upper": "skull"}[name]


def test_a_source_part_is_the_same_part_only_at_a_similar_extent(head):
    """The registration matched the target's lower teeth to a source part of the same kind: its motion is
    transferred when the source part is the same size, not when it is three times larger (a tongue, a cavity)."""
    V, T, lab, jaw, _, _ = head
    lower = _part_of(V, lab, (0.0, -0.63, 0.83))
    src = parts.propose_parts(V, T, lab, None, jaw)
    assert parts.propose_parts(V, T, lab, {lower: lower}, jaw, src, [lower]).kinds[lower] == "source"
    big = V.copy()
    c = V[lab == lower].mean(axis=0)
    big[lab == lower] = c + 3.0 * (V[lab == lower] - c)
    src_big = parts.propose_parts(big, T, lab, None, jaw)
    assert src_big.kinds[lower] == "jaw"
    assert parts.propose_parts(V, T, lab, {lower: lower}, jaw, src_big, [lower]).kinds[lower] == "jaw"


def test_a_sheet_of_upper_teeth_behind_the_lips_follows_the_upper_lip_not_the_jaw(head):
    """Teeth modelled as open sheets just behind the lips (Ready Player Me's) lie on the skin like a lash: the
    upper row is not carried by the jaw (in ``jawOpen`` it moves far less than the skin in front of it) and
    goes with the upper lip in a lip shape (Ready Player Me's artist moves it in ``mouthFunnel``)."""
    V0, T0, _, _, _, _ = head
    skin_eye = int(np.flatnonzero(parts.triangle_parts(len(V0), T0)[0] >= 2)[0])
    skin = (V0[:skin_eye], T0[np.all(T0 < skin_eye, axis=1)])
    n = np.array([0.0, -0.34, 0.94]) / np.linalg.norm([0.0, -0.34, 0.94])
    cap = skin[1][np.all(np.linalg.norm(skin[0][skin[1]] / np.linalg.norm(skin[0][skin[1]], axis=2,
                                                                          keepdims=True) - n, axis=2) < 0.25, axis=1)]
    used, inv = np.unique(cap, return_inverse=True)
    sheet = (skin[0][used] * 0.997, inv.reshape(-1, 3))
    lowers = [_sphere(4, 8, r=0.1, centre=(x, -0.63, 0.7), scale=(1.0, 0.4, 0.3)) for x in (-0.12, 0.12)]
    upper = _sphere(4, 8, r=0.1, centre=(0.0, -0.36, 0.6), scale=(1.0, 0.4, 0.6))
    V, T = _assemble(skin, sheet, *lowers, upper)
    lab, _ = parts.triangle_parts(len(V), T)
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    jaw = np.zeros_like(V)
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw[chin] = (V[chin] - pivot) @ rot.T + pivot - V[chin]
    plan = parts.propose_parts(V, T, lab, None, jaw)
    s = int(lab[len(skin[0])])                                   # the sheet follows skin and eye
    assert "lies behind the upper lip" in plan.reasons[s] and plan.kinds[s] == "follow"
    assert all(plan.kinds[_part_of(V, lab, (x, -0.63, 0.7))] == "jaw" for x in (-0.12, 0.12))
    lip = np.zeros_like(V)
    upper_lip = (lab == 0) & (V[:, 1] > -0.3) & (V[:, 2] > 0.5)
    lip[upper_lip] = [0.0, 0.0, 0.05]                                  # the upper lip pushed forward
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, lip]), ["jawOpen", "mouthFunnel"])
    sheet = np.flatnonzero(lab == s)
    top = sheet[np.argmax(V[sheet, 1])]                                 # the sheet's vertex on the upper lip
    assert out[1, top, 2] > 0.9 * 0.05 and np.abs(out[1, top, :2]).max() < 0.1 * 0.05
    assert np.linalg.norm(out[0, sheet], axis=1).max() < 0.1 * np.linalg.norm(jaw[lab == 0], axis=1).max()


def _cavity_head():
    """Skin (radius 1) and a mouth cavity: the back of a sphere of radius 0.25 whose open rim reaches the lips
    (an open bag touching the skin, on the mirror plane)."""
    skin = _sphere(20, 32, nose=True)
    V, T = _sphere(8, 12, r=0.25, centre=(0.0, -0.45, 0.72))
    T = T[np.all(V[T][:, :, 2] < 0.85, axis=1)]
    used, inv = np.unique(T, return_inverse=True)
    V, T = _assemble(skin, (V[used], inv.reshape(-1, 3)))
    lab, _ = parts.triangle_parts(len(V), T)
    return V, T, lab, _part_of(V, lab, (0.0, -0.45, 0.47))


@pytest.mark.parametrize("kind, reason, extent, same", [
    ("jaw", "inside, in the lower row (moves with the jaw)", 0.16, True),      # Face Cap: a closed bag
    ("follow", "touches the skin", 0.2, True),                                  # an open bag like the target's
    ("follow", "lies on the skin", 0.16, False),                                # a sheet of teeth (Ready Player Me)
    ("jaw", "inside, in the lower row (moves with the jaw)", 0.04, False)])     # a tongue: too small
def test_a_mouth_cavity_takes_the_source_cavitys_motion_open_or_closed(kind, reason, extent, same):
    V, T, lab, cav = _cavity_head()
    plan = parts.propose_parts(V, T, lab)
    assert plan.kinds[cav] == "follow" and plan.reasons[cav] == "touches the skin"
    ext = plan.extents[cav]
    assert 0.1 < ext < 0.3
    source = parts.PartPlan(np.zeros(1, int), {0: "skin", 5: kind}, {0: 1.0, 5: 1.0}, {0: "", 5: reason},
                            extents={5: extent})
    out = parts.propose_parts(V, T, lab, {cav: 5}, None, source, [5])
    assert (out.kinds[cav] == "source") == same


def test_a_mouth_cavity_holding_the_teeth_opens_its_floor_with_the_jaw_and_keeps_its_roof():
    """A mouth bag (open at the lips, holding lower teeth near its floor and upper teeth near its roof) in a
    ``jawOpen`` that turns the chin 15°: the floor beside the lower teeth goes with the jaw's rotation, the roof
    beside the upper teeth stays (the skin nearest both is the moving chin's)."""
    skin = _sphere(20, 32, nose=True)
    B, BT = _sphere(10, 16, r=0.32, centre=(0.0, -0.35, 0.68))
    BT = BT[np.all(np.linalg.norm(B[BT], axis=2) < 1.05, axis=1)]            # cut open where it meets the skin
    used, inv = np.unique(BT, return_inverse=True)
    lower = _sphere(4, 8, r=0.1, centre=(0.0, -0.55, 0.6), scale=(1.0, 0.4, 0.6))
    upper = _sphere(4, 8, r=0.1, centre=(0.0, -0.15, 0.6), scale=(1.0, 0.4, 0.6))
    V, T = _assemble(skin, (B[used], inv.reshape(-1, 3)), lower, upper)
    lab, _ = parts.triangle_parts(len(V), T)
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    turned = (V - pivot) @ rot.T + pivot - V
    jaw = np.where(((lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0))[:, None], turned, 0.0)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    cav = _part_of(V, lab, (0.0, -0.35, 0.36))
    assert plan.kinds[cav] == "follow" and plan.reasons[cav] == "touches the skin"
    out, _ = parts.move_parts(plan, V, T, jaw[None].copy(), ["jawOpen"])
    bag = np.flatnonzero(lab == cav)
    floor = bag[np.argmin(np.linalg.norm(V[bag] - (0.0, -0.65, 0.6), axis=1))]
    roof = bag[np.argmin(np.linalg.norm(V[bag] - (0.0, -0.05, 0.6), axis=1))]
    assert np.linalg.norm(out[0, floor] - turned[floor]) < 0.2 * np.linalg.norm(turned[floor])
    assert np.linalg.norm(out[0, roof]) < 0.2 * np.linalg.norm(turned[roof])


def test_a_lip_shape_leaves_the_mouth_cavity_still_even_where_it_touches_the_lips():
    """A lip shape (the skin pushed forward, no jaw) leaves the mouth cavity still, its rim on the lips too,
    and a jaw shape opens it: every shared head's artist skins the cavity to the jaw and the skull (ICT FaceKit,
    Ready Player Me, Face Cap: 0.00 of the lips' motion on the cavity in every lip shape, vertices 4·10⁻⁸ of
    the diagonal from the lip included; the whole jaw's motion in ``jawOpen``)."""
    V, T, lab, cav = _cavity_head()
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw = np.where(chin[:, None], (V - pivot) @ rot.T + pivot - V, 0.0)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    assert parts._is_cavity(plan, cav)
    lip = np.where(((lab == 0) & (V[:, 2] > 0.5))[:, None], [0.0, 0.0, 0.05], 0.0)
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, lip]), ["jawOpen", "mouthFunnel"])
    bag = np.flatnonzero(lab == cav)
    _, _, _, dist = parts._Skin(V, T, lab).closest(V[bag])
    assert (dist < parts.TOUCH * parts.bbox_diagonal(V)).any()            # the rim touches the lips
    assert not out[1, bag].any()
    low = bag[V[bag, 1] < -0.5]                                            # the cavity's floor, over the chin
    turned = (V[low] - pivot) @ rot.T + pivot - V[low]
    assert np.linalg.norm(out[0, low] - turned, axis=1).max() < 0.5 * np.linalg.norm(turned, axis=1).min()


def _arch(y, n=24, centre=(0.0, 0.55), radius=0.2, width=0.05, height=0.08, sweep=100.0):
    """A row of teeth in one piece (a CC/Daz-style arch): a closed tube of rectangular section (``width``
    radially, ``height`` along y) swept along a U in the horizontal plane at height ``y`` — the circle of
    ``radius`` about (x, z) = ``centre``, ``sweep`` degrees either side of +z (the front) — with end caps."""
    th = np.radians(np.linspace(-sweep, sweep, n))
    corners = [(radius - width / 2, y - height / 2), (radius + width / 2, y - height / 2),
               (radius + width / 2, y + height / 2), (radius - width / 2, y + height / 2)]
    V = np.array([[r * np.sin(t) + centre[0], h, r * np.cos(t) + centre[1]] for t in th for r, h in corners])
    T = []
    for i in range(n - 1):
        for c in range(4):
            a, b, a1, b1 = 4 * i + c, 4 * i + (c + 1) % 4, 4 * (i + 1) + c, 4 * (i + 1) + (c + 1) % 4
            T += [[a, b, b1], [a, b1, a1]]
    last = 4 * (n - 1)
    T += [[0, 2, 1], [0, 3, 2], [last, last + 1, last + 2], [last, last + 2, last + 3]]
    return V, np.array(T)


def _mouth(head, tongue=True, bag=False, arch=False):
    """The fixture's skin and eye with two lower and two upper teeth beside the mirror plane, and a tongue
    across the plane behind the lower teeth (or a closed mouth bag holding the teeth); ``arch``: the lower
    teeth in one piece (:func:`_arch`) around the tongue."""
    V0, T0, _, _, _, _ = head
    skin_eye = int(np.flatnonzero(parts.triangle_parts(len(V0), T0)[0] >= 2)[0])
    meshes = [(V0[:skin_eye], T0[np.all(T0 < skin_eye, axis=1)])]
    meshes += [_sphere(4, 8, r=0.06, centre=(x, y, 0.75), scale=(1.0, 0.4, 0.6)) for x in (-0.12, 0.12)
               for y in ((-0.2,) if arch else (-0.5, -0.2))]
    if arch:
        meshes.append(_arch(-0.5))
    if tongue:
        meshes.append(_sphere(6, 10, r=0.15, centre=(0.0, -0.42, 0.55), scale=(0.8, 0.25, 1.0)))
    if bag:
        meshes.append(_sphere(8, 12, r=0.32, centre=(0.0, -0.35, 0.6), scale=(1.0, 0.9, 0.9)))
    V, T = _assemble(*meshes)
    lab, _ = parts.triangle_parts(len(V), T)
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw = np.where(chin[:, None], (V - pivot) @ rot.T + pivot - V, 0.0)
    return V, T, lab, jaw


def test_the_tongue_goes_with_the_jaw_and_slides_out_in_tongue_out(head):
    """A solid of the lower row lying across the mirror plane is the tongue: it takes the jaw's rigid motion in
    ``jawOpen`` and slides forward (+z, perpendicular to the eyes' up) by :data:`TONGUE_OUT` of its depth in
    ``tongueOut``, where the teeth stay."""
    V, T, lab, jaw = _mouth(head)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    tongue = _part_of(V, lab, (0.0, -0.42, 0.4))
    assert plan.kinds[tongue] == "jaw" and plan.reasons[tongue] == parts.TONGUE
    teeth = [_part_of(V, lab, (x, -0.5, 0.75)) for x in (-0.12, 0.12)]
    assert all(plan.kinds[p] == "jaw" and plan.reasons[p] != parts.TONGUE for p in teeth)
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, np.zeros_like(V)]), ["jawOpen", "tongueOut"])
    on = lab == tongue
    depth = np.ptp(V[on, 2])
    assert np.allclose(out[1, on], [0.0, 0.0, parts.TONGUE_OUT * depth], atol=1e-6 * depth)
    assert not out[1, np.isin(lab, teeth)].any()
    R, _ = Rotation.align_vectors(out[0, on] + V[on] - (out[0, on] + V[on]).mean(axis=0),
                                  V[on] - V[on].mean(axis=0))
    assert abs(R.magnitude() - np.radians(15.0)) < 1e-6


@pytest.mark.parametrize("tongue", [True, False])
def test_lower_teeth_in_one_piece_are_no_tongue(head, tongue):
    """Lower teeth modelled as one arch (CC/Daz-style kits) lie across the mirror plane too, but they are a U
    around the mouth, not a blob behind the teeth: they stay teeth (the jaw's rigid motion only, still in
    ``tongueOut``), with the tongue inside them still the tongue."""
    V, T, lab, jaw = _mouth(head, tongue=tongue, arch=True)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    arch = _part_of(V, lab, (0.0, -0.5, 0.75))
    assert plan.kinds[arch] == "jaw" and plan.reasons[arch] != parts.TONGUE
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, np.zeros_like(V)]), ["jawOpen", "tongueOut"])
    assert not out[1, lab == arch].any()
    on = lab == arch
    R, _ = Rotation.align_vectors(out[0, on] + V[on] - (out[0, on] + V[on]).mean(axis=0),
                                  V[on] - V[on].mean(axis=0))
    assert abs(R.magnitude() - np.radians(15.0)) < 1e-6
    tongues = [p for p, r in plan.reasons.items() if r == parts.TONGUE]
    assert tongues == ([_part_of(V, lab, (0.0, -0.42, 0.4))] if tongue else [])


def test_tongue_out_goes_along_the_forward_the_caller_gives(head):
    """``move_parts(face_forward=…)`` slides the tongue along the given forward (perpendicular to the eyes'
    up), not the plan's own."""
    V, T, lab, jaw = _mouth(head)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    tongue = _part_of(V, lab, (0.0, -0.42, 0.4))
    fwd = np.array([0.6, 0.0, 0.8])
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, np.zeros_like(V)]), ["jawOpen", "tongueOut"],
                              face_forward=fwd)
    on = lab == tongue
    depth = np.ptp(V[on] @ fwd)
    assert np.allclose(out[1, on], parts.TONGUE_OUT * depth * fwd, atol=1e-6 * depth)


def test_a_mouth_bag_holding_the_teeth_is_no_tongue(head):
    V, T, lab, jaw = _mouth(head, tongue=False, bag=True)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    assert parts.TONGUE not in plan.reasons.values()


def test_a_sheet_of_lower_teeth_behind_the_lips_follows_the_lower_lip_not_the_upper(head):
    """Teeth modelled as open sheets behind the lips (Ready Player Me's): each row is bound to its own lip — the
    upper row to the skin that stays with the skull, the lower row to the skin the jaw moves (Ready Player Me's
    lower teeth in ``mouthClose``: up with the lower lip; its parts' share reproduced from ICT FaceKit 0.42 →
    0.48, bound to the nearest skin of either lip)."""
    V0, T0, _, _, _, _ = head
    skin_eye = int(np.flatnonzero(parts.triangle_parts(len(V0), T0)[0] >= 2)[0])
    skin = (V0[:skin_eye], T0[np.all(T0 < skin_eye, axis=1)])
    n = np.array([0.0, -0.5, 0.87]) / np.linalg.norm([0.0, -0.5, 0.87])     # behind the lower lip, reaching up
    sv = skin[0] / np.linalg.norm(skin[0], axis=1, keepdims=True)
    cap = skin[1][np.all(np.linalg.norm(sv[skin[1]] - n, axis=2) < 0.4, axis=1)]
    used, inv = np.unique(cap, return_inverse=True)
    lowers = [_sphere(4, 8, r=0.1, centre=(x, -0.63, 0.7), scale=(1.0, 0.4, 0.3)) for x in (-0.12, 0.12)]
    uppers = [_sphere(4, 8, r=0.1, centre=(x, 0.05, 0.6), scale=(1.0, 0.4, 0.6)) for x in (-0.12, 0.12)]
    V, T = _assemble(skin, (skin[0][used] * 0.997, inv.reshape(-1, 3)), *lowers, *uppers)
    lab, _ = parts.triangle_parts(len(V), T)
    rot = Rotation.from_euler("x", 15, degrees=True).as_matrix()
    pivot = np.array([0.0, 0.0, -0.3])
    chin = (lab == 0) & (V[:, 1] < -0.3) & (V[:, 2] > 0.0)
    jaw = np.where(chin[:, None], (V - pivot) @ rot.T + pivot - V, 0.0)
    plan = parts.propose_parts(V, T, lab, None, jaw)
    s = int(lab[len(skin[0])])
    assert plan.reasons[s] == parts.LOWER_SHEET and plan.kinds[s] == "follow"
    close = np.zeros_like(V)
    close[chin] = [0.0, 0.05, 0.0]                                       # the lower lip up, the upper still
    out, _ = parts.move_parts(plan, V, T, np.stack([jaw, close]), ["jawOpen", "mouthClose"])
    sheet = np.flatnonzero(lab == s)
    below = sheet[V[sheet, 1] < -0.35]                                    # behind the lower lip
    assert below.size and out[1, below, 1].min() > 0.5 * 0.05




def _sheet_grid(diag, bulge):
    """A sheet on the skin of ``_sphere(nose=True)`` over the brow (0.2 < y < 0.45, |x| ≤ 0.3), bulging inward
    by up to ``bulge`` × the diagonal in its middle row."""
    x, y = np.meshgrid(np.linspace(-0.3, 0.3, 13), np.linspace(0.2, 0.45, 11))
    d = np.stack([x, y, np.sqrt(1.0 - x ** 2 - y ** 2)], axis=-1).reshape(-1, 3)
    on_skin = 1.0 + 0.3 * np.exp(-np.sum((d - [0, 0, 1]) ** 2, axis=1) / 0.05) \
        + 0.2 * np.exp(-np.sum((d - [0, -0.8, 0.6]) ** 2, axis=1) / 0.08)      # _sphere(nose=True)'s radius
    V = d * (on_skin - bulge * diag * np.sin(np.pi * (d[:, 1] - 0.2) / 0.25))[:, None]
    i = np.arange(10 * 12).reshape(10, 12)
    i = (i // 12) * 13 + i % 12
    T = np.concatenate([np.stack([i, i + 1, i + 13], -1).reshape(-1, 3),
                        np.stack([i + 1, i + 14, i + 13], -1).reshape(-1, 3)])
    return V, T


def test_a_part_on_the_skin_moves_with_it_all_across_not_only_where_it_touches(head):
    """A part that follows the skin moves with the skin under it wherever it lies close: Ready Player Me's
    artist moves its whole sheet of upper teeth with the upper lip, 60–100 % of the lip's motion 1.5 % of the
    head's diagonal behind it and 25 % at 7 %.  A sheet over the brow bulging 1.6 % of the diagonal inward
    follows a brow raise by at least half of it wherever it lies within 1.5 % of the diagonal (the binding fell
    to a quarter at 1.2 %, to a tenth at 1.5 %), and nowhere by more than the brow."""
    V0, T0, _, _, _, _ = head
    skin_eye = int(np.flatnonzero(parts.triangle_parts(len(V0), T0)[0] >= 2)[0])
    skin = (V0[:skin_eye], T0[np.all(T0 < skin_eye, axis=1)])
    diag = parts.bbox_diagonal(V0)
    V, T = _assemble(skin, _sheet_grid(diag, 0.016))
    lab, _ = parts.triangle_parts(len(V), T)
    plan = parts.propose_parts(V, T, lab, None, None)
    s = int(lab[len(skin[0])])
    assert (plan.kinds[s], plan.reasons[s]) == ("follow", "lies on the skin")
    brow = np.zeros_like(V)
    brow[(lab == 0) & (V[:, 1] > 0.1) & (V[:, 2] > 0.5)] = [0.0, 0.05, 0.0]      # the brow raised
    out, _ = parts.move_parts(plan, V, T, brow[None], ["browInnerUp"])
    sheet = np.flatnonzero(lab == s)
    _, _, _, dist = parts._Skin(V, T, lab).closest(V[sheet])
    near = dist < 0.015 * diag
    assert near.sum() > 0.8 * sheet.size and dist[near].max() > 0.012 * diag
    assert out[0, sheet[near], 1].min() >= 0.5 * 0.05, out[0, sheet[near], 1].min() / 0.05
    assert np.abs(out[0, sheet]).max() <= 0.05 * (1 + 1e-6)
