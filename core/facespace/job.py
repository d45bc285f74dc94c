"""The pure middle step of each face-space verb (thesis 3.7, ch. 6, 9.3): arrays in, report (and what to write) out.

The bridge (:mod:`bridge.facespace`) reads the rig and its animation, calls one of these, and writes what it
returns; nothing here touches Blender data, so any thread may run them and the core tier tests them.

- :func:`whole_face_plan` — the keys of a whole-face copy (3.7.3);
- :func:`pca_copy` — the basis and unit-scaled sliders of a PCA copy (3.4.6, 3.7.5);
- :func:`convex_step` — Make Convex (3.7.3);
- :func:`compression_step` — the compression report (3.7.8);
- :func:`coherence_step` — the rig analysis: coherence, near-duplicates, empty targets, sparsity (3.7.1, 3.7.6);
- :func:`coherence_problem` — what is wrong with a stored rig analysis;
- :func:`prior_step` / :func:`meter_step` — learn the face prior and place an expression on it (ch. 6);
- :func:`inpaint_step` — fill a gap of one curve from the rest of the animation (9.3).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..progress import ProgressFn, notify
from ..result import Issue, ShapeSpaceError, Status
from .diagnostics import (
    coherence_image,
    coherence_matrix,
    empty_targets,
    mutual_coherence,
    similar_pairs,
    sparsity_comparison,
)
from .forms import convex_slider_values, neutral_key_count, to_whole_face
from .inpainting import fill_gap
from .pca import PCABasis, PCASliders, compressed_animation_pca, compression_report, pca_from_model, pca_sliders
from .prior import FaceGaussian, fit_face_gaussian
from .report import CoherenceReport, CompressionReport, ConvexReport, InpaintReport, MeterReport, PriorReport

__all__ = ["WholeFacePlan", "coherence_problem", "coherence_step", "compression_step", "convex_step",
           "inpaint_step", "meter_step", "neutral_key_names", "pca_copy", "prior_step", "whole_face_plan"]


def neutral_key_names(count: int, base: str = "Neutral") -> list:
    """Names of the ``count`` keys sharing the neutral's weight: ``Neutral``, ``Neutral 2``, …"""
    return [base] + [f"{base} {i}" for i in range(2, count + 1)]


@dataclass
class WholeFacePlan:
    """The keys of a whole-face copy (thesis 3.7.3), in the order they are added after the zero reference.

    Attributes
    ----------
    neutral_names : list of str
        The ``K`` keys sharing the neutral's weight (each driven by ``c0 / K`` when convex).
    neutral : ndarray, shape (p, 3)
        The neutral face ``b0`` (every Neutral key holds it).
    targets : ndarray, shape (n, p, 3)
        Whole-face targets ``b_k = b0 + d_k``.
    runs : list of ndarray of int
        The targets following each Neutral key (Blender sums keys in order in float32: interleaving keeps the
        running sum near one face instead of −Σw faces).
    """

    neutral_names: list
    neutral: np.ndarray
    targets: np.ndarray
    runs: list


def whole_face_plan(model: BlendshapeModel, convex: bool, limit: float, owner: str = "the rig",
                    neutral: str = "Neutral", zero: str = "Zero") -> WholeFacePlan:
    """What a whole-face copy of ``model`` holds (thesis 3.7.3).

    Parameters
    ----------
    model : BlendshapeModel
        A linear rig (primary targets only).
    convex : bool
        The copy's Neutral weight follows ``1 − Σw``: ``K`` = :func:`neutral_key_count` keys share it so each
        stays within ``±limit``; without it one free Neutral key.
    limit : float
        The host's bound on a key's weight (Blender: 10).
    owner : str
        How messages name the rig.
    neutral, zero : str
        Names of the Neutral key(s) and the zero reference.

    Returns
    -------
    WholeFacePlan

    Raises
    ------
    ShapeSpaceError
        A slider already named like one of the copy's own keys (code ``reserved_name``).
    """
    count = neutral_key_count(model.slider_min, model.slider_max, limit) if convex else 1
    names = neutral_key_names(count, neutral)
    clash = [n for n in model.names if n in names or n == zero]
    if clash:
        raise ShapeSpaceError(f"shape key {clash[0]!r} of {owner} has a name the whole-face copy needs for its own "
                              "keys: rename it first", ErrorCode.RESERVED_NAME)
    targets, b0 = to_whole_face(model)
    return WholeFacePlan(names, b0, targets, np.array_split(np.arange(model.n_targets), count))


