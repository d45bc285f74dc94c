"""The export report: what the command line prints and the operator reports."""
from __future__ import annotations

from dataclasses import dataclass, field

from ..result import Report

__all__ = ["BakedObject", "ExportReport"]


@dataclass
class BakedObject:
    """What the export baked into one object's exported copy.

    Attributes
    ----------
    object : str
    shape_keys : int
        Shape keys exported (after splitting).
    driven : list of str
        Keys whose driver (in-between, combination, any native driver) was baked to keyed weights.
    split : list of str
        Keys whose weights left [0, 1]: exported as rescaled positive/negative parts (core.export.weights).
    posespace : str
        ``""``, or the pose-space method whose correctives were baked (``psd``, ``sbe``, ``wpsd``).
    per_frame_keys : int
        Weighted PSD through glTF/FBX: one morph target per baked frame (0 otherwise).
    point_cache : bool
        Alembic with weighted PSD: the corrected mesh baked per frame before the armature.
    """

    object: str
    shape_keys: int = 0
    driven: list = field(default_factory=list)
    split: list = field(default_factory=list)
    posespace: str = ""
    per_frame_keys: int = 0
    point_cache: bool = False


@dataclass
class ExportReport(Report):
    """One export.

    Attributes
    ----------
    format : str
        ``gltf``, ``fbx`` or ``abc``.
    path : str
        The file written.
    objects : list of str
        The objects exported (armatures of exported meshes included).
    frame_start, frame_end : int
        The baked range (the actions' full range unless one was asked for); equal for a still.
    animated : bool
        False when nothing was animated: the file holds the current frame as a still.
    baked : list of BakedObject
    notes : list of str
        What the format could not carry, duplicates ignored, and the like (one line each).
    seconds : float
        Bake + export wall time.
    status : Status
        ``WARNING`` when there are ``notes`` (something was left out, or could not be carried), else ``OK``
        (a failed export raises instead of returning a report).
    """

    format: str = ""
    path: str = ""
    objects: list = field(default_factory=list)
    frame_start: int = 0
    frame_end: int = 0
    animated: bool = True
    baked: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def frames(self) -> int:
        """Frames in the baked range."""
        return self.frame_end - self.frame_start + 1
