"""ARKit channel-name normalisation and matching."""
import re

import pytest

from core.names import ARKIT_52, canonical_name, match_channels

# Names where "Left"/"Right" is a direction of motion, not a side of the face:
# capture tools (facecap, ICT) keep them spelled out in the snake convention.
DIRECTIONAL = {"jawLeft", "jawRight", "mouthLeft", "mouthRight"}


def to_snake(name):
    """eyeBlinkLeft -> eyeBlink_L (facecap / ICT side-suffix convention)."""
    if name not in DIRECTIONAL:
        if name.endswith("Left"):
            return name[:-4] + "_L"
        if name.endswith("Right"):
            return name[:-5] + "_R"
    return name


def to_pascal(name):
    return name[0].upper() + name[1:]


def test_arkit_52_is_52_unique_camelcase_names():
    assert len(ARKIT_52) == 52 and len(set(ARKIT_52)) == 52
    assert all(re.fullmatch(r"[a-z]+(?:[A-Z][a-z]*)*", n) for n in ARKIT_52)
    assert len({n.lower() for n in ARKIT_52}) == 52


@pytest.mark.parametrize("spelling", ["eyeBlink_L", "eyeBlinkLeft", "EyeBlinkLeft", "eyeBlink.L",
                                      "EYEBLINK_LEFT", "EYEBLINK_L", "eyeBlink_l", "eyeblinkleft",
                                      "  eyeBlink_L  ", "eyeBlink-L", "eyeBlink L", "eyeBlink_Left"])
def test_canonical_eye_blink_left(spelling):
    assert canonical_name(spelling) == "eyeBlinkLeft"


@pytest.mark.parametrize("spelling", ["eyeBlink_R", "eyeBlinkRight", "EyeBlinkRight", "eyeBlink.R", "EYEBLINK_RIGHT"])
def test_canonical_eye_blink_right(spelling):
    assert canonical_name(spelling) == "eyeBlinkRight"


@pytest.mark.parametrize("convention", [lambda n: n, to_snake, to_pascal,
                                        lambda n: to_pascal(to_snake(n)), str.upper, str.lower])
def test_all_52_round_trip(convention):
    for name in ARKIT_52:
        spelled = convention(name)
        assert canonical_name(spelled) == name, (spelled, canonical_name(spelled))


def test_snake_generation_actually_changes_sided_names():
    sided = [n for n in ARKIT_52 if to_snake(n) != n]
    assert len(sided) == 36  # 18 left/right pairs; jaw/mouth Left/Right are directions
    assert to_snake("eyeBlinkLeft") == "eyeBlink_L" and to_snake("jawLeft") == "jawLeft"


@pytest.mark.parametrize("name,canon", [
    ("jawLeft", "jawLeft"), ("JawLeft", "jawLeft"), ("jawRight", "jawRight"),
    ("mouthLeft", "mouthLeft"), ("MouthLeft", "mouthLeft"), ("mouthRight", "mouthRight"),
    ("MouthRight", "mouthRight"), ("JAWLEFT", "jawLeft"),
])
def test_directional_names_are_not_split_into_other_channels(name, canon):
    assert canonical_name(name) == canon


@pytest.mark.parametrize("name,canon", [
    ("mouthRollLower", "mouthRollLower"), ("mouthShrugUpper", "mouthShrugUpper"), ("mouthPucker", "mouthPucker"),
    ("mouthFunnel", "mouthFunnel"), ("MouthRollLower", "mouthRollLower"), ("MOUTHPUCKER", "mouthPucker"),
    ("MouthFunnel", "mouthFunnel"), ("MOUTHROLLUPPER", "mouthRollUpper"),
])
def test_trailing_l_or_r_glued_to_the_word_is_not_a_side(name, canon):
    assert canonical_name(name) == canon


def test_non_arkit_names_keep_side_and_match_across_conventions():
    assert canonical_name("brow_raise_L") == "browraiseLeft"
    assert canonical_name("cheekPuff_L") == "cheekPuffLeft"        # ICT split channel
    assert canonical_name("browInnerUp_R") == "browInnerUpRight"
    assert canonical_name("Curl") == "curl"
    assert canonical_name("myShape.L") == canonical_name("myShape_L") == canonical_name("myShapeLeft")


def test_canonical_name_type_error():
    with pytest.raises(TypeError):
        canonical_name(3)


def test_match_llf_to_facecap_reports_unmatched():
    llf = ["EyeBlinkLeft", "EyeBlinkRight", "JawOpen", "JawLeft", "MouthLeft", "MouthSmileLeft", "TongueOut"]
    facecap = ["eyeBlink_L", "eyeBlink_R", "jawOpen", "jawLeft", "mouthLeft", "mouthSmile_L", "cheekPuff"]
    mapping, un_src, un_tgt = match_channels(llf, facecap)
    assert mapping == {"EyeBlinkLeft": "eyeBlink_L", "EyeBlinkRight": "eyeBlink_R", "JawOpen": "jawOpen",
                       "JawLeft": "jawLeft", "MouthLeft": "mouthLeft", "MouthSmileLeft": "mouthSmile_L"}
    assert un_src == ["TongueOut"]
    assert un_tgt == ["cheekPuff"]


def test_full_arkit_match_between_conventions():
    llf = [to_pascal(n) for n in ARKIT_52]
    facecap = [to_snake(n) for n in reversed(ARKIT_52)]
    mapping, un_src, un_tgt = match_channels(llf, facecap)
    assert un_src == [] and un_tgt == []
    assert mapping == {to_pascal(n): to_snake(n) for n in ARKIT_52}
    assert len(set(mapping.values())) == 52  # one-to-one


def test_exact_matches_win_over_canonical():
    # the canonical duplicate comes first in the source, but the exact name takes the target
    mapping, un_src, un_tgt = match_channels(["EyeBlinkLeft", "eyeBlinkLeft"], ["eyeBlinkLeft"])
    assert mapping == {"eyeBlinkLeft": "eyeBlinkLeft"}
    assert un_src == ["EyeBlinkLeft"] and un_tgt == []


def test_exact_matches_pair_identical_names_even_when_canonical_twins_exist():
    mapping, un_src, un_tgt = match_channels(["eyeBlink_L", "eyeBlinkLeft"], ["eyeBlinkLeft", "eyeBlink_L"])
    assert mapping == {"eyeBlink_L": "eyeBlink_L", "eyeBlinkLeft": "eyeBlinkLeft"}
    assert un_src == [] and un_tgt == []


def test_unmatched_lists_keep_input_order():
    mapping, un_src, un_tgt = match_channels(["z", "JawOpen", "a"], ["q", "jawOpen", "b"])
    assert mapping == {"JawOpen": "jawOpen"}
    assert un_src == ["z", "a"] and un_tgt == ["q", "b"]


def test_canonical_twin_target_is_used_when_first_is_taken():
    mapping, un_src, un_tgt = match_channels(["eyeBlinkLeft", "EyeBlinkLeft"], ["eyeBlinkLeft", "eyeBlink_L"])
    assert mapping == {"eyeBlinkLeft": "eyeBlinkLeft", "EyeBlinkLeft": "eyeBlink_L"}
    assert un_src == [] and un_tgt == []