def pca_copy(model: BlendshapeModel, weights: ArrayLike | None, tol: float, limit: float,
             what: str = "the rig's shape keys move") -> tuple[PCABasis, PCASliders]:
    """The basis and sliders of a PCA copy (thesis 3.4.6, 3.7.5).

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n), or None
        An animation (its PCA, with the fewest components keeping every frame within ``tol``), or ``None``
        (an exact orthonormal basis of the rig's target span).
    tol : float
        Max vertex error of the animation's PCA (object units).
    limit : float
        The host's bound on a slider (Blender: 10): a unit grows so every frame stays within it.
    what : str
        How a refusal names what moves nothing, e.g. ``"action 'Take' moves"``.

    Returns
    -------
    (PCABasis, PCASliders)

    Raises
    ------
    ShapeSpaceError
        No number of components reaches ``tol`` (``tolerance_not_met``); nothing moves (``empty``).
    """
    if weights is None:
        basis = pca_from_model(model)
    else:
        res = compressed_animation_pca(model, weights, tol)
        if res.value is None:
            raise ShapeSpaceError(res.message, ErrorCode.TOLERANCE_NOT_MET)
        basis = res.value
    if basis.n_components == 0:
        raise ShapeSpaceError(f"{what} no vertex: a PCA copy would have no sliders", ErrorCode.EMPTY)
    return basis, pca_sliders(model, basis, weights, limit)


def convex_step(w: ArrayLike, slider_min: ArrayLike, slider_max: ArrayLike) -> tuple[np.ndarray, ConvexReport]:
    """Make Convex (thesis 3.7.3): the nearest convex slider values (:func:`convex_slider_values`) and the report.

    Returns
    -------
    values : ndarray, shape (n,)
    ConvexReport
    """
    res = convex_slider_values(w, slider_min, slider_max)
    d = res.diagnostics
    return res.value, ConvexReport(sum_before=d["sum_before"], sum_after=d["sum_after"], moved=d["moved"])


def compression_step(model: BlendshapeModel, weights: ArrayLike, tol: float,
                     progress: ProgressFn | None = None) -> CompressionReport:
    """How many PCA components keep an animation ``weights`` (f, n) within ``tol`` (thesis 3.7.8).

    Status FAILED (with an ``error`` issue ``tolerance_not_met``) when no number of components does;
    ``progress`` is told 0.95 when done.
    """
    weights = np.asarray(weights)
    res = compression_report(model, weights, tol)
    notify(progress, 0.95)
    d = res.diagnostics
    failed = res.value is None
    return CompressionReport(components=res.value, targets=model.n_targets, frames=int(weights.shape[0]),
                             tol=float(tol), ratio=d["compression_ratio"], animation_rank=d["animation_rank"],
                             rig_rank=d["rig_rank"], message=res.message,
                             status=Status.FAILED if failed else Status.OK,
                             issues=[Issue("error", str(ErrorCode.TOLERANCE_NOT_MET.value), res.message)]
                             if failed else [])


