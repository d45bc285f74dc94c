"""ARKit channel-name normalisation across naming conventions.

Face rigs and capture files name the same ARKit blendshape differently:

==================  =====================  ========================
convention          example                seen in
==================  =====================  ========================
snake side suffix   ``eyeBlink_L``         facecap, ICT FaceKit
ARKit camelCase     ``eyeBlinkLeft``       Ready Player Me, ARKit
PascalCase          ``EyeBlinkLeft``       Live Link Face CSV / FBHead
==================  =====================  ========================

:func:`canonical_name` maps all of them to one canonical key (ARKit's own
camelCase, ``eyeBlinkLeft``) so channels can be matched by meaning, and
:func:`match_channels` builds a source→target mapping.
"""
from __future__ import annotations

import re
from collections.abc import Sequence

#: The 52 ARKit blendshape locations in Apple's camelCase spelling.
ARKIT_52 = (
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight",
    "eyeBlinkLeft", "eyeBlinkRight", "eyeLookDownLeft", "eyeLookDownRight",
    "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight",
    "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight",
    "eyeWideLeft", "eyeWideRight",
    "jawForward", "jawLeft", "jawOpen", "jawRight",
    "mouthClose", "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthFunnel", "mouthLeft", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthPressLeft", "mouthPressRight", "mouthPucker", "mouthRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthSmileLeft", "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthUpperUpLeft", "mouthUpperUpRight", "noseSneerLeft", "noseSneerRight",
    "tongueOut",
)

_SIDE_SUFFIX = re.compile(r"(?:[_.\-\s]?)(L|R|Left|Right|l|r|left|right)$")
#: Face Cap's blendshape order (the index of its OSC ``/W`` messages); iFacialMocap uses the same names.
FACECAP_52 = (
    "browInnerUp", "browDown_L", "browDown_R", "browOuterUp_L", "browOuterUp_R", "eyeLookUp_L", "eyeLookUp_R",
    "eyeLookDown_L", "eyeLookDown_R", "eyeLookIn_L", "eyeLookIn_R", "eyeLookOut_L", "eyeLookOut_R", "eyeBlink_L",
    "eyeBlink_R", "eyeSquint_L", "eyeSquint_R", "eyeWide_L", "eyeWide_R", "cheekPuff", "cheekSquint_L",
    "cheekSquint_R", "noseSneer_L", "noseSneer_R", "jawOpen", "jawForward", "jawLeft", "jawRight", "mouthFunnel",
    "mouthPucker", "mouthLeft", "mouthRight", "mouthRollUpper", "mouthRollLower", "mouthShrugUpper",
    "mouthShrugLower", "mouthClose", "mouthSmile_L", "mouthSmile_R", "mouthFrown_L", "mouthFrown_R",
    "mouthDimple_L", "mouthDimple_R", "mouthUpperUp_L", "mouthUpperUp_R", "mouthLowerDown_L", "mouthLowerDown_R",
    "mouthPress_L", "mouthPress_R", "mouthStretch_L", "mouthStretch_R", "tongueOut",
)

_LOOKUP = {n.lower(): n for n in ARKIT_52}


def canonical_name(name: str) -> str:
    """Return the canonical (ARKit camelCase) spelling of a channel name.

    Parameters
    ----------
    name : str
        A shape-key or capture-column name in any of the supported
        conventions (``eyeBlink_L``, ``eyeBlinkLeft``, ``EyeBlinkLeft``,
        ``eyeBlink.L``, ``EYEBLINK_LEFT``).

    Returns
    -------
    str
        ``"eyeBlinkLeft"`` for every example above.  Names that are not ARKit
        channels are returned with whitespace stripped and the side suffix
        unified (``"brow_raise_L"`` → ``"browraiseLeft"``), so two
        non-ARKit rigs that share a convention still match.
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a str, got {type(name).__name__}")
    stripped = name.strip()
    side = ""
    m = _SIDE_SUFFIX.search(stripped)
    base = stripped
    if m and m.start(1) > 0:
        token = m.group(1).lower()
        # A bare trailing lower-case 'l'/'r' glued to the word ("Curl") is not a side.
        glued = m.group(0) == m.group(1)
        if not (glued and len(m.group(1)) == 1):
            side = "Left" if token.startswith("l") else "Right"
            base = stripped[: m.start(0)]
    base = base.replace("_", "").replace(" ", "")
    candidate = (base + side).lower()
    if candidate in _LOOKUP:
        return _LOOKUP[candidate]
    # ICT splits browInnerUp / cheekPuff into sides: keep the side, canonical stem.
    if base.lower() in _LOOKUP and side:
        return _LOOKUP[base.lower()] + side
    return (base[:1].lower() + base[1:] + side) if base else stripped


def match_channels(source_names: Sequence[str], target_names: Sequence[str]) -> dict:
    """Match channels of two rigs by canonical name.

    Parameters
    ----------
    source_names, target_names : sequence of str
        Channel names in any convention.

    Returns
    -------
    mapping : dict
        ``{source_name: target_name}`` for every source channel whose
        canonical name occurs among the targets.  Exact (case-sensitive)
        name matches win over canonical ones.
    unmatched_source, unmatched_target : list of str
        Channels left without a partner, in input order.
    """
    source_names = list(source_names)
    target_names = list(target_names)
    by_canon = {}
    for t in target_names:
        by_canon.setdefault(canonical_name(t), []).append(t)
    exact = set(target_names)
    mapping = {}
    used = set()
    for s in source_names:
        if s in exact and s not in used:
            mapping[s] = s
            used.add(s)
    for s in source_names:
        if s in mapping:
            continue
        t = next((c for c in by_canon.get(canonical_name(s), ()) if c not in used), None)
        if t is not None:
            mapping[s] = t
            used.add(t)
    unmatched_source = [s for s in source_names if s not in mapping]
    unmatched_target = [t for t in target_names if t not in used]
    return mapping, unmatched_source, unmatched_target
