"""Issue #25 item 5, pure half: stored control-set entries (check on read, mirror) and the proposal's ranking."""
import json

import numpy as np
import pytest

from core.errors import ErrorCode
from core.result import ShapeSpaceError, Status
from core.rig.controls import ChannelKind
from core.rig.proposal import deformation, rank_channels
from core.rig.stored import (
    StoredChannel,
    add_entries,
    blob_from_entries,
    entries_from_blob,
    mirror_entries,
    mirror_entry,
)

WHERE = "Object 'Face' ▸ shapespace_controls"


def _bone(owner, kind="rotation", index=0, lo=None, hi=None, arm="rig"):
    return StoredChannel(ChannelKind(kind), arm, owner, f'pose.bones["{owner}"].rotation_euler', index, lo, hi)


def test_entries_round_trip_through_json():
    entries = [_bone("jaw_master", lo=-0.2, hi=0.3), _bone("lips.L", "location", 2),
               StoredChannel(ChannelKind.SHAPE_KEY, "Face", "eyeBlink_L", 'data.shape_keys.key_blocks["eyeBlink_L"]'
                             '.value', -1, None, 0.8, False),
               StoredChannel(ChannelKind.PROPERTY, "rig", "ctl", 'pose.bones["ctl"]["smile"]')]
    data = json.loads(json.dumps(blob_from_entries("rig", entries)))
    assert entries_from_blob(data, WHERE) == ("rig", entries)


@pytest.mark.parametrize("change,said", [
    ({"kind": "twist"}, "unknown kind 'twist'"),
    ({"index": 3}, "has no axis 3"),
    ({"index": True}, "field 'index' must be int"),
    ({"owner": ""}, "field 'owner' is empty"),
    ({"lo": 1.0, "hi": 0.0}, "bounds [1, 0] are not an interval"),
    ({"lo": "x"}, "'lo' must be a finite number or null"),
    ({"enabled": 1}, "field 'enabled' must be bool"),
])
def test_a_damaged_entry_is_named_in_one_line(change, said):
    good = blob_from_entries("rig", [_bone("jaw"), _bone("lips.L")])
    good["channels"][1].update(change)
    with pytest.raises(ShapeSpaceError) as exc:
        entries_from_blob(good, WHERE)
    assert exc.value.code == ErrorCode.CORRUPT_METADATA
    msg = str(exc.value)
    assert WHERE in msg and "channel 1" in msg and said in msg and "\n" not in msg, msg


def test_a_channel_stored_twice_is_damage():
    data = blob_from_entries("rig", [_bone("jaw"), _bone("jaw")])
    with pytest.raises(ShapeSpaceError, match=r"channel 1 \(jaw rotation X\) repeats channel 0"):
        entries_from_blob(data, WHERE)


def test_mirror_maps_every_side_spelling_and_reflects_bounds_as_a_flipped_pose():
    assert mirror_entry(_bone("jaw_master")) is None
    cases = {"lid.T.L.002": "lid.T.R.002", "brow.T.R": "brow.T.L", "EyeLeft": "EyeRight", "cheek_l": "cheek_r",
             "lip_L": "lip_R"}
    for a, b in cases.items():
        m = mirror_entry(_bone(a))
        assert m.owner == b and m.path == f'pose.bones["{b}"].rotation_euler'
    # rotation X keeps its sign, rotation Y/Z and location X flip; location Y/Z and scale keep theirs
    assert (mirror_entry(_bone("a.L", "rotation", 0, -0.1, 0.3)).lo, mirror_entry(_bone("a.L", "rotation", 0, -0.1,
            0.3)).hi) == (-0.1, 0.3)
    m = mirror_entry(_bone("a.L", "rotation", 2, -0.1, None))
    assert (m.lo, m.hi) == (None, 0.1)
    m = mirror_entry(_bone("a.L", "location", 0, 0.0, 0.2))
    assert (m.lo, m.hi) == (-0.2, -0.0)
    m = mirror_entry(_bone("a.L", "location", 1, 0.0, 0.2))
    assert (m.lo, m.hi) == (0.0, 0.2)
    key = StoredChannel(ChannelKind.SHAPE_KEY, "Face", "eyeBlink_L", 'data.shape_keys.key_blocks["eyeBlink_L"].value')
    assert mirror_entry(key).path == 'data.shape_keys.key_blocks["eyeBlink_R"].value'
    prop = StoredChannel(ChannelKind.PROPERTY, "rig", "ctl", 'pose.bones["ctl"]["blink_L"]')
    assert mirror_entry(prop).path == 'pose.bones["ctl"]["blink_R"]' and mirror_entry(prop).owner == "ctl"


def test_mirror_entries_adds_only_missing_mirrors_after_the_originals():
    entries = [_bone("jaw"), _bone("lips.L"), _bone("lips.R"), _bone("brow.L", "location", 1)]
    merged, added = mirror_entries(entries)
    assert merged[:4] == entries
    assert [(e.owner, e.kind.value, e.index) for e in added] == [("brow.R", "location", 1)]
    again, none = mirror_entries(merged)
    assert again == merged and none == []
    assert add_entries(entries, [_bone("jaw"), _bone("nose")])[1] == [_bone("nose")]


def test_deformation_takes_out_the_rigid_motion():
    rng = np.random.default_rng(0)
    rest = rng.normal(size=(200, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    rigid = rest @ q.T + [0.3, -1.0, 2.0]
    assert deformation(rest, rigid) < 1e-12
    bent = rigid.copy()
    bent[7] += [0.0, 0.0, 0.05]
    assert 0.04 < deformation(rest, bent) <= 0.05 + 1e-12
    bent[3, 1] = np.nan
    with pytest.raises(ShapeSpaceError, match="moved: vertex 3 is not finite"):
        deformation(rest, bent)


def test_rank_keeps_what_deforms_largest_first_and_names_the_rest():
    rep = rank_channels(["a", "b", "c", "d"], [0.0, 2e-3, 1e-9, 5e-2], 1.0, locked=["e"], held=["f"])
    assert rep.proposed == ["d", "b"] and rep.status == Status.OK
    assert rep.skipped == {"locked": ["e"], "held": ["f"], "inert": ["a", "c"]}
    line = rep.summary()
    assert line.startswith("proposed 2 channels") and "1 locked (e)" in line and "2 does not deform the face (a, c)" \
        in line and "\n" not in line
    assert rank_channels(["a"], [0.0], 1.0).status == Status.FAILED
    with pytest.raises(ShapeSpaceError):
        rank_channels(["a"], [np.nan], 1.0)