def coherence_step(model: BlendshapeModel, weights: ArrayLike | None, threshold: float = 0.95, png: str = "",
                   progress: ProgressFn | None = None) -> tuple[CoherenceReport, np.ndarray]:
    """The rig analysis (thesis 3.7.1, 3.7.6, Figs 3.12–3.15) and its coherence picture.

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n), or None
        The rig's animation: with two frames or more the report compares the sparsity of its blendshape
        weights and PCA coefficients.
    threshold : float
        Pairs of targets whose coherence exceeds it are listed.
    png : str
        The PNG the picture goes to (``""``: packed), recorded in the report.
    progress : callable, optional
        Told 0.4 after the coherence, 0.5 before the sparsity, 0.9 when done.

    Returns
    -------
    CoherenceReport
        ``image`` is left empty: the caller names the image it makes.
    ndarray, shape (h, w, 4), uint8
        The coherence picture (:func:`coherence_image`), rows top-down.
    """
    coherence = coherence_matrix(model)
    rep = CoherenceReport(targets=model.n_targets, mutual_coherence=float(mutual_coherence(model)),
                          similar_pairs=[[a, b, float(c)] for a, b, c in similar_pairs(model, threshold)],
                          empty_targets=empty_targets(model), png=png or "")
    notify(progress, 0.4)
    if weights is not None and np.shape(weights)[0] >= 2:   # sparsity over time needs two frames or more
        notify(progress, 0.5)
        sp = sparsity_comparison(model, weights)
        rep.sparsity = {form: {k: float(v) for k, v in vals.items() if np.isscalar(v)}
                        for form, vals in sp.value.items()}
        rep.sparsity_message = sp.message
    notify(progress, 0.9)
    return rep, coherence_image(coherence)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def coherence_problem(coherence: dict) -> str | None:
    """What is wrong with a stored rig analysis ``coherence`` (its fields' types already checked), or None.

    Every empty target must be a name, every similar pair ``[name, name, number]``, and a sparsity entry must
    give each form's ``curve_small_fraction`` as a number (or null).
    """
    if not all(isinstance(n, str) for n in coherence["empty_targets"]):
        return "coherence: every empty target must be a shape-key name"
    for pair in coherence["similar_pairs"]:
        ok = isinstance(pair, list) and len(pair) == 3 and all(isinstance(v, str) for v in pair[:2]) \
            and _is_number(pair[2])
        if not ok:
            return f"coherence: similar pair {pair!r:.60} must be [name, name, number]"
    sparsity = coherence.get("sparsity")
    for form in ("blendshape", "pca") if sparsity else ():
        entry = sparsity.get(form)
        value = entry.get("curve_small_fraction", "missing") if isinstance(entry, dict) else "missing"
        if value is not None and not _is_number(value):
            return f"coherence: sparsity needs {form}.curve_small_fraction (a number)"
    return None


def prior_step(names: list, weights: ArrayLike) -> tuple[FaceGaussian, dict, PriorReport]:
    """Fit the face-space Gaussian (ch. 6) to an animation ``weights`` (f, n) of the sliders ``names``.

    Returns
    -------
    FaceGaussian
    dict
        What the rig stores (names, mean, eigenbasis, …: the fields of the face-prior blob).
    PriorReport
        Status WARNING (and a ``regularised`` warning issue) when the covariance needed a ridge.
    """
    weights = np.asarray(weights)
    g = fit_face_gaussian(weights)
    frames = int(weights.shape[0])
    blob = {"names": list(names), "mean": g.mean.tolist(), "eigvecs": g.eigvecs.tolist(),
            "eigvals": g.eigvals.tolist(), "dimension": g.dimension, "ridge": g.ridge,
            "regularised": g.regularised, "message": g.message, "frames": frames}
    rep = PriorReport(frames=frames, dimension=g.dimension, regularised=g.regularised, message=g.message,
                      status=Status.WARNING if g.regularised else Status.OK,
                      issues=[Issue("warning", "regularised", g.message)] if g.regularised else [])
    return g, blob, rep


def meter_step(g: FaceGaussian, names: list, w: ArrayLike, owner: str = "the rig") -> MeterReport:
    """Where the expression ``w`` (n,) of the sliders ``names`` lies on the face prior ``g`` (ch. 6).

    A slider value that is not finite is refused, naming the key (code ``non_finite``).  The report's status
    is WARNING (with the prior's issues) unless the expression is typical.
    """
    w = np.asarray(w, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(w))
    if bad.size:
        raise ShapeSpaceError(f"shape key {names[bad[0]]!r} of {owner} has value {w[bad[0]]}", ErrorCode.NON_FINITE)
    res = g.plausibility(w[None])
    verdict = str(res.value[0])
    return MeterReport(norm=float(res.diagnostics["norm"][0]), shell_radius=g.shell_radius,
                       percentile=float(res.diagnostics["percentile"][0]), plausibility=verdict,
                       status=Status.OK if verdict == "typical" else Status.WARNING,
                       issues=[i for i in res.issues if i.severity != "info"])


def inpaint_step(samples: ArrayLike, gap: ArrayLike) -> tuple[np.ndarray, InpaintReport]:
    """Fill the ``gap`` (T,) bool of the first column of ``samples`` (T, 1 + c) from the covariance of the
    animation (thesis 9.3, :func:`fill_gap`).

    Returns
    -------
    values : ndarray, shape (g,)
        The filled samples on the gap's frames (the known ones are untouched by construction).
    InpaintReport
    """
    gap = np.asarray(gap, dtype=bool)
    res = fill_gap(samples, gap)
    return res.value[gap], InpaintReport(frames=int(gap.sum()), channels=len(res.diagnostics["channels"]),
                                         method=res.diagnostics.get("method", ""), message=res.message,
                                         status=res.status, issues=list(res.issues))
