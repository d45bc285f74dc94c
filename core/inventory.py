"""What ``shapespace info`` reports about a file: typed, JSON-ready dataclasses (no Blender here).

The bridge (:mod:`bridge.inventory`) fills these from ``bpy.data``; the command line prints
``FileInventory.to_json()``.  Field names are the JSON keys, so the report format is defined here once.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .errors import ErrorCode
from .result import Issue, Report, ShapeSpaceError, Status, to_jsonable

__all__ = ["IssueInfo", "ShapeKeyMeshInfo", "ArmatureModifierInfo", "SkinnedMeshInfo", "ArmatureInfo",
           "ActionInfo", "SceneInfo", "FileInventory", "CaptureInfo"]


@dataclass
class IssueInfo:
    """One finding (severity ``error``/``warning``/``info``, stable code, one-line message)."""

    severity: str
    code: str
    message: str

    @classmethod
    def of(cls, issue: Issue) -> IssueInfo:
        return cls(issue.severity, str(issue.code), issue.message)


@dataclass
class ShapeKeyMeshInfo:
    """A mesh with shape keys: size, rank, ARKit coverage and problems (``None`` where unreadable)."""

    object: str
    vertices: int
    shape_keys: int | None = None
    reference_key: str | None = None
    names: list = field(default_factory=list)
    rank: int | None = None
    arkit_channels: int | None = None
    bbox_diagonal_local: float | None = None
    animated_by: str | None = None
    issues: list = field(default_factory=list)


@dataclass
class ArmatureModifierInfo:
    name: str
    armature: str
    preserve_volume: bool


@dataclass
class SkinnedMeshInfo:
    """A mesh deformed by Armature modifiers, with its skinning problems."""

    object: str
    vertices: int
    modifiers: list = field(default_factory=list)
    issues: list = field(default_factory=list)


@dataclass
class ArmatureInfo:
    object: str
    bones: int
    deform_bones: int
    action: str | None


@dataclass
class ActionInfo:
    """An action: frame range, what it animates, and whether any key sits between frames."""

    name: str
    frame_range: list
    fcurves: int
    shape_key_curves: int
    bone_curves: int
    slots: list
    fractional_keys: bool


@dataclass
class SceneInfo:
    name: str
    fps: float
    frame_start: int
    frame_end: int


@dataclass
class FileInventory(Report):
    """Everything ``shapespace info`` reports about one file."""

    file: str | None
    blender: str
    shapespace: str
    scene: SceneInfo
    shape_key_meshes: list = field(default_factory=list)
    skinned_meshes: list = field(default_factory=list)
    armatures: list = field(default_factory=list)
    actions: list = field(default_factory=list)

    def require_rigs(self) -> None:
        """Refuse a file with nothing ShapeSpace can work on."""
        if not (self.shape_key_meshes or self.skinned_meshes or self.armatures):
            raise ShapeSpaceError("no meshes with shape keys, armatures or skinned meshes found", ErrorCode.NO_RIGS)


@dataclass
class CaptureInfo(Report):
    """What ``shapespace info`` reports about one capture recording: ``file`` and its ``take`` description
    (kind, channels, rate, duration, head / eye channels, ``issues`` as one-line messages), printed flat beside
    ``status`` (``WARNING`` when the take has issues: the reader had to skip or repair something)."""

    file: str = ""
    take: dict = field(default_factory=dict)

    @classmethod
    def of(cls, file: str, take: dict) -> CaptureInfo:
        """The report of recording ``file`` described as ``take`` (its status from the take's issues)."""
        return cls(file=file, take=take, status=Status.WARNING if take.get("issues") else Status.OK)

    def to_json(self) -> dict:
        return {"file": self.file, **to_jsonable(self.take), "status": self.status.name.lower()}
