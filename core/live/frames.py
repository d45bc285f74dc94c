"""One decoded capture frame, and the channel orders of the live sources (by name, never by packet index).

Each protocol delivers its blendshapes in its own fixed order under its own
names; the live pipeline keeps that order (the solvers are built for it) and
maps channels onto rigs by name (:func:`core.names.match_channels`), exactly
as the offline retarget maps a CSV's columns.

- :data:`LLF_CURVES` — Live Link Face's 61 curves in the ARKit enum order the
  "Live Link (ARKit)" packets use (which is *not* the CSV's column order: the
  CSV swaps ``JawLeft``/``JawRight`` and ``MouthLeft``/``MouthRight``), with
  the same PascalCase names as the CSV columns;
- :data:`FACECAP_52` — Face Cap's blendshape order (its OSC ``/W`` index) and
  names, which iFacialMocap shares.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..blendshape import MAX_ABS_WEIGHT
from ..names import FACECAP_52

__all__ = ["LLF_CURVES", "LLF_BLENDSHAPES", "LLF_ROTATIONS", "FACECAP_52", "LiveFrame", "format_timecode",
           "MAX_ABS_ANGLE", "ROTATION_CHANNELS", "implausible_channel"]

#: Live Link Face curve order in its UDP packets (ARKit ``ARFaceAnchor.BlendShapeLocation`` enum order).
LLF_CURVES = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawLeft", "JawRight", "JawOpen", "MouthClose", "MouthFunnel",
    "MouthPucker", "MouthLeft", "MouthRight", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft",
    "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper", "MouthPressLeft", "MouthPressRight",
    "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight", "BrowDownLeft",
    "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight", "CheekPuff", "CheekSquintLeft",
    "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
    "HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
    "RightEyeYaw", "RightEyePitch", "RightEyeRoll",
)
LLF_BLENDSHAPES = LLF_CURVES[:52]
LLF_ROTATIONS = LLF_CURVES[52:]

#: Largest head or eye angle magnitude accepted, in radians (two turns): beyond it a value is damaged, not a pose.
MAX_ABS_ANGLE = 4.0 * math.pi
#: The rotation channels of a frame vector after its weights (:meth:`LiveFrame.vector`).
ROTATION_CHANNELS = tuple(f"{part} {axis}" for part in ("head", "left eye", "right eye")
                          for axis in ("yaw", "pitch", "roll"))


def implausible_channel(names: Sequence[str], vector: ArrayLike) -> str:
    """'' or a one-line reason naming the first channel of a frame vector beyond the plausibility limits.

    The live counterpart of the offline reader's: a weight beyond ±:data:`~core.blendshape.MAX_ABS_WEIGHT`
    (ARKit weights lie in [0, 1]) or an angle beyond ±:data:`MAX_ABS_ANGLE` is damaged data, refused rather
    than clipped.

    Parameters
    ----------
    names : sequence of str
        The source's blendshape names (n,).
    vector : array_like (n + 9,)
        ``[weights, head, eye_left, eye_right]`` (:meth:`LiveFrame.vector`).
    """
    v = np.asarray(vector, dtype=np.float64)
    n = len(names)
    bad = np.flatnonzero(~(np.abs(v[:n]) <= MAX_ABS_WEIGHT))
    if bad.size:
        k = int(bad[0])
        return (f"weight {names[k]} = {v[k]:.6g} is not a blendshape weight (they lie in [0, 1]; beyond "
                f"±{MAX_ABS_WEIGHT:g} a value is damaged)")
    bad = np.flatnonzero(~(np.abs(v[n:]) <= MAX_ABS_ANGLE))
    if bad.size:
        k = int(bad[0])
        return (f"{ROTATION_CHANNELS[k]} = {v[n + k]:.6g} rad is not an angle of a face (beyond "
                f"±{MAX_ABS_ANGLE:.4g} rad a value is damaged)")
    return ""


def _zeros3() -> np.ndarray:
    return np.zeros(3)


@dataclass
class LiveFrame:
    """A decoded capture frame.

    Attributes
    ----------
    names : tuple of str
        The source's channel names (one of the constant orders above).
    weights : ndarray (n,)
        Blendshape weights in ``names`` order (0 … 1 for ARKit sources).
    head : ndarray (3,)
        Head rotation ``(yaw, pitch, roll)`` in radians, in the face frame (x: the face's left, y: up,
        z: out of the face), ``R = R_y(yaw) R_x(pitch) R_z(roll)``.
    eye_left, eye_right : ndarray (3,)
        Eye rotations ``(yaw, pitch, roll)`` in radians, relative to the head, same convention.
    time : float
        Source time in seconds (the packet's timecode, an OSC bundle's time tag, or the arrival time when
        the protocol carries none).
    frame : int or None
        The source's frame counter, when it sends one (Live Link Face): gaps show dropped frames.
    rate : float or None
        The counter's rate (frames per second).
    arrival : float
        ``time.monotonic()`` when the datagram was received.
    head_position : ndarray (3,)
        Head translation when the source sends one (Face Cap ``/HT``, iFacialMocap), else zeros.
    subject : str
        The sender's subject / device name, when it sends one.
    """

    names: tuple
    weights: np.ndarray
    head: np.ndarray = field(default_factory=_zeros3)
    eye_left: np.ndarray = field(default_factory=_zeros3)
    eye_right: np.ndarray = field(default_factory=_zeros3)
    time: float = 0.0
    frame: int | None = None
    rate: float | None = None
    arrival: float = 0.0
    head_position: np.ndarray = field(default_factory=_zeros3)
    subject: str = ""

    def vector(self) -> np.ndarray:
        """``[weights, head, eye_left, eye_right]``: shape (n + 9,), the values the pipeline filters."""
        return np.concatenate([self.weights, self.head, self.eye_left, self.eye_right])


def format_timecode(seconds: float, fps: float = 60.0) -> str:
    """Seconds → ``HH:MM:SS:FF.fff`` at ``fps`` (the Live Link Face CSV's timecode form)."""
    total = max(float(seconds), 0.0)
    whole = int(total)
    frames = (total - whole) * fps
    h, rem = divmod(whole, 3600)
    m, s = divmod(rem, 60)
    return f"{h:02d}:{m:02d}:{s:02d}:{int(frames):02d}.{int(round((frames - int(frames)) * 1000)) % 1000:03d}"
