"""The face-space capability's reports: what each face-space verb returns (one contract, :class:`core.result.Report`).

Each report is a dataclass whose fields are the keys the verb returned before (the JSON of :meth:`to_json` has the
same keys, plus ``status`` and ``issues``).  Fields listed in ``_OPTIONAL`` are left out of the JSON while they are
``None`` (a coherence report without an animation has no sparsity).  :meth:`FaceSpaceReport.payload` is the JSON
without ``status`` and ``issues``: what the rig's analysis blob stores.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..result import Report

__all__ = ["CoherenceReport", "CompressionReport", "ConvexReport", "FaceSpaceReport", "FillReport",
           "InpaintReport", "MeterReport", "PriorReport"]


@dataclass
class FaceSpaceReport(Report):
    """Base of the face-space reports: :meth:`to_json` leaves out the optional fields that are ``None``."""

    _OPTIONAL = ()

    def to_json(self) -> dict:
        out = super().to_json()
        for name in self._OPTIONAL:
            if getattr(self, name) is None:
                out.pop(name, None)
        return out

    def payload(self) -> dict:
        """The report's own keys (the JSON without ``status`` and ``issues``), as the rig stores them."""
        out = self.to_json()
        out.pop("status", None)
        out.pop("issues", None)
        return out


@dataclass
class ConvexReport(FaceSpaceReport):
    """Make Convex (3.7.3): the slider sum before and after, and how far the sliders moved (Euclidean)."""

    sum_before: float = 0.0
    sum_after: float = 0.0
    moved: float = 0.0


@dataclass
class CompressionReport(FaceSpaceReport):
    """Compression report (3.7.8): ``components`` of the animation's PCA keep its ``frames`` within ``tol``
    (``None`` and status FAILED when no number of components does); ``ratio`` = targets / components."""

    components: int | None = None
    targets: int = 0
    frames: int = 0
    tol: float = 0.0
    ratio: float | None = None
    animation_rank: int = 0
    rig_rank: int = 0
    message: str = ""


@dataclass
class CoherenceReport(FaceSpaceReport):
    """Rig analysis (3.7.1, 3.7.6): mutual coherence, near-duplicate pairs ``[a, b, coherence]``, empty targets,
    the PNG written (``""`` when packed), the image datablock's name and, with an animation of two frames or
    more, the sparsity of its blendshape weights vs PCA coefficients."""

    _OPTIONAL = ("sparsity", "sparsity_message")

    targets: int = 0
    mutual_coherence: float = 0.0
    similar_pairs: list = field(default_factory=list)
    empty_targets: list = field(default_factory=list)
    png: str = ""
    sparsity: dict | None = None
    sparsity_message: str | None = None
    image: str = ""


@dataclass
class PriorReport(FaceSpaceReport):
    """Learn Face Prior (ch. 6): frames used, the Gaussian's dimension, whether it was regularised (status
    WARNING then) and its one-line message."""

    frames: int = 0
    dimension: int = 0
    regularised: bool = False
    message: str = ""


@dataclass
class MeterReport(FaceSpaceReport):
    """The probability meter (ch. 6): the face norm of the current expression, the typical shell's radius, the
    χ² percentile and the ``plausibility`` (``"typical"``, ``"too_average"`` or ``"too_extreme"``; status
    WARNING unless typical)."""

    norm: float = 0.0
    shell_radius: float = 0.0
    percentile: float = 0.0
    plausibility: str = "typical"


@dataclass
class FillReport(FaceSpaceReport):
    """Fill In-Betweens (6.5): how many frames were keyed between ``start`` and ``end``."""

    frames: int = 0
    start: int = 0
    end: int = 0


@dataclass
class InpaintReport(FaceSpaceReport):
    """Inpaint Gap (9.3): frames keyed, curves that informed the fill (the target included), the method."""

    frames: int = 0
    channels: int = 0
    method: str = ""
    message: str = ""
